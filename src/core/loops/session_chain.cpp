#include "uw_multislam/core/loops/session_chain.h"

#include <algorithm>

namespace uw_multislam {
namespace core {

SessionChain::Append SessionChain::append(int keyframe, const UncertainPose2& motion, const Pose2& odometry_pose) {
  const int next = numKeyframes();
  if (next == 0) {
    odometry_poses_.push_back(Pose2());  // the session's origin
    placeholder_.push_back(keyframe != 0);
    if (keyframe == 0) return Append::kAppended;
    if (keyframe - 1 > max_gap_) {
      odometry_poses_.clear();
      placeholder_.clear();
      return Append::kTooFar;
    }
    append(keyframe, motion, odometry_pose);
    return Append::kBridged;
  }
  if (keyframe < next) return Append::kStale;
  if (keyframe - next > max_gap_) return Append::kTooFar;
  if (keyframe == next) {
    odometry_.append(motion);
    odometry_poses_.push_back(odometry_pose);
    placeholder_.push_back(false);
    return Append::kAppended;
  }
  const Pose2 last = odometry_poses_.back();
  while (numKeyframes() < keyframe) {
    odometry_.append(UncertainPose2::exact(Pose2()));
    odometry_poses_.push_back(last);
    placeholder_.push_back(true);
  }
  odometry_.append(UncertainPose2(between(last, odometry_pose), motion.covariance));
  odometry_poses_.push_back(odometry_pose);
  placeholder_.push_back(false);
  return Append::kBridged;
}

bool SessionChain::isPlaceholder(int keyframe) const {
  return keyframe >= 0 && keyframe < numKeyframes() && placeholder_[keyframe];
}

Trajectory SessionChain::candidateTrajectory(const std::vector<Pose2>& optimised) const {
  if (optimised.size() < 2) return odometry_;
  Trajectory t;
  const std::size_t n = odometry_.numKeyframes();
  const std::size_t m = std::min(optimised.size(), n);
  for (std::size_t k = 1; k < n; ++k) {
    const UncertainPose2& odo = odometry_.motion(static_cast<int>(k));
    t.append(k < m ? UncertainPose2(between(optimised[k - 1], optimised[k]), odo.covariance) : odo);
  }
  return t;
}

}  // namespace core
}  // namespace uw_multislam
