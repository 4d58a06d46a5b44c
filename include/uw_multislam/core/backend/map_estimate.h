// One map's estimate: the motions of its chain, concatenated as in (33) (each session's motions and
// the link between consecutive sessions; motion k reaches keyframe k + 1), with their uncertainty in
// one of two forms:
//  - marginal: each motion with its own 3x3 covariance (the odometry's or a link's measurement; the
//    sparse pose graph solves the means and keeps these covariances);
//  - joint: the IEKF's filter (iekf.h), the motions with their 3N x 3N covariance P (10)-(20).
// The map's optimiser (map_optimizer.h) chooses the form; what the back-end reads from a map (its
// motions and their marginal covariances) and how it cuts one after a split is the same for both.
#pragma once

#include <Eigen/Core>

#include <optional>
#include <utility>
#include <vector>

#include "uw_multislam/core/backend/iekf.h"
#include "uw_multislam/core/geometry/uncertain_pose.h"

namespace uw_multislam {
namespace core {

class MapEstimate {
 public:
  /// Marginal form, no motion (a map of one keyframe).
  MapEstimate() = default;
  /// Marginal form: motion k with covariance covariances[k]. Throws std::invalid_argument when the
  /// sizes differ.
  MapEstimate(std::vector<Pose2> motions, std::vector<Eigen::Matrix3d> covariances);
  /// Joint form.
  explicit MapEstimate(TrajectoryIekf filter);

  int numMotions() const;
  Pose2 motion(int k) const;
  /// Motion k's marginal covariance (joint form: its diagonal block of P).
  Eigen::Matrix3d motionCov(int k) const;
  /// The joint form's filter; null in the marginal form.
  const TrajectoryIekf* filter() const { return filter_ ? &*filter_ : nullptr; }

  /// Appends X_k^{k-1} with its covariance ((10)(11) in the joint form).
  void append(const UncertainPose2& motion);
  /// Replaces motion k's mean, its covariance kept (a pose graph's solution). Marginal form only:
  /// std::logic_error otherwise.
  void setMotion(int k, const Pose2& mean);
  /// The same motions in the marginal form (the joint form's diagonal blocks).
  MapEstimate marginal() const;
  /// The motion ranges [a, b) of `ranges`, in order, in the same form. The range numbered
  /// `composed` (if any) becomes one motion, their composition, with the covariance J Σ Jᵀ for the
  /// Jacobian J of the composition (joint form: and its cross terms J P with the rest).
  MapEstimate slice(const std::vector<std::pair<int, int>>& ranges, int composed = -1) const;
  /// first's motions, the link, second's, in the marginal form (34), whatever their forms.
  static MapEstimate concatenate(const MapEstimate& first, const UncertainPose2& link, const MapEstimate& second);

 private:
  std::vector<Pose2> motions_;            // marginal form
  std::vector<Eigen::Matrix3d> cov_;      // marginal form
  std::optional<TrajectoryIekf> filter_;  // joint form
};

}  // namespace core
}  // namespace uw_multislam
