// Tracking loss, the multi-session way (paper 003 §5.1 starts a new sub-map when tracking fails
// and re-links it later; we do it with sessions). SegmentedOdometry wraps the odometry of one
// camera stream: after max_fallbacks consecutive frames the odometry could not match (blank,
// occluded or featureless water, a camera restart), the session is closed; a new session starts
// at the first later frame with at least min_features features, its origin (the first session
// too starts at the first such frame). Global loops then
// join the pieces back (core/backend.h). The fallback keyframes made before the session closes
// stay in it, with their large covariance.
#pragma once

#include <memory>
#include <string>

#include "uw_multislam/core/odometry.h"

namespace uw_multislam {
namespace core {

struct TrackingLossOptions {
  int max_fallbacks = 5;    // consecutive unmatched frames that close the session (0 = never)
  int min_features = 100;   // features a frame needs to start the next session

  std::string validate() const;
};

class SegmentedOdometry {
 public:
  struct Step {
    OdometryUpdate update;         // of the current session's odometry (status kSkipped while lost)
    bool session_started = false;  // this frame is the origin of a session (the first one too)
    bool session_closed = false;   // this frame closed the session (tracking lost)
  };

  /// Throws std::invalid_argument on bad options.
  SegmentedOdometry(const CameraIntrinsics& camera, const OdometryOptions& odometry, const TrackingLossOptions& loss);

  Step process(const OdometryInput& input);

  /// The current session's odometry (after a closing frame: the closed one, until the next
  /// process()); nullptr while no session is open.
  const Odometry* odometry() const { return odometry_.get(); }
  /// Sessions started so far.
  int sessions() const { return sessions_; }
  /// Frames processed while lost (no session), and sessions closed by tracking loss.
  int framesLost() const { return frames_lost_; }
  int losses() const { return losses_; }
  /// The timings of every odometry so far, the finished ones included.
  StageTimes times() const;

 private:
  CameraIntrinsics camera_;
  OdometryOptions options_;
  TrackingLossOptions loss_;
  std::unique_ptr<Odometry> odometry_;
  bool closed_ = false;  // odometry_ is the session just closed
  int consecutive_fallbacks_ = 0;
  int sessions_ = 0, frames_lost_ = 0, losses_ = 0;
  StageTimes times_;  // finished odometries' timings
};

}  // namespace core
}  // namespace uw_multislam
