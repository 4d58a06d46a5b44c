// The work that runs around a SessionManager (cf. cartographer's PoseGraph2D::AddWorkItem): the
// queue of keyframes, loops and other vehicles' keyframes, the loops that wait for their
// keyframes, the optimisation loop, and the requests that go with the stored sessions (the
// handover to the loop detectors, paging, keyframe features) and with relocalisation. Both heads
// drive it: core::Pipeline (offline_slam) synchronously, the back-end nodelet asynchronously.
//
// Threading. The worker owns the manager and the one mutex that guards it (mutex_). Every use of
// the manager goes through the worker: the work items, locked() (a host's request or query under
// the mutex) and the requests below.
//  - Synchronous (start() never called): each work item is processed in the caller's thread
//    before the call returns; exceptions reach the caller.
//  - Asynchronous (after start()): work items go into a bounded queue (core/common/work_queue.h,
//    queue_size; when full the OLDEST is dropped and counted; optimiseDue() is a priority item,
//    never dropped), and one worker thread, owned here, processes them in order. An item that
//    throws is counted (stats().skipped) and logged. stop() processes what is queued and joins
//    the thread.
// Either way an item is processed the same: under the mutex, the manager's call and the item's
// `done` callback; then, after a keyframe, every waiting loop tried again (each under the
// mutex); then optimisation of every due map: its problem taken under the mutex, solved WITHOUT
// it (requests, queries and the host's per-frame work go on meanwhile), applied under it; a map
// changed while it was solved (its revision moved on) is solved again. Last, the `after_item`
// hook runs under the mutex (the back-end publishes there). The manager runs with deferred
// optimisation, so no request (and no service) ever waits for a solve: it only marks maps due.
//
// Callbacks (done, after_item, the manager's events, Log) run under the mutex: they must not
// call back into the worker. The statistics and the handover list have a mutex each, taken after
// mutex_ when both are held (ACQUIRED_AFTER: clang -Wthread-safety checks the order).
#pragma once

#include <cstddef>
#include <deque>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <type_traits>
#include <variant>
#include <vector>

#include "uw_multislam/core/common/status.h"
#include "uw_multislam/core/common/thread_annotations.h"
#include "uw_multislam/core/common/work_queue.h"
#include "uw_multislam/core/loops/haloc.h"
#include "uw_multislam/core/session/session_manager.h"

namespace uw_multislam {
namespace core {

struct SessionWorkerOptions {
  int queue_size = 1000;         // asynchronous: items waiting (>= 1); full: the oldest dropped, counted
  int max_waiting_loops = 1000;  // loops waiting for a keyframe (>= 0); full: the oldest dropped, counted
  /// loops.page_stored: stored sessions go to the loop detectors with their hashes only (the
  /// detectors read features with keyframeFeatures when a keyframe is a candidate).
  bool page_stored = false;
  /// The worker thread's nice value, 0..19 (core/common/thread_priority.h): above 0 it yields the
  /// cores to the odometry's frames, which are latency bound, while both want them.
  int nice = 0;
  /// How a due map's problem is solved (default SessionManager::solveOptimisation). Runs without
  /// the mutex; a test wraps it to change the map meanwhile.
  std::function<void(MapOptimisation*)> solve;
  std::string validate() const;
};

struct SessionWorkerStats {
  long pushed = 0;              // items accepted into the queue (asynchronous; priority items not counted)
  long dropped_queue_full = 0;  // items dropped because the queue was full
  std::size_t queued = 0;       // items waiting now
  long keyframes = 0;           // this vehicle's keyframes processed
  long loops = 0;               // loops processed (a retried loop counts once)
  long skipped = 0;             // items whose processing threw (asynchronous: counted, logged)
  std::size_t waiting = 0;      // loops waiting for a keyframe now
  long waiting_dropped = 0;     // waiting loops dropped past max_waiting_loops
  long solves = 0;              // map problems solved
  long solved_again = 0;        // solves whose map changed meanwhile (dropped, the map solved again)
};

/// The stored sessions handed to the loop detectors, and the newest handover to one of them.
struct HandoverStats {
  long subscribers = 0;  // handovers started
  long total = 0;        // keyframes the newest one hands over
  long sent = 0;         // of them, sent so far
  long without_features = 0;
  double seconds = 0.0;  // how long the newest one took (when done)
};

/// keyframe_features' answer: a stored keyframe's features, or where another vehicle's are.
struct KeyframeFeaturesAnswer {
  ReloadedSession session;  // id and camera (keyframes empty)
  StoredKeyframe keyframe;  // the features (no thumbnail)
  /// Another vehicle's session: nothing was read here; that vehicle is asked for its session
  /// `remote_session` (the answer is OK with `vehicle` set).
  std::string vehicle;
  int remote_session = -1;
};

/// The active session's relocalisation in another map (SessionManager::relocalise), followed from
/// one publication to the next: what changed is said once, and what /diagnostics shows is kept.
class RelocalisationTracker {
 public:
  struct State {
    int session = -1, map = -1, loops = 0, keyframe = -1;
    long published = 0;  // relocalised poses published for this session
  };
  /// The session's relocalisation now; a change (relocalised, or no longer: not by a join) goes
  /// into *said (else it is cleared).
  std::optional<SessionQueries::Relocalisation> update(const SessionQueries& manager, int session, std::string* said);
  void published() { ++state_.published; }
  /// No active session (finish_session): nothing relocalised.
  void reset() { state_ = State(); }
  const State& state() const { return state_; }

 private:
  State state_;
};

class SessionWorker {
 public:
  enum class Severity { kInfo, kWarn, kError };
  using Log = std::function<void(Severity, const std::string&)>;
  /// Work items' callbacks, under the mutex, after the manager's call.
  using KeyframeDone = std::function<void(const SessionQueries&, const KeyframeInput&, const Status&)>;
  using ForeignDone =
      std::function<void(const SessionQueries&, const KeyframeInput&, const Status&, int local_id, bool opened)>;
  using Done = std::function<void(const SessionQueries&, const Status&)>;
  using AfterItem = std::function<void(SessionManager&)>;

  /// Takes the manager and turns its deferred optimisation on (this worker optimises). Throws
  /// std::invalid_argument on bad options.
  SessionWorker(std::unique_ptr<SessionManager> manager, const SessionWorkerOptions& options, Log log = {});
  /// The same around a manager the caller keeps (it must outlive the worker, and be used only
  /// through it while the worker lives).
  SessionWorker(SessionManager* manager, const SessionWorkerOptions& options, Log log = {});
  /// stop(): what is queued is processed first.
  ~SessionWorker();
  SessionWorker(const SessionWorker&) = delete;
  SessionWorker& operator=(const SessionWorker&) = delete;

  // --- Driving --------------------------------------------------------------------------------
  /// Asynchronous from now on: the worker thread starts; `after_item` (may be empty) runs under
  /// the mutex after each item. Call once.
  void start(AfterItem after_item = {});
  /// No more items; what is queued is processed, the thread joined. Items given later are refused.
  void stop();
  bool asynchronous() const { return thread_.joinable(); }

  // --- Work items, in order (see "Threading") -------------------------------------------------
  /// This vehicle's keyframe (SessionManager::addKeyframe), with the loops it closed (offline:
  /// stored with it in one transaction). Returns false when refused (stopped).
  bool addKeyframe(KeyframeInput keyframe, std::vector<Loop> loops = {}, KeyframeDone done = {});
  /// A loop (SessionManager::addLoop). One naming a keyframe that has not arrived waits, up to
  /// max_waiting_loops (then the oldest is dropped, counted), and is tried again after each keyframe.
  bool addLoop(const Loop& loop);
  /// Another vehicle's keyframe, made with `settings` (HashSettings::compatible with ours, else
  /// FAILED_PRECONDITION), then SessionManager::addForeignKeyframe.
  bool addForeignKeyframe(const std::string& vehicle, const HashSettings& settings, KeyframeInput keyframe,
                          ForeignDone done = {});
  /// Another vehicle's session ended (SessionManager::endForeignSession).
  bool endForeignSession(const std::string& vehicle, int remote_session, double stamp_s, Done done = {});
  /// Optimises every due map (a request left some due: join, split, start, add_link, optimise).
  /// Asynchronous: a priority item (the caller does not wait); synchronous: now.
  void optimiseDue();

  // --- Requests and queries under the mutex ---------------------------------------------------
  /// f(manager) under the mutex (the const one: f(manager.view()), the queries); its result.
  /// What it returns must not refer into the manager.
  template <typename F>
  decltype(auto) locked(F&& f) EXCLUDES(mutex_) {
    MutexLock lock(&mutex_);
    if constexpr (std::is_invocable_v<F, SessionManager&>)
      return f(*manager_);
    else
      return f(manager_->view());
  }
  template <typename F>
  decltype(auto) locked(F&& f) const EXCLUDES(mutex_) {
    MutexLock lock(&mutex_);
    return f(manager_->view());
  }
  /// The manager's hasher (immutable: no lock needed).
  const ImageHasher& hasher() const NO_THREAD_SAFETY_ANALYSIS { return manager_->view().hasher(); }
  SessionWorkerStats stats() const;

  // --- Stored sessions and the loop detectors ---------------------------------------------------
  /// ~reload_stored: every stored (UNLOADED) session reloaded without reading anything
  /// (ReloadRead::kNothing: the handover reads each one later, session by session) and put on
  /// the handover list. Returns the sessions and keyframes listed; refusals are logged.
  std::pair<int, long> reloadStored();
  /// reload_session: SessionManager::reload with features; on OK the session joins the handover
  /// list, `send` gets each keyframe under the mutex (features dropped when paging: the loop
  /// detectors read them again when needed), and *out the session with its thumbnails.
  Status reloadSession(const std::string& name_or_id, ReloadedSession* out,
                       const std::function<void(const ReloadedSession&, const StoredKeyframe&)>& send);
  /// Hands every listed session to one new loop detector: session by session, each under the
  /// mutex (an unload cannot come between a session's keyframes and its notice, and the worker
  /// maps between sessions), its hashes read, and its features unless paging; `send` per
  /// keyframe under the mutex. A session that cannot be read is logged and skipped; a keyframe
  /// whose features cannot be read goes without them (no candidate). Returns the stats.
  HandoverStats handOver(const std::string& to,
                         const std::function<void(const ReloadedSession&, const StoredKeyframe&)>& send);
  /// The loop detectors forget the session (unload, delete): later handovers skip it. Takes
  /// only the handover list's mutex (callable under locked()).
  void forgetHandedOver(int session);
  HandoverStats handoverStats() const;
  std::vector<int> handedOver() const;

  /// keyframe_features: one keyframe as the store keeps it (a loop detector pages it in), read
  /// under the mutex. `check_only`: only whether it is there. Another vehicle's session: OK with
  /// out->vehicle set (nothing read; ask that vehicle). Refused: INVALID_ARGUMENT (ids),
  /// NOT_FOUND (no such session, or the keyframe not in the store yet), FAILED_PRECONDITION (no
  /// store), DATA_LOSS (stored but unreadable).
  Status keyframeFeatures(int session, int keyframe, bool check_only, KeyframeFeaturesAnswer* out) const;

 private:
  struct KeyframeItem {
    KeyframeInput keyframe;
    std::vector<Loop> loops;
    KeyframeDone done;
  };
  struct LoopItem {
    Loop loop;
  };
  struct ForeignKeyframeItem {
    std::string vehicle;
    HashSettings settings;
    KeyframeInput keyframe;
    ForeignDone done;
  };
  struct ForeignEndItem {
    std::string vehicle;
    int remote_session = -1;
    double stamp_s = 0.0;
    Done done;
  };
  struct OptimiseItem {};
  using Item = std::variant<OptimiseItem, KeyframeItem, LoopItem, ForeignKeyframeItem, ForeignEndItem>;

  bool submit(Item item);
  void run();
  void process(Item& item) EXCLUDES(mutex_);
  /// `f` under the mutex (asynchronous: a throw counted and logged), then optimiseDueNow(). `f`
  /// is a lambda: it asserts the mutex held (the analysis does not follow the lock into it).
  template <typename F>
  void step(F f) EXCLUDES(mutex_);
  /// A loop's attempt: accepted, refused (logged) or waiting.
  void tryLoop(const Loop& loop) REQUIRES(mutex_);
  void optimiseDueNow() EXCLUDES(mutex_);
  void say(Severity s, const std::string& line) const;

  std::unique_ptr<SessionManager> owned_;
  SessionManager* manager_ PT_GUARDED_BY(mutex_);  // hasher() excepted: immutable
  const SessionWorkerOptions options_;
  const Log log_;
  mutable Mutex mutex_;
  std::deque<Loop> waiting_ GUARDED_BY(mutex_);
  AfterItem after_item_;  // set before the thread starts; read by it only

  mutable Mutex stats_mutex_ ACQUIRED_AFTER(mutex_);
  SessionWorkerStats stats_ GUARDED_BY(stats_mutex_);  // the queue's counters are the queue's

  BoundedWorkQueue<Item> queue_;  // asynchronous
  std::thread thread_;

  mutable Mutex handover_mutex_ ACQUIRED_AFTER(mutex_);
  std::vector<int> handed_ GUARDED_BY(handover_mutex_);
  HandoverStats handover_ GUARDED_BY(handover_mutex_);
};

}  // namespace core
}  // namespace uw_multislam
