// The session manager's read-only view (cf. cartographer's PoseGraph behind pose_graph()): every
// query about the sessions, their ids, maps, loops, the store and the audit trail, answered from
// the manager's state (session_table.h), which it never changes. Reached by SessionManager::view();
// the types the manager's requests and events use: session_types.h.
// Like the manager, not thread-safe: the host's lock (SessionWorker) covers queries as well.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "uw_multislam/core/common/status.h"
#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/session/session_table.h"
#include "uw_multislam/core/session/session_types.h"

namespace uw_multislam {
namespace core {

class SessionQueries {
 public:
  using EventSink = SessionEventSink;
  using Log = SessionLog;

  /// A view of `table`, which must outlive it.
  explicit SessionQueries(const SessionTable& table) : t_(table) {}
  SessionQueries(const SessionQueries&) = delete;
  SessionQueries& operator=(const SessionQueries&) = delete;

  // --- Sessions and ids ---------------------------------------------------------------------
  std::vector<SessionSummary> list() const;
  bool has(int session) const { return t_.has(session); }
  /// Whether the session has received a keyframe (false for one start_session opened that no
  /// keyframe has followed yet; true for the stored ones).
  bool hasKeyframe(int session) const { return t_.at(session).origin_received; }
  std::vector<int> sessionIds() const;
  int activeSession() const { return t_.active(); }
  /// The id the next new session takes (one past the largest so far).
  int nextId() const { return t_.nextId(); }
  const std::string& name(int session) const { return t_.at(session).name(); }
  /// The camera its keyframes were made with (the store's, for a stored session).
  const CameraIntrinsics& camera(int session) const { return t_.at(session).camera; }
  /// The session named `name`, or -1.
  int idOfName(const std::string& name) const { return t_.idOfName(name); }
  /// The session a request names: digits only, by its id (no name is made only of digits; a
  /// session an older store named "3" is found by that name when no session 3 exists); anything
  /// else, by its name (names are unique); -1 when none. Every service and tool that takes a name
  /// or an id resolves it here.
  int findSession(const std::string& name_or_id) const { return t_.findSession(name_or_id); }
  /// The vehicle a session came from (empty: this vehicle's own), and its id there (-1: ours).
  const std::string& vehicleOf(int session) const { return t_.at(session).vehicle(); }
  int remoteIdOf(int session) const { return t_.at(session).remoteId(); }
  /// This manager's id of a vehicle's session while it records here, or -1.
  int foreignSession(const std::string& vehicle, int remote_session) const {
    return t_.foreignSession(vehicle, remote_session);
  }
  /// How many sessions were restored from the store.
  int restoredSessions() const { return t_.restoredSessions(); }
  /// Whether the session was restored from the store (not recorded in this run). Its id is its
  /// store id, and this run's sessions take ids past every stored one (firstNewId() on).
  bool restored(int session) const { return t_.restored(session); }
  /// The first id this run gives: past every id the store holds or held (deleted sessions).
  int firstNewId() const { return t_.firstNewId(); }
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
  /// A keyframe of the session in its map's frame, with the covariance of the odometry chain from
  /// the map's origin (MultiSessionBackend::keyframeInMap).
  UncertainPose2 keyframeInMap(int session, int keyframe) const;
  /// Keyframe `to` in keyframe `from`'s frame (from <= to) with the chain's covariance between them
  /// (MultiSessionBackend::keyframeChain).
  UncertainPose2 keyframeChain(int session, int from, int to) const;
  /// The odometry's poses of the session's keyframes (X_k^0 as received).
  const std::vector<Pose2>& odometryPoses(int session) const { return t_.at(session).odometry; }
  const std::vector<double>& stamps(int session) const { return t_.at(session).stamps; }
  /// The position priors the back-end holds (addPositionPrior), `session` in these ids, each in
  /// the current frame of its map.
  std::vector<PriorRecord> positionPriors() const;
  const std::vector<int>& frames(int session) const { return t_.at(session).frames; }
  /// Where each keyframe's odometry motion came from ([0], the origin: kVisual).
  const std::vector<MotionSource>& motionSources(int session) const { return t_.at(session).sources; }
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
  const std::vector<HistoryEntry>& history() const { return t_.history(); }
  /// The accepted loops (session ids), in order, restored ones first.
  const std::vector<Loop>& loops() const { return t_.loops(); }
  /// Whether loops()[i] was refused by the back-end (inconsistent at a join, or gated inside a map).
  bool loopRefused(std::size_t i) const;
  /// addLink's checks, nothing changed: OK when addLink would take the link (unless the back-end
  /// refuses the loop). Besides the ends, the pose and the inliers, the link's length: at most
  /// linkReach (a longer one is no link the maps could hold; the reply says the bound).
  Status checkLink(const Loop& loop) const;
  /// How far apart two keyframes a link joins can be: the extent of the map of each (the
  /// diagonal of its keyframes' box; one map counted once) and what the two cameras see around
  /// their keyframes (altitude x the image's half diagonal in focal lengths). `why` (optional):
  /// the terms in words.
  double linkReach(int session_a, int keyframe_a, int session_b, int keyframe_b, std::string* why = nullptr) const;
  /// The diagonal of the box of a map's keyframes (in its frame), m.
  double mapExtent(int map) const;
  /// addLink's checks of the two ends alone (ids, keyframes, a bridged keyframe, a keyframe linked
  /// to itself; codes as addLink's), for a caller that measures the link first (findStoredLink).
  Status checkLinkEnds(const Loop& loop) const;
  bool localising() const { return t_.localising(); }
  /// OK in mapping mode; in localisation mode the FAILED_PRECONDITION that refuses `what` (a
  /// request that would change a stored map).
  Status storedMapsMayChange(const std::string& what) const;

  // --- The store -----------------------------------------------------------------------------
  bool hasStore() const { return t_.store() != nullptr; }
  /// The datum the store keeps (SessionManager::storeDatum), nullopt without one or without a
  /// store. Throws StoreError on a store that cannot be read.
  std::optional<std::string> storedDatum() const {
    return t_.store() ? t_.store()->datum() : std::optional<std::string>();
  }
  const std::string& storePath() const { return t_.options().store_path; }
  /// The store as replies name it: its file name only (the log keeps the full path).
  std::string storeName() const;
  /// One keyframe as the store keeps it (points, descriptors): of a session restored from the
  /// store (paging), or of this run's sessions once written (add_link's "find it").
  /// Throws StoreError: no store, a keyframe not in the store (not yet, or kept in memory only),
  /// a missing or corrupt one.
  StoredKeyframe storedFeatures(int session, int keyframe) const;
  /// Whether the keyframe is in the store (storedFeatures can read it).
  bool inStore(int session, int keyframe) const { return hasStore() && t_.keyframeStored(session, keyframe); }
  /// A stored session's keyframes with their frame data and hashes only (no features), without
  /// reloading it. Throws StoreError as storedFeatures.
  std::vector<StoredKeyframe> storedHashes(int session) const;

  // --- Settings and counters ---------------------------------------------------------------
  const SessionManagerStats& stats() const { return t_.stats(); }
  const BackendStats& backendStats() const { return t_.backend().stats(); }
  const SessionManagerOptions& options() const { return t_.options(); }
  const ImageHasher& hasher() const { return t_.hasher(); }
  /// The settings this manager's hashes are made with (HashSettings::compatible decides whether
  /// another vehicle's or a store's can be compared with them).
  HashSettings hashSettings() const;

 private:
  const SessionTable& t_;
};

}  // namespace core
}  // namespace uw_multislam
