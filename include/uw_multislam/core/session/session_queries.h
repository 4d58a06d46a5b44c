// The session manager's read-only view (cf. cartographer's PoseGraph behind pose_graph()): every
// query about the sessions, their ids, maps, loops, the store and the audit trail. Reached by
// SessionManager::view(); the types the manager's requests and events use are declared here too.
// Like the manager, not thread-safe: the host's lock (SessionWorker) covers queries as well.
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "uw_multislam/core/backend/backend.h"
#include "uw_multislam/core/common/status.h"
#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/frontend/features.h"
#include "uw_multislam/core/loops/haloc.h"
#include "uw_multislam/core/loops/loop_detector.h"
#include "uw_multislam/core/session/slam_config.h"
#include "uw_multislam/core/store/session_store.h"

namespace uw_multislam {
namespace core {

/// The largest session id (a million sessions: far more than any fleet records). Keyframes and
/// loops naming a larger one are refused (INVALID_ARGUMENT), and so is start_session once
/// nextId() would pass it (RESOURCE_EXHAUSTED): ids never overflow an int.
constexpr int kMaxSessionId = 1000000;
/// The longest session name start_session accepts (bytes): names go into topics' and files'
/// names, the store and every reply (a 100 kB name was accepted before the limit).
constexpr std::size_t kMaxSessionNameLength = 256;

struct SessionManagerOptions {
  BackendOptions backend;
  /// The keyframe hashes (paper (6)(7)): the store keeps them and refuses other settings.
  HashMode hash_mode = HashMode::kSortedDct;
  std::uint64_t projection_seed = 20231122;
  int num_features = 500;
  /// The feature kind (odometry.features.type): the store records it and refuses another.
  FeatureType features = FeatureType::kSift;
  /// The session store (SQLite); empty: sessions live in memory only.
  std::string store_path;
  /// A cap on the store file (MB; 0: none): writes past it fail as on a full disk, counted
  /// (store_failures) and logged, and the manager goes on in memory (SessionStore::setMaxBytes).
  double store_max_mb = 0.0;
  /// A keyframe id further than this past the expected one is refused (a corrupt message),
  /// instead of bridging the gap with placeholder keyframes. Small: each placeholder is a stored
  /// row and a transaction (about 17 kB with the WAL), so one message may cost the store at most
  /// this many of them (32: 0.66 MB per message measured; 1000 had let 10 messages grow a store
  /// by 67 MB).
  int max_keyframe_gap = 32;
  /// startSession is refused (RESOURCE_EXHAUSTED) while this many sessions in a row, the newest
  /// ones, have no keyframe yet (start_session in a loop must not pile up empty sessions); 0: no
  /// limit (offline_slam, whose sessions always start from a keyframe).
  int max_empty_sessions = 0;
  /// The cause the audit trail gives the requests (join, split, add_link, mode changes): "tool"
  /// (offline_slam and the other tools) or "service" (the back-end nodelet's services); joins
  /// the rule makes by itself are "automatic".
  std::string requester = "tool";

  std::string validate() const;
};

/// The manager's options from the SLAM configuration (back-end, hash settings) and a store path.
SessionManagerOptions sessionManagerOptions(const SlamConfig& config, const std::string& store_path);

/// A vehicle's name as the hash exchange takes it (it goes into session names, the store, logs):
/// 1 to 64 characters of A-Z a-z 0-9 _ -.
bool validVehicleName(const std::string& vehicle);

enum class SessionState { kActive, kFinished, kUnloaded };

/// A keyframe as the session manager takes it (from the odometry, in process or by message).
/// The nav's placement of a session's first keyframe (SessionManager::addNavPlacement): the earlier
/// keyframe it is placed against and the first keyframe's pose in that keyframe's frame, with the
/// nav's covariance over the stretch between them (nav_prior.h navPlacement).
struct NavPlacementInput {
  int session = -1, keyframe = -1;
  UncertainPose2 z;
};

struct KeyframeInput {
  int session = 0;
  int keyframe = 0;  // 0 is the session's origin
  int frame_index = 0;
  double stamp_s = 0.0;
  double altitude_m = 0.0;
  CameraIntrinsics camera;
  FrameFeatures features;                              // may be empty (then nothing is stored to verify loops later)
  UncertainPose2 motion;                               // X_k^{k-1} (1), ignored for keyframe 0
  MotionSource motion_source = MotionSource::kVisual;  // where `motion` came from
  Pose2 odometry_pose;                                 // X_k^0 of the odometry chain
  Eigen::VectorXf hash;                                // the keyframe's hash; empty: the manager computes it (once)
  std::vector<std::uint8_t> thumbnail;                 // small JPEG for the store, may be empty
  /// Keyframe 0 of a piece or session the nav places (offline: core::Pipeline; live: the Keyframe
  /// message's placement): the SessionWorker hands it to addNavPlacement once the keyframe is in.
  std::optional<NavPlacementInput> nav_placement = std::nullopt;
};

struct SessionSummary {
  int id = 0;
  std::string name;
  std::string vehicle;  // another vehicle's session (hash exchange): its name; empty: ours
  SessionState state = SessionState::kFinished;
  int map = 0;
  int keyframes = 0;
  int loops = 0;
  double first_stamp_s = 0.0, last_stamp_s = 0.0;
};

/// A link of a map in session ids.
struct SessionLink {
  int map = 0, previous = 0, current = 0, loops = 0;
  UncertainPose2 measured;
  Pose2 estimate;
};

struct SessionEvent {
  enum class Kind {
    kSessionStarted,
    kSessionEnded,
    kKeyframeAdded,
    kLoopAccepted,
    kLoopRefused,
    kMapsJoined,
    kMapSplit,
    kMapOptimised
  };
  Kind kind = Kind::kKeyframeAdded;
  int session = -1;  // the session concerned (a loop's new keyframe's session; a join's second session)
  int other = -1;    // a loop's or a join's other session
  int map = -1;
  std::string message;
  std::string vehicle;  // kSessionStarted/kSessionEnded: another vehicle's session, its name (empty: ours)
};
const char* sessionEventName(SessionEvent::Kind k);

struct SessionManagerStats {
  long keyframes = 0, keyframes_stale = 0, keyframes_refused = 0, keyframe_gaps = 0;
  long keyframe_jumps = 0;  // jumps past max_keyframe_gap that ended a piece (a new session from there)
  long nav_placements = 0;  // sessions placed in their predecessor's map by the nav (addNavPlacement)
  long loops = 0, loops_refused = 0;
  long store_failures = 0;
};

/// A stored session's keyframes, as reload() hands them back (for the loop detector).
struct ReloadedSession {
  int id = -1;
  CameraIntrinsics camera;
  std::vector<StoredKeyframe> keyframes;
};

/// A due map's optimisation problem, taken out of the manager (deferred optimisation).
struct MapOptimisation {
  int map = -1;  // the map's id (its first session)
  OptimisationJob job;
};

class SessionQueries {
 public:
  using EventSink = std::function<void(const SessionEvent&)>;
  using Log = std::function<void(const std::string&)>;

  // --- Sessions and ids ---------------------------------------------------------------------
  std::vector<SessionSummary> list() const;
  bool has(int session) const { return sessions_.count(session) > 0; }
  /// Whether the session has received a keyframe (false for one start_session opened that no
  /// keyframe has followed yet; true for the stored ones).
  bool hasKeyframe(int session) const { return at(session).origin_received; }
  std::vector<int> sessionIds() const;
  int activeSession() const { return active_; }
  /// The id the next new session takes (one past the largest so far).
  int nextId() const { return std::max(next_id_floor_, sessions_.empty() ? 0 : sessions_.rbegin()->first + 1); }
  const std::string& name(int session) const { return at(session).name; }
  /// The camera its keyframes were made with (the store's, for a stored session).
  const CameraIntrinsics& camera(int session) const { return at(session).camera; }
  /// The session named `name`, or -1.
  int idOfName(const std::string& name) const;
  /// The session a request names: by its name first (names are unique), else by its id in
  /// decimal digits (a session named "3" is not session 3); -1 when none. Every service and tool
  /// that takes a name or an id resolves it here.
  int findSession(const std::string& name_or_id) const;
  /// The vehicle a session came from (empty: this vehicle's own), and its id there (-1: ours).
  const std::string& vehicleOf(int session) const { return at(session).vehicle; }
  int remoteIdOf(int session) const { return at(session).remote_id; }
  /// This manager's id of a vehicle's session while it records here, or -1.
  int foreignSession(const std::string& vehicle, int remote_session) const;
  /// How many sessions were restored from the store.
  int restoredSessions() const { return restored_sessions_; }
  /// Whether the session was restored from the store (not recorded in this run). Its id is its
  /// store id, and this run's sessions take ids past every stored one (firstNewId() on).
  bool restored(int session) const { return session < first_new_id_ && has(session); }
  /// The first id this run gives: past every id the store holds or held (deleted sessions).
  int firstNewId() const { return first_new_id_; }
  /// The stored sessions made from these frames before (a dataset folder run into the store
  /// again): every keyframe of such a session is one of `frames`, same index and stamp (to 1 us).
  std::vector<int> storedSessionsOf(const std::vector<FrameRecord>& frames) const;

  // --- Maps and poses -----------------------------------------------------------------------
  int mapOf(int session) const;
  std::vector<int> mapIds() const;
  /// The session's keyframe poses in its map's frame, and in its own frame.
  std::vector<Pose2> poses(int session) const;
  std::vector<Pose2> posesInSessionFrame(int session) const;
  /// The session's last keyframe in its map's frame with its covariance (MultiSessionBackend::keyframeInMap).
  UncertainPose2 lastKeyframeInMap(int session) const;
  /// The odometry's poses of the session's keyframes (X_k^0 as received).
  const std::vector<Pose2>& odometryPoses(int session) const { return at(session).odometry; }
  const std::vector<double>& stamps(int session) const { return at(session).stamps; }
  const std::vector<int>& frames(int session) const { return at(session).frames; }
  /// Where each keyframe's odometry motion came from ([0], the origin: kVisual).
  const std::vector<MotionSource>& motionSources(int session) const { return at(session).sources; }
  /// map <- odometry correction of the session: its last pose in the map times the inverse of its
  /// last odometry pose.
  Pose2 correction(int session) const;
  /// Relocalisation: the session in a stored map before or without a join
  /// (MultiSessionBackend::relocalise, the consistency rule), in session ids; nullopt when no
  /// map holding a session restored from the store has loops that pass it, or the session is
  /// unknown. (Maps of this run's sessions only join as usual.) Changes nothing; works in
  /// localisation mode.
  struct Relocalisation {
    int map = -1;                // the other map (its first session's id)
    int loops = 0, inliers = 0;  // the consistent set's
    int keyframe = -1;           // the session's last keyframe
    UncertainPose2 pose;         // that keyframe in `map`'s frame
    Pose2 correction;            // `map` <- the session's odometry frame (as correction())
  };
  std::optional<Relocalisation> relocalise(int session) const;

  // --- Loops, links, the audit trail ---------------------------------------------------------
  std::vector<SessionLink> links() const;
  /// The audit trail: every join, split, manual link and mode change, restored
  /// from the store and then this run's, in order (session_store.h, HistoryEntry). Written to the
  /// store as it happens, except in localisation mode (the store must stay byte-identical): the
  /// mode change itself is recorded when mapping resumes. Without a store it lives in memory.
  const std::vector<HistoryEntry>& history() const { return history_; }
  /// The accepted loops (session ids), in order, restored ones first.
  const std::vector<Loop>& loops() const { return loops_; }
  /// Whether loops()[i] was refused by the back-end (inconsistent at a join, or gated inside a map).
  bool loopRefused(std::size_t i) const;
  /// addLink's checks, nothing changed: OK when addLink would take the link (unless the back-end
  /// refuses the loop).
  Status checkLink(const Loop& loop) const;
  /// addLink's checks of the two ends alone (ids, keyframes, a bridged keyframe, a keyframe linked
  /// to itself; codes as addLink's), for a caller that measures the link first (findStoredLink).
  Status checkLinkEnds(const Loop& loop) const;
  bool localising() const { return localising_; }
  /// OK in mapping mode; in localisation mode the FAILED_PRECONDITION that refuses `what` (a
  /// request that would change a stored map).
  Status storedMapsMayChange(const std::string& what) const;

  // --- The store -----------------------------------------------------------------------------
  bool hasStore() const { return store_ != nullptr; }
  const std::string& storePath() const { return options_.store_path; }
  /// The store as replies name it: its file name only (the log keeps the full path).
  std::string storeName() const;
  /// One keyframe as the store keeps it (points, descriptors): of a session restored from the
  /// store (paging), or of this run's sessions once written (add_link's "find it").
  /// Throws StoreError: no store, a keyframe not in the store (not yet, or kept in memory only),
  /// a missing or corrupt one.
  StoredKeyframe storedFeatures(int session, int keyframe) const;
  /// Whether the keyframe is in the store (storedFeatures can read it).
  bool inStore(int session, int keyframe) const { return store_ != nullptr && keyframeStored(session, keyframe); }
  /// A stored session's keyframes with their frame data and hashes only (no features), without
  /// reloading it. Throws StoreError as storedFeatures.
  std::vector<StoredKeyframe> storedHashes(int session) const;

  // --- Settings and counters ---------------------------------------------------------------
  const SessionManagerStats& stats() const { return stats_; }
  const BackendStats& backendStats() const { return backend_->stats(); }
  const SessionManagerOptions& options() const { return options_; }
  const ImageHasher& hasher() const { return hasher_; }
  /// The settings this manager's hashes are made with (HashSettings::compatible decides whether
  /// another vehicle's or a store's can be compared with them).
  HashSettings hashSettings() const;

 protected:
  /// Opens nothing: SessionManager's constructor opens the store and restores it.
  SessionQueries(const SessionManagerOptions& options, EventSink events, Log log);
  ~SessionQueries() = default;
  SessionQueries(const SessionQueries&) = delete;
  SessionQueries& operator=(const SessionQueries&) = delete;

  struct Session {
    std::string name;
    int backend = -1;            // the back-end's index (private)
    std::int64_t store_id = -1;  // the store's row (private)
    CameraIntrinsics camera;
    std::vector<double> stamps;         // per keyframe
    std::vector<Pose2> odometry;        // X_k^0 per keyframe
    std::vector<int> frames;            // frame index per keyframe
    std::vector<MotionSource> sources;  // per keyframe, of the motion reaching it
    std::set<int> phantoms;             // keyframes that never arrived (bridged)
    bool origin_received = false;       // keyframe 0 arrived (not only start_session)
    bool unloaded = false;
    int loops = 0;
    // The store keeps a prefix 0..stored-1 of the keyframes: after a failed keyframe write
    // (store_cut) the later ones are not written either (a gap would make the store unrestorable).
    int stored = 0;
    bool store_cut = false;
    bool memory_only = false;  // keyframes from `stored` on are not written: localisation mode
    std::string vehicle;       // another vehicle's session: its name (empty: ours)
    int remote_id = -1;        // and its id there
  };
  /// Whether the keyframe is in the store (or `pending`: written in the same transaction).
  bool keyframeStored(int session, int keyframe, int pending_session = -1, int pending_keyframe = -1) const;
  const Session& at(int session) const;
  Session& at(int session);
  int idOfBackend(int backend_session) const { return id_of_backend_.at(backend_session); }
  /// "a,b,c" of back-end sessions, in session ids.
  std::string chainText(const std::vector<int>& backend_sessions) const;
  /// "a:ka>b:kb ..." of back-end loop ids.
  std::string loopsText(const std::vector<int>& backend_loops) const;
  void emit(SessionEvent::Kind kind, int session, int other, int map, const std::string& message) const;
  void say(const std::string& line) const;
  /// The newest sessions in a row that have no keyframe.
  int trailingEmptySessions() const;

  // The state: SessionManager changes it, this class only reads it.
  SessionManagerOptions options_;
  EventSink events_;
  Log log_;
  ImageHasher hasher_;
  std::unique_ptr<MultiSessionBackend> backend_;
  std::unique_ptr<SessionStore> store_;
  std::map<int, Session> sessions_;
  std::vector<int> id_of_backend_;  // back-end index -> session id
  bool localising_ = false;
  std::vector<std::int64_t> store_loops_;  // back-end loop index -> store loop id (-1: not stored)
  std::vector<Loop> loops_;                // accepted loops, session ids
  std::vector<HistoryEntry> history_;      // the audit trail
  std::ptrdiff_t history_restored_ = 0;    // its entries from earlier runs (the first ones)
  const char* cause_ = "automatic";        // of the joins and splits recordMapChanges finds
  bool hold_changes_ = false;              // afterBackendChange leaves them to the caller
  std::string localising_since_;           // when localisation mode began (UTC), for its entry
  int active_ = -1;
  int restored_sessions_ = 0;
  int first_new_id_ = 0;   // nextId() once the store is restored: ids below it are stored sessions'
  int next_id_floor_ = 0;  // past every id given so far (a deleted session's id is not reused)
  std::set<int> deleted_;  // ids of sessions deleted in this run
  std::map<std::pair<std::string, int>, int> foreign_ids_;    // (vehicle, its session) recording here -> id
  std::map<std::pair<std::string, int>, int> ended_foreign_;  // ended in this run -> id: later keyframes refused
  int seen_joins_ = 0, seen_splits_ = 0, seen_optimisations_ = 0;
  SessionManagerStats stats_;
};

}  // namespace core
}  // namespace uw_multislam
