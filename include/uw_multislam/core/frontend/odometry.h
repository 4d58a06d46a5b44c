// Visual odometry of one session (paper 000 §5): each frame is matched against the last
// keyframe; RANSAC (Algorithm 1) gives the motion in metres, scaled by the altitudes; keyframes
// are chosen by footprint overlap, rotation, time and match strength; the keyframe trajectory
// is a chain of relative motions with covariances ((1), core/geometry/trajectory.h).
//
// Keyframe rule: the current frame becomes a keyframe when its footprint overlaps the last
// keyframe's by less than keyframes.min_overlap, when it has turned by more than
// max_rotation_rad, when max_interval_s has passed (if set), or when fewer than
// min_tracking_inliers matches support the motion (the match is getting weak).
//
// Failure handling: when the frame cannot be matched to the last keyframe, the last frame that
// was tracked is promoted to keyframe and the match is tried again against it. If that fails
// too, the dense pass registers the two again (options.dense, core/frontend/dense_match.h: many
// more features on flat-field normalised images, accepted by the overlap its motion predicts and
// its inliers' spread); a frame it matches becomes a keyframe. If that fails as well (or there is
// no keyframe to try) the frame is unmatched (status kFallback, counted). It is
// bridged: it gets no keyframe and no motion, only a predicted pose to report, and the next frame
// is matched to the last keyframe (the frame before it, promoted), with which it still overlaps
// when consecutive frames overlap by more than half. When the next frame does not register with
// the last keyframe either, it is tried against the unmatched frame before it (normal, then
// dense): if the two register, the chain breaks between the session and that frame, and rather
// than fail every following frame against a keyframe that falls further behind, the session ends
// there (OdometryUpdate::restart_index) and SegmentedOdometry starts the next one at the
// unmatched frame (restartFrames()), no frame lost. A reused motion is a guess that is wrong
// whenever the vehicle changed its step (a metre-sized kink in a smooth real track), so none is
// made while bridging. Only after fallback.bridge_frames consecutive unmatched frames is the
// previous frame-to-frame motion reused, as the paper does (§5): the frame becomes a keyframe
// whose motion is marked as a fallback, with the fallback covariance; with the default
// tracking.max_fallbacks the session has ended before that (tracking loss: a new piece), so
// reuse is what a session that must never end (max_fallbacks 0) falls back on.
//
// Navigation prior (core/frontend/nav_prior.h), when the input carries the vehicle's
// dead-reckoned nav and options.nav.enabled: (a) RANSAC's 2-point hypotheses far from the nav's
// motion (the same chi-square gate, with the hypothesis's own noise added) are not scored, so a
// repetitive seabed cannot lead the consensus astray (nav.gate_ransac); (c) every visual motion is compared with the
// nav's motion over the same interval by a chi-square gate; a motion that fails is refused (counted, the reason in the
// update) and the nav's motion used instead; with nav.fuse a motion that passes is combined with the nav's. (b) With
// on_tracking_loss dead_reckoning a frame that cannot be matched is carried by the nav's motion (not a fallback: the
// session goes on); such a frame becomes a keyframe when the nav-predicted footprint overlap drops below
// keyframes.min_overlap, it turned by more than max_rotation_rad, or it has nav.min_features_to_restart features while
// the last keyframe has fewer (a blank): so vision restarts at the first good frame. Without
// nav every frame is processed exactly as before. Every keyframe's motion has its source.
//
// Tracking between keyframes (options.klt.enabled; core/frontend/klt_tracker.h): each frame after
// a keyframe is first tracked by KLT from the keyframe's corners; its motion comes from the same
// RANSAC (with the altitude scale, the nav prior's gating and the nav gate) on the tracked pairs.
// When that motion exists, passes the nav gate and the keyframe rule would not take the frame,
// the frame is tracked without SIFT. Otherwise (too few tracks, RANSAC fails, a keyframe is due
// by overlap, rotation, time or inliers, the nav refuses it) the frame goes the full way above:
// SIFT, matching to the keyframe, the keyframe rule, promotion and fallback as documented; so
// every keyframe's motion is still measured by SIFT matching. A promotion needs the promoted
// frame's features: they are extracted then from its kept image. Tracks start only at a keyframe
// with a measured motion (not a fallback, not carried by the nav) and at least klt.min_tracks SIFT
// features; after any other new keyframe (promoted, fallback, the nav's) frames go the full way
// until the next such keyframe, so tracking loss is detected as without KLT.
//
// Distortion: features are extracted on the raw image and only their coordinates are undistorted
// (core/frontend/camera_model.h); from there on, and in the keyframes, the camera is the pinhole
// featureCamera().
//
// Bad input: an empty image, one of another size than the camera's or of an unsupported type is
// skipped and counted (with the reason in the update); a non-finite or non-positive altitude is
// replaced by the last valid one (counted), or the frame is skipped when there is none yet.
#pragma once

#include <opencv2/core.hpp>

#include <cmath>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "uw_multislam/core/common/stage_timer.h"
#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/frontend/dense_match.h"
#include "uw_multislam/core/frontend/enhancement.h"
#include "uw_multislam/core/frontend/features.h"
#include "uw_multislam/core/frontend/klt_tracker.h"
#include "uw_multislam/core/frontend/matching.h"
#include "uw_multislam/core/frontend/nav_prior.h"
#include "uw_multislam/core/frontend/pair_motion.h"
#include "uw_multislam/core/frontend/rigid_ransac.h"
#include "uw_multislam/core/geometry/trajectory.h"

namespace uw_multislam {
namespace core {

struct KeyframeOptions {
  double min_overlap = 0.5;       // fraction of the current footprint seen by the last keyframe
  double max_rotation_rad = 0.5;  // turned since the last keyframe
  /// At least one keyframe this often (0 = no time limit). The overlap rule alone took none for
  /// 150 s while a real ROV hovered at a turn (11 frames, 13-15 s apart), and the revisits among
  /// those frames (50 of the survey's 148 ground-truth pairs) could not be found as loops. 10 s
  /// costs nothing at video rates while the vehicle moves (the overlap rule fires first) and keeps
  /// every frame of a still camera that shoots less often.
  double max_interval_s = 10.0;
  int min_tracking_inliers = 40;  // fewer inliers than this: take a keyframe while matching works

  /// The rule's geometric and time tests for a frame at `overlap` with the last keyframe, turned by
  /// `yaw_rad` from it, `since_keyframe_s` after it (the inlier test is the matcher's, apart): one
  /// rule for the odometry's decision, its lookahead and FrameSkipRule's prediction.
  bool takes(double overlap, double yaw_rad, double since_keyframe_s) const {
    return overlap < min_overlap || std::abs(yaw_rad) > max_rotation_rad ||
           (max_interval_s > 0 && since_keyframe_s > max_interval_s);
  }
  std::string validate() const;
};

/// Constant velocity: `pose` moved on by `f` times `step` (its x, y and yaw scaled alike), the
/// prediction of a frame `f` steps after `pose` (FrameSkipRule, the odometry's keyframe lookahead).
inline Pose2 extrapolate(const Pose2& pose, const Pose2& step, double f) {
  return compose(pose, Pose2(f * step.x(), f * step.y(), f * step.yaw()));
}

struct FallbackOptions {
  /// Covariance of a reused motion: sigma_xy = max(min_sigma_m, relative_sigma * |step|),
  /// sigma_yaw = sigma_yaw_rad. Large on purpose: loops must be able to correct it.
  double min_sigma_m = 0.05;
  double relative_sigma = 0.5;
  double sigma_yaw_rad = 0.1;
  /// Consecutive unmatched frames bridged (no keyframe, no motion) before the previous motion is
  /// reused; 0: reuse at once (the paper's §5).
  int bridge_frames = 5;

  std::string validate() const;
};

struct OdometryOptions {
  /// CLAHE by default: on the generated hazy mission it takes the odometry from 58 fallbacks
  /// in 158 frames to none (end drift 47.7 % -> 0.09 %), costs about a millisecond, and changes
  /// nothing measurable on clear water (README benchmark). Dehazing adds ~5 ms for no further
  /// gain on our missions.
  EnhancementOptions enhancement{EnhancementMode::kClahe};
  FeatureOptions features;
  MatchOptions matching;
  RansacOptions ransac;
  KeyframeOptions keyframes;
  FallbackOptions fallback;
  NavPriorOptions nav;      // used only for frames that carry a nav pose
  KltOptions klt;           // tracking between keyframes (off: SIFT on every frame)
  DenseMatchOptions dense;  // the denser registration tried where the normal one fails
  /// An altitude above this is not a reading a bottom-looking camera can use (a glitch, 1e308, a
  /// sensor's "no bottom" value such as 9999): treated as missing, the last valid one reused and
  /// counted (stats altitude_out_of_range). The live node also drops readings outside the
  /// altimeter's own range.
  double max_altitude_m = 200.0;

  /// Empty when usable, else a sentence naming the component and value.
  std::string validate() const;
};

struct OdometryInput {
  int index = 0;
  double stamp_s = 0.0;
  double altitude_m = 0.0;
  cv::Mat image;  // 8-bit BGR or grey
  /// The vehicle's dead-reckoned nav at stamp_s (frame and conventions of gt.csv), if any.
  std::optional<NavRecord> nav = std::nullopt;
  /// > 0: the frames within this span (s of stamps) after this one will not be processed before a
  /// newer one (a live odometry behind its camera, taking the newest frame: they arrive while this
  /// one is processed, core/frontend/frame_skip.h). If the keyframe rule would take one of them,
  /// predicted at this frame's velocity, this frame becomes the keyframe now (counted in
  /// early_keyframes): earlier, at a higher overlap, rather than at a frame that would wait behind
  /// a newer one. 0: the rule as it is (every frame processed).
  double keyframe_lookahead_s = 0.0;
};

enum class FrameStatus {
  kFirstKeyframe,  // the session's origin
  kTracked,        // matched to the last keyframe, not a keyframe itself
  kKeyframe,       // matched and made a keyframe
  kFallback,       // not matched: bridged (no keyframe, keyframe_id -1) or made a keyframe with the reused motion
  kSkipped,        // not used (empty image, no altitude yet)
};
std::string statusName(FrameStatus s);

struct OdometryUpdate {
  int index = 0;
  FrameStatus status = FrameStatus::kSkipped;
  std::string reason;    // why skipped / why a fallback
  std::string nav_note;  // why this frame's nav was not used (nav.max_speed_m_s), else empty
  Pose2 pose;            // the frame's pose in the session frame (when not skipped)
  /// Its covariance: the motions since the session's first frame composed to first order (the
  /// keyframes' chain, then this frame's motion from the last keyframe), as Trajectory::absolute.
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
  int keyframe_id = -1;         // new keyframe's id (trajectory index) when one was made
  bool early_keyframe = false;  // made a keyframe by OdometryInput::keyframe_lookahead_s, not by the rule itself
  int features = 0;             // SIFT features extracted (0 for a frame tracked by KLT)
  int tracks = 0;               // KLT tracks from the last keyframe, when tracked (klt.enabled)
  bool klt = false;             // the frame's motion is KLT's (no extraction)
  int matches = 0;
  int inliers = 0;
  double overlap = 0.0;  // with the last keyframe, when matched
  double scale = 1.0;    // RANSAC's scale correction (altitude inconsistency), when matched
  /// Where the frame's motion from the last keyframe came from (kNav: vision failed or refused).
  MotionSource source = MotionSource::kVisual;
  bool gate_refused = false;     // the visual motion failed the nav gate
  double gate_distance2 = -1.0;  // the gate's squared Mahalanobis distance, -1 when not checked
  /// A nav stream lost both vision and the nav (refused or missing readings) for more than
  /// fallback.bridge_frames frames: no motion was made up, the session must end (SegmentedOdometry).
  bool nav_loss = false;
  bool dense = false;  // the motion came from the dense pass (core/frontend/dense_match.h)
  /// >= 0: the frame registers with the unmatched frame of this index but not with the session: the
  /// chain breaks before that frame. The session must end (a tracking loss); Odometry::restartFrames()
  /// are where the next one starts (SegmentedOdometry).
  int restart_index = -1;
};

/// How a frame's motion from its keyframe was measured (its OdometryUpdate's numbers).
struct MatchSummary {
  int matches = 0;
  int inliers = 0;
  double overlap = 0.0;
  double scale = 1.0;
};

/// What is kept about each keyframe (the features only for the last one).
struct KeyframeInfo {
  int frame_index = 0;
  double stamp_s = 0.0;
  double altitude_m = 0.0;
  bool fallback = false;                        // its motion from the previous keyframe is a reused one
  MotionSource source = MotionSource::kVisual;  // of that motion (kFallback when fallback)
  /// The frame's own match to the keyframe before it: of the frame that became the keyframe, or
  /// of a promoted frame from when it was tracked (zeros for the first keyframe and fallbacks).
  MatchSummary match{};
  /// The nav reading that anchors the nav at this keyframe (accepted, not refused; none for a
  /// fallback keyframe or a frame without nav): where a piece's nav placement starts or ends.
  std::optional<NavRecord> nav = std::nullopt;
};

struct OdometryStats {
  int frames = 0;
  int keyframes = 0;
  int tracked = 0;
  int fallbacks = 0;
  int bridged = 0;          // ... of them, bridged (no keyframe, no reused motion)
  int promotions = 0;       // previous frames promoted to keyframe after a failed match
  int early_keyframes = 0;  // keyframes made ahead of the rule (OdometryInput::keyframe_lookahead_s)
  int skipped_image = 0;
  int skipped_altitude = 0;
  int altitude_reused = 0;
  int altitude_out_of_range = 0;  // finite but above max_altitude_m (then reused, or skipped when none yet)
  int nav_frames = 0;             // frames whose motion is the nav's (vision failed or was refused)
  int gate_checks = 0;            // visual motions compared with the nav
  int gate_refusals = 0;          // ... refused by the gate
  int fused = 0;                  // ... combined with the nav (nav.fuse)
  long hypotheses_gated = 0;      // RANSAC hypotheses the nav prior refused (nav.gate_ransac)
  int nav_implausible = 0;        // frames whose nav step was too fast to be a motion (nav.max_speed_m_s): no nav
  int nav_losses = 0;             // frames past the bridged ones with neither a visual motion nor a usable nav reading
  int klt_tracked = 0;            // frames whose motion came from KLT tracks (klt.enabled), no extraction
  int klt_extracted = 0;          // frames KLT tracked but that went the full way (keyframe due or degraded)
  int klt_degraded = 0;           // ... of them, because the tracks failed (too few, RANSAC, nav gate)
  int dense_tries = 0;            // dense registrations tried (the normal one failed)
  int dense_matches = 0;          // ... accepted: frames the dense pass kept in the session
  int restarts = 0;               // frames that registered with the unmatched frame before them, not the session
};

/// What Odometry::process computes from a frame's image alone, before it looks at its own state:
/// the enhanced grey image and (SIFT on every frame, klt off) its features, keypoints undistorted.
/// A pure function of the image and the options, so a worker thread may compute it ahead of the
/// frame (two cores: offline_slam --threads) and the odometry's output is the
/// same as when it computes them itself.
struct PreparedFrame {
  bool done = false;  // false: nothing prepared (another image size than the camera's: process skips it)
  cv::Mat grey;       // enhanced
  std::optional<FrameFeatures> features;  // none with klt on: whether a frame is extracted depends on its tracks
  std::string error;                      // the image is unusable (the std::invalid_argument process would have caught)
  double enhance_ms = 0.0;
  double features_ms = 0.0;
};

/// The odometry's first steps for one camera: enhancement and feature extraction. Not thread-safe
/// (one per thread); its outputs depend only on the image.
class FramePreparer {
 public:
  FramePreparer(const CameraIntrinsics& camera, const OdometryOptions& options);
  // A copy would share the SIFT and CLAHE objects (cv::Ptr) between threads: move only.
  FramePreparer(const FramePreparer&) = delete;
  FramePreparer& operator=(const FramePreparer&) = delete;
  FramePreparer(FramePreparer&&) = default;
  FramePreparer& operator=(FramePreparer&&) = default;
  /// Throws std::invalid_argument for an unsupported image.
  cv::Mat enhance(const cv::Mat& image);
  /// SIFT features of an enhanced grey image, keypoints undistorted.
  FrameFeatures extract(const cv::Mat& grey) const;
  /// enhance() then (klt off) extract(), timed, the error kept.
  PreparedFrame prepare(const cv::Mat& image);

 private:
  CameraIntrinsics camera_;
  bool extract_all_;
  FeatureImageEnhancer enhancer_;
  FeatureExtractor extractor_;
};

class Odometry {
 public:
  /// Throws std::invalid_argument naming the bad option or camera value.
  Odometry(const CameraIntrinsics& camera, const OdometryOptions& options);

  /// `prepared` (may be null): the frame's FramePreparer::prepare(input.image), computed ahead by
  /// another thread with the same options and camera; moved from. The update is the same either way.
  OdometryUpdate process(const OdometryInput& input, PreparedFrame* prepared = nullptr);

  const Trajectory& trajectory() const { return trajectory_; }
  const std::vector<KeyframeInfo>& keyframes() const { return keyframes_; }
  /// Keyframes made by the last process() call (usually none or one; two when a tracked frame
  /// was promoted), with their features: what loop detection stores.
  struct NewKeyframe {
    int id;
    FrameFeatures features;
  };
  const std::vector<NewKeyframe>& newKeyframes() const { return new_keyframes_; }
  const OdometryStats& stats() const { return stats_; }
  const StageTimes& times() const { return times_; }
  /// The camera of the images (with their distortion).
  const CameraIntrinsics& camera() const { return camera_; }
  /// The camera of the features' coordinates: camera().pinhole(), the keypoints being undistorted
  /// right after extraction. Keyframes carry this one.
  const CameraIntrinsics& featureCamera() const { return feature_camera_; }

  /// A frame to process again, with what was computed for it: its grey image as input, its enhanced
  /// image and features prepared.
  struct RestartFrame {
    OdometryInput input;
    PreparedFrame prepared;
  };
  /// After an update with restart_index >= 0: that unmatched frame and the frame that registered
  /// with it, in order, for the next session to start from; empty otherwise.
  const std::vector<RestartFrame>& restartFrames() const { return restart_frames_; }

  /// A frame's grey image (the camera's, for the dense pass) and enhanced one (SIFT's input), and
  /// its dense features once computed: shared by the copies of a frame.
  struct FrameImages {
    cv::Mat grey;
    cv::Mat enhanced;
    std::optional<FrameFeatures> dense;
  };
  /// A keyframe of a closed piece, kept to register a later piece's keyframes with (rejoin:
  /// SegmentedOdometry).
  struct Anchor {
    int keyframe = -1;  // its id in its piece
    int frame_index = -1;
    double altitude_m = 0.0;
    FrameFeatures features;
    std::shared_ptr<FrameImages> images;
  };
  /// The last keyframe, with a measured motion (nullopt: none, or its motion is a reused one).
  std::optional<Anchor> lastKeyframeAnchor() const;
  /// The last keyframe registered with `anchor` as a frame with the keyframe (normal, then the
  /// dense pass; the same acceptance): its pose in the anchor's frame, or nullopt.
  std::optional<UncertainPose2> registerAnchor(const Anchor& anchor);

 private:
  struct TrackedFrame {
    int index = -1;
    double stamp_s = 0.0;
    double altitude_m = 0.0;
    FrameFeatures features;
    Pose2 pose;             // in the session frame
    UncertainPose2 motion;  // from the keyframe it was matched to
    MotionSource source = MotionSource::kVisual;
    std::optional<NavRecord> nav;
    MatchSummary match;  // its update's, once processed
    std::shared_ptr<FrameImages> images;
  };
  // The end of a frame's processing: its match summary kept (on its keyframe too, if it became
  // one; a promotion later reports it) and the frame becomes the previous one.
  void finishFrame(TrackedFrame* cur, const OdometryUpdate& up);
  // The frame carried by the nav's motion `m` from the last keyframe (vision failed or refused).
  void carryByNav(TrackedFrame* cur, const UncertainPose2& m, OdometryUpdate* up);
  // A frame no motion was measured for (bridged, or ending a piece with nav): counted as a fallback, its
  // pose the constant-step prediction for display only; the session's state stays the last matched frame's.
  void unmatchedFrame(OdometryUpdate* up);
  PairMotion matchToKeyframe(const FrameFeatures& f, double altitude_m, const std::optional<NavRecord>& nav);
  // The dense pass between `a` (the older frame) and `b`: a failure (ransac.success false, the
  // reason in ransac.failure) unless its motion passes denseAccepts.
  PairMotion matchDense(const TrackedFrame& a, const TrackedFrame& b, const MotionPrior* prior);
  const FrameFeatures& denseFeatures(const TrackedFrame& frame);
  // The unmatched frame before `cur` and `cur` register (normal, then dense): the chain breaks
  // before that frame. Then restart_frames_ holds both.
  bool registersWithUnmatched(const TrackedFrame& cur);
  // The nav prior gating RANSAC's hypotheses for a frame with `nav`, if any (nav.gate_ransac).
  std::optional<MotionPrior> ransacPrior(const std::optional<NavRecord>& nav) const;
  // SIFT features of an enhanced grey image, keypoints undistorted.
  FrameFeatures extractFeatures(const cv::Mat& grey);
  // KLT: the motion from the last keyframe by its tracked corners. True when the frame was
  // tracked that way (up and cur filled, state updated); false: the full way is needed.
  bool trackBetweenKeyframes(const cv::Mat& grey, TrackedFrame* cur, OdometryUpdate* up);
  // The full way for a frame with its features: first keyframe, matching, keyframe rule,
  // promotion, nav, fallback.
  OdometryUpdate processExtracted(TrackedFrame* cur, OdometryUpdate* up);
  double footprintOverlap(const Pose2& motion, double kf_altitude, double altitude) const;
  void addKeyframe(const TrackedFrame& frame, const UncertainPose2& motion, bool fallback,
                   MotionSource source = MotionSource::kVisual);
  bool needsKeyframe(const RansacResult& r, double overlap, double stamp_s) const;
  // Whether the keyframe rule would take a frame `lookahead_s_` after one at `pose` (session frame)
  // and `stamp_s`, at the velocity since the previous frame (OdometryInput::keyframe_lookahead_s).
  bool dueAhead(const Pose2& pose, double stamp_s, double altitude_m) const;
  // A session the nav carries across vision's gaps: it ends (OdometryUpdate::nav_loss) rather than
  // reuse the previous motion when neither vision nor an accepted nav reading gives one.
  bool navStream() const {
    return options_.nav.enabled && options_.nav.on_tracking_loss == TrackingLossPolicy::kDeadReckoning && nav_seen_;
  }

  CameraIntrinsics camera_;
  CameraIntrinsics feature_camera_;
  OdometryOptions options_;
  FramePreparer preparer_;
  std::optional<DenseExtractor> dense_;  // when options.dense.enabled
  KltTracker klt_;
  double lookahead_s_ = 0.0;  // the frame in process()'s OdometryInput::keyframe_lookahead_s
  cv::Mat prev_grey_;         // prev_'s enhanced image when it was tracked by KLT (no features yet)
  Trajectory trajectory_;
  std::vector<KeyframeInfo> keyframes_;
  TrackedFrame last_kf_;
  Eigen::Matrix3d last_kf_covariance_ = Eigen::Matrix3d::Zero();  // of last_kf_.pose, kept as keyframes are added
  TrackedFrame prev_;                                             // the last frame processed (tracked or keyframe)
  std::optional<NavRecord> prev_nav_accepted_;                    // the last nav reading not refused (the glitch check)
  std::optional<NavRecord> prev_nav_received_;            // the previous frame's reading, refused or not (its stamp)
  std::optional<std::pair<int, NavRecord>> refused_nav_;  // this frame's refused but steady reading
  bool nav_seen_ = false;                        // a nav reading came with a frame of this session (refused or not)
  Pose2 last_step_;                              // frame-to-frame motion of the last successful step
  int unmatched_ = 0;                            // consecutive unmatched frames (bridged, then reused)
  Pose2 predicted_;                              // the last unmatched frame's predicted pose (prev_ and last_step_ on)
  std::optional<TrackedFrame> unmatched_frame_;  // the last frame, when it was unmatched (the next may start from it)
  std::vector<RestartFrame> restart_frames_;
  double last_altitude_ = -1.0;  // last valid altitude
  OdometryStats stats_;
  StageTimes times_;
  std::vector<NewKeyframe> new_keyframes_;
};

}  // namespace core
}  // namespace uw_multislam
