// Every stage of the mission in one process, around a SessionManager: what offline_slam runs
// (and what tests drive). The same components the nodelets host, composed in-process:
//   frames -> FrameStream (session/frame_stream.h: stamps, session starts, odometry, keyframes,
//             tracking loss, the keyframe's hash computed once, the nav's placement), the
//             front end the odometry nodelet drives too; the SessionManager gives its session ids
//          -> LoopDetector (loops/loop_detector.h: local and global loops), whose local search
//             trajectory comes from SessionChain::candidateTrajectory as in the loop nodelet
//          -> SessionManager (session_manager.h: sessions, ids, back-end, store, joins), driven
//             synchronously by a SessionWorker (session_worker.h: the same work items and
//             optimisation loop the back-end nodelet runs on its thread).
// A camera stream (a dataset folder, or a bag's camera) is begun, fed frame by frame and ended;
// tracking loss inside a stream closes its session and the next good frame starts another
// (named "<stream>#<piece>").
//
// With the nav (odometry.nav.enabled and nav.place_pieces) a new piece is placed by the nav in the
// map of the piece before it at its first keyframe (SegmentedOdometry's NavPlacement, handed to
// SessionManager::addNavPlacement), and so is the first session of a stream whose nav is in the
// same declared world frame (nav_frame.yaml) as an earlier stream's: against that stream's last
// keyframe with a nav reading, the two dead reckonings' errors taken as independent
// (navPlacement, not one track). Loops then refine the placement.
#pragma once

#include <opencv2/core.hpp>

#include <deque>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "uw_multislam/core/frontend/tracking.h"
#include "uw_multislam/core/loops/loop_detector.h"
#include "uw_multislam/core/loops/session_chain.h"
#include "uw_multislam/core/session/frame_stream.h"
#include "uw_multislam/core/session/session_manager.h"
#include "uw_multislam/core/session/session_worker.h"
#include "uw_multislam/core/session/slam_config.h"
#include "uw_multislam/core/store/keyframe_image.h"

namespace uw_multislam {
namespace core {

/// Hands every stored (UNLOADED) session of `manager` to `detector` (SessionManager::reload), so
/// that new keyframes find global loops against them; their cameras are appended to `cameras`
/// (the detector keeps pointers to them: a deque, never shrunk while the detector lives). Paged:
/// only hashes and ids go into RAM, features are read from the store (through the manager) when
/// a stored keyframe is a candidate, cached within loops.feature_cache_mb. `manager` must
/// outlive the detector. Returns the number of keyframes handed over. Throws StoreError.
int loadStoredSessions(SessionManager* manager, LoopDetector* detector, std::deque<CameraIntrinsics>* cameras);

class Pipeline {
 public:
  using Log = std::function<void(const std::string&)>;
  /// A stream's image of a frame index (for a keyframe's stored image, config `store`; may return empty).
  using ImageOf = std::function<cv::Mat(int frame_index)>;

  /// `worker` (synchronous: never started) must outlive the pipeline. Every stored session of
  /// its manager is reloaded into the loop detector, so that new keyframes find global loops
  /// against them. `log` receives one line per session piece and per tracking loss; `verbose`
  /// adds skipped and fallback frames.
  Pipeline(const SlamConfig& config, SessionWorker* worker, Log log = {}, bool verbose = true);
  /// The same with a synchronous worker of its own around `manager` (which must outlive the
  /// pipeline, and is driven with deferred optimisation from now on).
  Pipeline(const SlamConfig& config, SessionManager* manager, Log log = {}, bool verbose = true);

  /// `nav` (may be empty): the stream's dead-reckoned nav; each frame without a nav of its own
  /// gets the track's pose at its stamp (config odometry.nav.enabled). `nav_frame`: the declared
  /// world frame its nav is in (nav_frame.yaml), if any: streams in the same one are placed
  /// against each other.
  void beginStream(const std::string& name, const CameraIntrinsics& camera, ImageOf image_of = {}, NavTrack nav = {},
                   std::optional<NavFrame> nav_frame = std::nullopt);
  /// A dataset folder as a stream: named by its directory, its camera, its images read from the
  /// folder for the keyframes' stored images, its nav.csv as `nav`. `d` must outlive the stream.
  void beginStream(const Dataset& d);
  /// One frame of the current stream (`frame.nav`: its own nav, else the stream's track at its
  /// stamp). `prepared` (may be null): its image prepared ahead by another thread (a FramePreparer
  /// made by preparer()); the result is the same.
  FrameResult processFrame(const OdometryInput& frame, PreparedFrame* prepared = nullptr);
  /// A FramePreparer for the current stream's frames (its camera, the odometry's options), for a
  /// worker thread that prepares frames ahead (offline_slam --threads).
  FramePreparer preparer() const;
  /// Ends the stream (its open session ends at `stamp_s`).
  void endStream(double stamp_s);
  /// Optimises what is pending and saves the maps.
  void finish();
  /// The worker that drives the manager (the host's requests and queries go through it).
  SessionWorker& worker() { return *worker_; }

  /// The sessions begun for each stream, in order (several when tracking was lost).
  const std::vector<std::vector<int>>& streamSessions() const { return stream_sessions_; }
  const LoopDetector& loopDetector() const { return detector_; }
  /// The front end (its counts: stamps skipped, jumps, sessions, placements).
  const FrameStream& frames() const { return frames_; }
  /// Every stage's timing: odometry (all streams), hashing, loop detection, session manager.
  StageTimes times() const;

 private:
  Pipeline(const SlamConfig& config, SessionWorker* worker, std::unique_ptr<SessionWorker> own, Log log, bool verbose);
  // The hooks of the front end: a session opens (the manager gives its id) and ends.
  int startPiece(const SessionOpening& o);
  void endPiece(const SessionClosing& c);
  // One released keyframe: loops, the stored image, the manager.
  void addKeyframe(StreamKeyframe k, const OdometryInput& frame);
  void say(const std::string& line) const;

  SlamConfig config_;
  std::unique_ptr<SessionWorker> own_worker_;  // when made around a manager
  SessionWorker* worker_;
  Log log_;
  bool verbose_;
  LoopDetector detector_;
  std::deque<CameraIntrinsics> cameras_;  // the detector keeps pointers: never moved
  std::string stream_;
  CameraIntrinsics stream_camera_;  // the stream's camera, with its distortion
  ImageOf image_of_;
  NavTrack nav_;
  bool streaming_ = false;  // a stream is begun
  FrameStream frames_;
  SessionChain chain_;
  int session_ = -1;       // the manager's id of the stream's open piece; -1 while lost
  int read_failures_ = 0;  // the detector's feature_read_failures already logged
  int pieces_ = 0;
  long stream_frames_ = 0, stream_unreadable_ = 0;  // this stream's frames, and how many came without an image
  std::vector<std::vector<int>> stream_sessions_;
  StageTimes times_;
};

}  // namespace core
}  // namespace uw_multislam
