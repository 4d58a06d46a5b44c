// The trajectory of one session as a chain of relative motions (paper 000 §4, (1) and (2)).
//
// Keyframe 0 is the session's origin; motion k (1 <= k <= numMotions()) is X_k^{k-1}, the
// roto-translation from keyframe k-1 to keyframe k, with its covariance. The motions are
// independent of each other here (block-diagonal P_t); optimisers that correlate them use
// relativeJacobian() with their own joint covariance.
#pragma once

#include <Eigen/Core>

#include <cstddef>
#include <vector>

#include "uw_multislam/core/geometry/uncertain_pose.h"

namespace uw_multislam {
namespace core {

class Trajectory {
 public:
  /// A trajectory with a single keyframe (the origin) and no motions.
  Trajectory();

  /// Appends X_t^{t-1}; the new keyframe gets index numKeyframes() - 1. O(1).
  void append(const UncertainPose2& motion);
  /// Replaces X_k^{k-1} (1 <= k <= numMotions()); absolute poses after k are updated. O(N - k).
  void setMotion(std::size_t k, const UncertainPose2& motion);

  std::size_t numKeyframes() const { return absolute_.size(); }
  std::size_t numMotions() const { return motions_.size(); }

  /// X_k^{k-1}, 1 <= k <= numMotions(). Throws std::out_of_range otherwise.
  const UncertainPose2& motion(std::size_t k) const;

  /// The stacked means of (1): (X_1^0ᵀ ... X_t^{t-1}ᵀ)ᵀ, length 3 * numMotions().
  Eigen::VectorXd stateVector() const;
  /// The block-diagonal covariance P_t of (1), 3N x 3N. Dense: for small N and tests only.
  Eigen::MatrixXd stateCovariance() const;

  /// Mean of the absolute pose X_k^0. O(1).
  const Pose2& absolutePose(std::size_t k) const;
  /// All absolute poses X_0^0 ... X_t^0.
  const std::vector<Pose2>& absolutePoses() const { return absolute_; }
  /// X_k^0 with its covariance. O(k).
  UncertainPose2 absolute(std::size_t k) const { return relative(0, k); }

  /// X_j^i of (2) for any i, j (j > i, j < i, j == i) with its first-order covariance.
  /// O(|j - i|). Throws std::out_of_range for a keyframe index past the end.
  UncertainPose2 relative(std::size_t i, std::size_t j) const;

  /// Jacobian of the mean of X_j^i with respect to the motions X_{lo+1}^{lo} ... X_{hi}^{hi-1},
  /// lo = min(i, j), hi = max(i, j): a 3 x 3(hi - lo) matrix, column block b belonging to
  /// motion lo + 1 + b. Used to propagate a joint (non block-diagonal) covariance.
  Eigen::MatrixXd relativeJacobian(std::size_t i, std::size_t j) const;

 private:
  void checkKeyframe(std::size_t k) const;
  void checkMotion(std::size_t k) const;
  /// Mean of X_hi^lo by chain composition of (2), with the prefixes P_0..P_n (P_0 = 0).
  std::vector<Pose2> prefixes(std::size_t lo, std::size_t hi) const;

  std::vector<UncertainPose2> motions_;  // motions_[k-1] is X_k^{k-1}
  std::vector<Pose2> absolute_;          // absolute_[k] is the mean of X_k^0
};

}  // namespace core
}  // namespace uw_multislam
