// The session manager: the one object that owns sessions, their ids, maps, joins and splits, and
// the session store (README "Architecture"; cf. cartographer's MapBuilder).
//
// Both heads drive it through a SessionWorker (session_worker.h: its lock, work queue and
// optimisation loop): offline_slam through core::Pipeline (pipeline.h, every stage in one
// process) synchronously, and the back-end nodelet, which feeds it the Keyframe and Loop
// messages of the odometry and loop-detector nodelets, on the worker's thread. Nothing else
// starts a session, assigns an id or writes the store.
//
// One id space. A session's id is what services, messages, the store's rows as the user sees
// them, CSV outputs, rviz frames and logs call it. Sessions restored from the store take ids
// 0..k-1 in store order (the store's own row ids are remapped here and never leave this class);
// a live session takes the id its first keyframe names (the odometry continues from nextId(),
// which the back-end announces) or, from startSession, nextId(). Ids only grow, and never past
// kMaxSessionId: a keyframe, loop or request naming a larger (or negative) id is refused, so a
// corrupt message cannot make the ids wrap. A map is named by the id of its first session, its
// frame is that session's frame.
//
// What changed is reported through an EventSink: session started/ended, keyframe added, loop
// accepted/refused, maps joined/split, map optimised. The ROS layer turns events into messages
// and tf; offline_slam into log lines.
//
// Requests answer with a core::Status whose codes are Status.msg's; a request that fails changes
// nothing. Store writes that fail (disk full, I/O error) are counted and logged, never fatal: the
// map lives on in memory, and the next successful save of the maps writes it whole.
//
// Not thread-safe: one caller at a time (SessionWorker holds the lock every head takes).
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "uw_multislam/core/backend/backend.h"
#include "uw_multislam/core/common/status.h"
#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/frontend/features.h"
#include "uw_multislam/core/loops/haloc.h"
#include "uw_multislam/core/loops/loop_detector.h"
#include "uw_multislam/core/session/session_store.h"
#include "uw_multislam/core/session/slam_config.h"

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
  /// instead of bridging the gap with placeholder keyframes.
  int max_keyframe_gap = 1000;
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
const char* sessionStateName(SessionState s);

/// A keyframe as the session manager takes it (from the odometry, in process or by message).
struct KeyframeInput {
  int session = 0;
  int keyframe = 0;  // 0 is the session's origin
  int frame_index = 0;
  double stamp_s = 0.0;
  double altitude_m = 0.0;
  CameraIntrinsics camera;
  FrameFeatures features;               // may be empty (then nothing is stored to verify loops later)
  UncertainPose2 motion;                // X_k^{k-1} (1), ignored for keyframe 0
  MotionSource motion_source = MotionSource::kVisual;  // where `motion` came from
  Pose2 odometry_pose;                  // X_k^0 of the odometry chain
  Eigen::VectorXf hash;                 // the keyframe's hash; empty: the manager computes it (once)
  std::vector<std::uint8_t> thumbnail;  // small JPEG for the store, may be empty
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

class SessionManager {
 public:
  using EventSink = std::function<void(const SessionEvent&)>;
  using Log = std::function<void(const std::string&)>;

  /// Opens the store (if any), checks its hash settings and restores every stored session,
  /// loop and map (listed UNLOADED until reload()). Throws std::invalid_argument on bad options,
  /// StoreError on a store that cannot be used (the file is left untouched).
  SessionManager(const SessionManagerOptions& options, EventSink events = {}, Log log = {});
  ~SessionManager();
  SessionManager(const SessionManager&) = delete;
  SessionManager& operator=(const SessionManager&) = delete;

  // --- Requests ----------------------------------------------------------------------------
  /// Ends the active session and starts a new one, `id` or (-1) nextId(), named `name` (empty:
  /// "session_<id>"). ALREADY_EXISTS when the name is taken, INVALID_ARGUMENT for an id that is
  /// not new or past kMaxSessionId or the name longer than kMaxSessionNameLength, RESOURCE_EXHAUSTED when max_empty_sessions sessions in a row
  /// have no keyframe or no id is left. The session has its origin keyframe; the next keyframe 0
  /// given to it fills it in.
  Status startSession(const std::string& name, double stamp_s, int id = -1, int* started = nullptr);
  /// Stops the active session (its map may be optimised); the maps are saved.
  Status endSession(double stamp_s);
  /// A keyframe of the active session, or keyframe 0..k of a new session (ending the active one).
  /// A session id outside [0, kMaxSessionId] or a negative keyframe id is INVALID_ARGUMENT.
  /// `loops` (optional) are loops it closed, stored with it in one transaction (offline). A
  /// keyframe of an older session, or repeated, is FAILED_PRECONDITION (stale); lost keyframes
  /// (a gap in the ids) are bridged by placeholders that no loop may use, up to max_keyframe_gap.
  Status addKeyframe(const KeyframeInput& keyframe, const std::vector<Loop>& loops = {});
  /// Another vehicle's keyframe (the hash exchange between vehicles): `keyframe.session` is its id
  /// on that vehicle. The first keyframe of (vehicle, session) opens a session of this manager
  /// (nextId(), named "<vehicle>_session_<id>", local_id says which), which grows beside the
  /// active one: both are recording, each in its own map, until loops join them once one has
  /// ended (MultiSessionBackend::endSession). Only what crosses the link is kept: hash, motion,
  /// odometry pose, camera, altitude (features and image are dropped; the vehicle is asked for
  /// features when a loop needs them). Written to the store (without features, with provenance
  /// "fleet:<vehicle>") like any session, finished at endForeignSession or destruction. A name
  /// already taken (an earlier run's) gets _2, _3, ...; a keyframe 0 with another stamp for a
  /// session that records or has ended here is the vehicle starting over (a restart on a new
  /// store): the old one ends, a new one opens. Refused with nothing changed: INVALID_ARGUMENT
  /// (vehicle name not 1-64 of [A-Za-z0-9_-], ids, a gap past max_keyframe_gap),
  /// FAILED_PRECONDITION (stale: repeated or out of order, or the session ended).
  Status addForeignKeyframe(const std::string& vehicle, const KeyframeInput& keyframe, int* local_id = nullptr);
  /// That vehicle's session ended (its last keyframe sent): recording stops, postponed joins are
  /// tried. NOT_FOUND when it is not recording here. Later keyframes of it are refused.
  Status endForeignSession(const std::string& vehicle, int remote_session, double stamp_s);
  /// Ends every other vehicle's session still recording here (at its last keyframe's stamp), as
  /// endForeignSession; returns how many. The destructor does it too (a host whose event sink
  /// must still be alive calls it first).
  int finishForeignSessions();
  /// This manager's id of a vehicle's session while it records here, or -1.
  int foreignSession(const std::string& vehicle, int remote_session) const;
  /// The vehicle a session came from (empty: this vehicle's own), and its id there (-1: ours).
  const std::string& vehicleOf(int session) const { return at(session).vehicle; }
  int remoteIdOf(int session) const { return at(session).remote_id; }
  /// A loop in session ids. UNAVAILABLE-like answer through `waiting`: true when one of its
  /// keyframes has not arrived yet (try again after the next keyframe); else OK (accepted) or a
  /// refusal (FAILED_PRECONDITION / INVALID_ARGUMENT with the reason). A session id outside
  /// [0, kMaxSessionId] or a negative keyframe id is INVALID_ARGUMENT at once (never waiting).
  Status addLoop(const Loop& loop, bool* waiting = nullptr);
  /// The operator's manual link (add_link): a loop between two keyframes the manager holds (in
  /// memory or restored from the store), with the measured pose of b in a's frame and its
  /// covariance (`loop.z`) and the support it counts for in the join rule (`loop.inliers`, >= 0).
  /// Its kind follows the sessions (local inside one, global between two); it is then a loop like
  /// a detector's: stored, optimised, counted towards joins. Refused with nothing changed:
  /// INVALID_ARGUMENT (an id out of range, a keyframe linked to itself, a pose or covariance not
  /// finite, a covariance not symmetric positive definite, negative inliers), NOT_FOUND (an unknown
  /// session or keyframe), FAILED_PRECONDITION (a bridged keyframe that never arrived, or the
  /// back-end refusing the loop).
  Status addLink(Loop loop);
  /// addLink's checks, nothing changed: OK when addLink would take the link (unless the back-end
  /// refuses the loop).
  Status checkLink(const Loop& loop) const;
  /// addLink's checks of the two ends alone (ids, keyframes, a bridged keyframe, a keyframe linked
  /// to itself; codes as addLink's), for a caller that measures the link first (findStoredLink).
  Status checkLinkEnds(const Loop& loop) const;
  /// The operator's "optimise now": every map with loops waiting for optimisation (fewer than
  /// optimise_every) is optimised now, or (deferred) marked due. `maps`: how many.
  /// FAILED_PRECONDITION when optimisation is off (backend.optimise false).
  Status optimisePending(int* maps = nullptr);
  /// Localisation mode (set_mode): nothing is written to the store and no stored
  /// map changes, while sessions are still tracked. A session recording when it is switched on
  /// keeps what is stored and the rest in memory only; sessions started in it are memory only;
  /// neither is ever written later (a store keeps a prefix of each session). Automatic joins wait;
  /// join, split, add_link, optimise and detect_loops are refused (FAILED_PRECONDITION). Back in
  /// mapping mode everything goes on as before (the memory-only keyframes stay unstored).
  Status setLocalisation(bool on);
  bool localising() const { return localising_; }
  /// OK in mapping mode; in localisation mode the FAILED_PRECONDITION that refuses `what` (a
  /// request that would change a stored map).
  Status storedMapsMayChange(const std::string& what) const;
  /// Joins the maps of two sessions from the global loops between them (min_loops 0: K).
  /// INVALID_ARGUMENT for an id outside [0, kMaxSessionId], NOT_FOUND for an unknown one.
  Status join(int session_a, int session_b, int min_loops = 0);
  /// Splits a session off its map (INVALID_ARGUMENT, NOT_FOUND as join).
  Status split(int session);
  /// What reload() reads of a session's keyframes: everything (features, hash, thumbnail), the
  /// frame data and hashes only (paging: features are read later with storedFeatures), or nothing
  /// (the host hands the hashes over later with storedHashes, session by session).
  enum class ReloadRead { kFeatures, kHashes, kNothing };
  /// Brings a stored (UNLOADED) session back by name or id: its keyframes as `read` says, for the
  /// loop detector. NOT_FOUND, ALREADY_EXISTS (loaded), FAILED_PRECONDITION (no store), DATA_LOSS.
  Status reload(const std::string& name_or_id, ReloadedSession* out, ReloadRead read = ReloadRead::kFeatures);
  /// unload_session: a reloaded stored session goes back to UNLOADED, so the
  /// host drops its features from the loop detectors (it keeps its place in its map, its poses and
  /// loops; reload() brings it back). Nothing is lost: only sessions restored from the store,
  /// whose keyframes are all stored, qualify. NOT_FOUND (no such stored or recorded session),
  /// FAILED_PRECONDITION (no store, a session recorded in this run, already unloaded).
  Status unload(const std::string& name_or_id, int* id = nullptr);
  /// delete_session: removes a finished session alone in its map from the store
  /// (keyframes, motions, its loops, its map; one transaction) and from memory, for good. The ids
  /// of the others stay (a later restart numbers the stored sessions 0..k-1 again), ids are not
  /// reused. Recorded in the audit trail. Refused with nothing changed: NOT_FOUND,
  /// FAILED_PRECONDITION (no store, localisation mode, the recording session, a session sharing
  /// its map: split it off first, `confirm` false: the message says what would go), DATA_LOSS
  /// (the store could not be changed).
  Status deleteSession(const std::string& name_or_id, bool confirm, int* id = nullptr);
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
  /// Optimises every map with pending loops (now, also when deferred); saves the maps.
  void flush();

  // --- Deferred optimisation (the back-end nodelet) -----------------------------------------
  // With it on, requests never optimise: they leave the maps that need it due (backend.h,
  // "Deferred optimisation"). The host takes each due map's problem with nextOptimisation() under
  // its lock, solves it with solveOptimisation() without the lock (other requests and queries go
  // on meanwhile), and hands it back with applyOptimisation() under the lock again.
  void setDeferredOptimisation(bool on) { backend_->setDeferred(on); }
  /// The first due map's problem (its map in session ids), or nullopt when none is due.
  std::optional<MapOptimisation> nextOptimisation() const;
  static void solveOptimisation(MapOptimisation* o) { MultiSessionBackend::solveOptimisation(&o->job); }
  /// true: the result is in (kMapOptimised; the maps are saved when the map holds no recording
  /// session). false: the map changed while it was solved; nothing written, it is still due.
  bool applyOptimisation(const MapOptimisation& o);

  // --- What is there -----------------------------------------------------------------------
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
  const SessionManagerStats& stats() const { return stats_; }
  const BackendStats& backendStats() const { return backend_->stats(); }
  const SessionManagerOptions& options() const { return options_; }
  const ImageHasher& hasher() const { return hasher_; }
  /// The settings this manager's hashes are made with (HashSettings::compatible decides whether
  /// another vehicle's or a store's can be compared with them).
  HashSettings hashSettings() const;
  bool hasStore() const { return store_ != nullptr; }
  const std::string& storePath() const { return options_.store_path; }
  /// The store as replies name it: its file name only (the log keeps the full path).
  std::string storeName() const;
  int restoredSessions() const { return restored_sessions_; }
  /// The stored sessions made from these frames before (a dataset folder run into the store
  /// again): every keyframe of such a session is one of `frames`, same index and stamp (to 1 us).
  std::vector<int> storedSessionsOf(const std::vector<FrameRecord>& frames) const;

 private:
  struct Session {
    std::string name;
    int backend = -1;            // the back-end's index (private)
    std::int64_t store_id = -1;  // the store's row (private)
    CameraIntrinsics camera;
    std::vector<double> stamps;    // per keyframe
    std::vector<Pose2> odometry;   // X_k^0 per keyframe
    std::vector<int> frames;       // frame index per keyframe
    std::vector<MotionSource> sources;  // per keyframe, of the motion reaching it
    std::set<int> phantoms;        // keyframes that never arrived (bridged)
    bool origin_received = false;  // keyframe 0 arrived (not only start_session)
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
  void restore();
  /// Opens a session: this vehicle's (ends the active one, becomes active) or, with `vehicle`,
  /// another vehicle's `remote_id` (beside the active one).
  Status open(int id, const std::string& name, double stamp_s, const std::string& vehicle = "", int remote_id = -1);
  /// Appends keyframe k of an open session (k.session in this manager's ids) with its loops.
  Status appendKeyframe(KeyframeInput k, const std::vector<Loop>& loops);
  /// The session's store row (with its provenance when it is another vehicle's); sets store_id.
  void addStoreRow(Session& s, double stamp_s);
  /// Writes a keyframe with its motion and `loops` (converted to `stored`, whose ids are set).
  void storeKeyframe(Session& s, const KeyframeInput* k, int keyframe, const UncertainPose2* motion, double stamp_s,
                     const std::vector<Loop>* loops, std::vector<StoredLoop>* stored);
  /// Adds an accepted loop to the back-end (throws std::invalid_argument as the back-end does).
  void acceptLoop(const Loop& l);
  StoredLoop toStored(const Loop& l) const;
  /// After a back-end call: events for joins, splits and optimisations, and the maps saved when
  /// a join or split happened.
  void afterBackendChange();
  void saveMaps();
  /// The audit trail's next entry (its id, now), cause_ unless `cause` is given; not appended.
  HistoryEntry nextEntry(const std::string& kind, const std::string& sessions, const std::string& loops,
                         const std::string& message, const char* cause = nullptr) const;
  /// Appends to the audit trail (and the store, unless localising); cause_ unless `cause` is given.
  void record(const std::string& kind, const std::string& sessions, const std::string& loops,
              const std::string& message, const char* cause = nullptr);
  /// The back-end's joins and splits since the last call, into the audit trail.
  void recordMapChanges();
  /// "a,b,c" of back-end sessions, in session ids.
  std::string chainText(const std::vector<int>& backend_sessions) const;
  /// "a:ka>b:kb ..." of back-end loop ids.
  std::string loopsText(const std::vector<int>& backend_loops) const;
  template <typename F>
  bool storeWrite(const char* what, F write);
  void emit(SessionEvent::Kind kind, int session, int other, int map, const std::string& message) const;
  void say(const std::string& line) const;
  /// The newest sessions in a row that have no keyframe.
  int trailingEmptySessions() const;

  SessionManagerOptions options_;
  EventSink events_;
  Log log_;
  ImageHasher hasher_;
  std::unique_ptr<MultiSessionBackend> backend_;
  std::unique_ptr<SessionStore> store_;
  std::map<int, Session> sessions_;
  std::vector<int> id_of_backend_;         // back-end index -> session id
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
  int next_id_floor_ = 0;  // past every id given so far (a deleted session's id is not reused)
  std::set<int> deleted_;  // ids of sessions deleted in this run
  std::map<std::pair<std::string, int>, int> foreign_ids_;  // (vehicle, its session) recording here -> id
  std::map<std::pair<std::string, int>, int> ended_foreign_;  // ended in this run -> id: later keyframes refused
  int seen_joins_ = 0, seen_splits_ = 0, seen_optimisations_ = 0;
  SessionManagerStats stats_;
};

}  // namespace core
}  // namespace uw_multislam
