// The chain of keyframes of one session as a loop-detection stage sees it (paper 000 §6): the
// odometry motions X_k^{k-1} in keyframe order, and the poses local-loop candidates are chosen by.
// The one code path for both heads: core::Pipeline (offline_slam) and the loop-detector nodelet
// build the local search trajectory with candidateTrajectory(), so a live and an offline run give
// the same candidates, radii and loops.
#pragma once

#include <vector>

#include "uw_multislam/core/geometry/trajectory.h"

namespace uw_multislam {
namespace core {

class SessionChain {
 public:
  enum class Append {
    kAppended,  // the next keyframe (or the origin)
    kBridged,   // after a gap: lost keyframes became placeholders at the last known pose
    kStale,     // repeated or out of order: nothing changed
    kTooFar,    // the gap is larger than max_gap: nothing changed (a corrupt id)
  };

  /// `max_gap`: the most keyframes a gap may bridge.
  explicit SessionChain(int max_gap = 1000) : max_gap_(max_gap) {}

  /// Keyframe `keyframe` with its motion from the previous one and its odometry pose X_k^0.
  /// Keyframe 0 (or the first one given) is the origin. Lost keyframes (a gap in the ids) stay at
  /// the last known pose with an exact zero motion, and this keyframe gets the odometry poses'
  /// motion across the gap with its own covariance.
  Append append(int keyframe, const UncertainPose2& motion, const Pose2& odometry_pose);

  int numKeyframes() const { return static_cast<int>(odometry_poses_.size()); }
  const Trajectory& odometry() const { return odometry_; }
  const std::vector<Pose2>& odometryPoses() const { return odometry_poses_; }
  /// Placeholders (keyframes that never arrived): never loop candidates.
  bool isPlaceholder(int keyframe) const;

  /// The trajectory local-loop candidates are chosen by: the motions between the latest optimised
  /// poses (`optimised[k]`: keyframe k in the session's frame, may cover fewer keyframes or be
  /// empty) where there are some, the odometry's beyond; the covariances are always the
  /// odometry's, which widen the search radius (an upper bound: optimised marginals are smaller).
  Trajectory candidateTrajectory(const std::vector<Pose2>& optimised) const;

 private:
  int max_gap_;
  Trajectory odometry_;
  std::vector<Pose2> odometry_poses_;
  std::vector<bool> placeholder_;
};

}  // namespace core
}  // namespace uw_multislam
