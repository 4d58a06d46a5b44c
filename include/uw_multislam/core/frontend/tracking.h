// Tracking loss, the multi-session way (paper 003 §5.1 starts a new sub-map when tracking fails
// and re-links it later; we do it with sessions). SegmentedOdometry wraps the odometry of one
// camera stream: after max_fallbacks consecutive frames the odometry could not match (blank,
// occluded or featureless water, a camera restart), the session is closed; a new session starts
// at the first later frame with at least min_features features, its origin (the first session
// too starts at the first such frame). When a frame registers with the unmatched frame before it
// but not with the session (OdometryUpdate::restart_index), the session is closed at that frame and
// the next one starts, at the next process(), from the unmatched frame: the two frames are processed
// again in it (their features kept) before the new frame, so none is lost. Global loops then
// join the pieces back (core/backend/backend.h). Before that, the next piece's first keyframes
// (rejoin_keyframes) are registered with the closed piece's last keyframe (Odometry::registerAnchor):
// the first that registers places the piece against its predecessor (Step::placement, visual), a
// link that joins the two maps at once, as the nav's placement does.
//
// Keyframes whose motion is a fallback (a reused motion: the frame could not be matched) are held
// back until a later frame is matched again; if the session closes first they are dropped, so a
// session ends at its last keyframe with a measured motion, not at extrapolated guesses.
#pragma once

#include <memory>
#include <optional>
#include <string>
#include <utility>

#include "uw_multislam/core/frontend/odometry.h"

namespace uw_multislam {
namespace core {

struct TrackingLossOptions {
  int max_fallbacks = 5;   // consecutive unmatched frames that close the session (0 = never)
  int min_features = 100;  // features a frame needs to start the next session
  /// After a tracking loss, this many keyframes of the next piece are registered with the closed
  /// piece's last keyframe (normal, then the dense pass); the first that registers joins the two
  /// (a visual bridge, NavPlacement::visual). 0: never.
  int rejoin_keyframes = 3;

  std::string validate() const;
};

/// Where the nav puts a new piece's first keyframe: relative to keyframe `keyframe` of the piece
/// before it (its id there), `z` the first keyframe's pose in that keyframe's frame with the nav's
/// covariance over the stretch between them (navPlacement, one track).
struct NavPlacement {
  int keyframe = -1;
  UncertainPose2 z;
  /// `z` is the two keyframes' registration (a visual bridge: SegmentedOdometry's rejoin), not the nav's.
  bool visual = false;
};

class SegmentedOdometry {
 public:
  struct Step {
    OdometryUpdate update;  // of the current session's odometry (status kSkipped while lost)
    /// A session starts with this frame: its origin is this frame (the first session too) or, after
    /// a restart, the earlier frames restartFrames() named, released as its first keyframes here.
    bool session_started = false;
    bool session_closed = false;  // this frame closed the session (tracking lost)
    /// With session_started after a tracking loss, when nav.place_pieces and the nav has a reading
    /// at a kept keyframe of the previous piece and at this one: the nav's placement of this piece.
    std::optional<NavPlacement> placement = std::nullopt;
  };

  /// Throws std::invalid_argument on bad options.
  SegmentedOdometry(const CameraIntrinsics& camera, const OdometryOptions& odometry, const TrackingLossOptions& loss);

  /// `prepared`: as Odometry::process's (may be null).
  Step process(const OdometryInput& input, PreparedFrame* prepared = nullptr);

  /// The current session's odometry (after a closing frame: the closed one, until the next
  /// process()); nullptr while no session is open.
  const Odometry* odometry() const { return odometry_.get(); }
  /// The keyframes released by the last process(), in order: the odometry's new keyframes, with
  /// fallback keyframes held back until tracking is confirmed.
  const std::vector<Odometry::NewKeyframe>& newKeyframes() const { return released_; }
  /// Keyframes of the current (or just closed) session that count: its trajectory's first
  /// keptKeyframes() keyframes; fallback keyframes dropped at a close are not among them.
  int keptKeyframes() const { return kept_; }
  /// The last kept keyframe of the current (or just closed) session with a nav reading: its id
  /// and that reading (a nav placement's start). nullopt: none, or no session.
  std::optional<std::pair<int, NavRecord>> lastNavKeyframe() const;
  /// Sessions started so far.
  int sessions() const { return sessions_; }
  /// Frames processed while lost (no session), and sessions closed by tracking loss.
  int framesLost() const { return frames_lost_; }
  int losses() const { return losses_; }
  /// Keyframes of a piece registered with the piece before it (rejoin_keyframes), and those that registered.
  int rejoinTries() const { return rejoin_tries_; }
  int rejoins() const { return rejoins_; }
  /// Over every odometry so far: dense registrations tried, accepted (OdometryStats), restarts.
  long denseTries() const;
  long denseMatches() const;
  long restarts() const;
  /// The timings of every odometry so far, the finished ones included.
  StageTimes times() const;

 private:
  // `odometry` (its first frame processed) becomes the open session.
  void begin(std::unique_ptr<Odometry> odometry, Step* step);
  // The next session from the frames the closed one ended at (restart_): false when the first
  // of them cannot start one.
  bool restart(Step* step);
  // The open session's new keyframes after an update: released, or held while fallbacks are unconfirmed.
  void absorb(const OdometryUpdate& update);
  // An odometry done with: its timings and counts kept.
  void retire(const Odometry& odometry);
  // The keyframe this frame made, when released, registered with the piece before (anchor_).
  void rejoin(Step* step);

  CameraIntrinsics camera_;
  OdometryOptions options_;
  TrackingLossOptions loss_;
  std::vector<Odometry::RestartFrame> restart_;  // where the next session starts (Odometry::restartFrames)
  std::unique_ptr<Odometry> odometry_;
  bool closed_ = false;  // odometry_ is the session just closed
  std::vector<Odometry::NewKeyframe> pending_, released_;
  int kept_ = 0;
  int consecutive_fallbacks_ = 0;
  // The closed piece's lastNavKeyframe(), until the next piece starts (its placement's start).
  std::optional<std::pair<int, NavRecord>> previous_nav_;
  // The closed piece's last keyframe, while the next piece's first keyframes may still register with it.
  std::optional<Odometry::Anchor> anchor_;
  int rejoin_left_ = 0;
  int sessions_ = 0, frames_lost_ = 0, losses_ = 0, rejoin_tries_ = 0, rejoins_ = 0;
  StageTimes times_;                                         // finished odometries' timings
  long dense_tries_ = 0, dense_matches_ = 0, restarts_ = 0;  // ... and counts
};

}  // namespace core
}  // namespace uw_multislam
