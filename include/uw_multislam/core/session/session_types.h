// The types the session manager's requests, events and queries use: its options, a keyframe as
// it takes one, a session's summary, its events and counters (session_manager.h, session_queries.h).
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "uw_multislam/core/backend/backend.h"
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

/// Whether a session name is made only of digits: such a name would read as a session's id in
/// every request that takes a name or an id, so start_session refuses it.
bool nameIsAnId(const std::string& name);
/// The session name of a dataset folder (offline_slam): the folder as given, "./7" for a folder
/// named "7" (the same folder, and a name that is not an id).
std::string sessionNameOfFolder(const std::string& folder);

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
  /// `z` is the two keyframes' registration after a tracking loss (a visual bridge), not the nav's.
  bool visual = false;
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
  /// Keyframes naming a session this manager did not open for our odometry (past nextId(), or
  /// another vehicle's): refused, the newest held (SessionManager::addKeyframe).
  long keyframes_unopened = 0;
  long keyframe_jumps = 0;  // jumps past max_keyframe_gap that ended a piece (a new session from there)
  long nav_placements = 0;  // sessions placed in their predecessor's map by the nav (addNavPlacement)
  long visual_bridges = 0;  // pieces placed in their predecessor's map by a visual bridge (the same)
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

using SessionEventSink = std::function<void(const SessionEvent&)>;
using SessionLog = std::function<void(const std::string&)>;

}  // namespace core
}  // namespace uw_multislam
