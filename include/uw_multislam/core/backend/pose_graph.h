// The sparse back-end: a 2-D pose graph solved with Ceres.
//
// The dense IEKF of iekf.h holds a 3N x 3N covariance; this solver holds the same information as
// a sparse graph over the absolute poses X_k of one map (the map's first keyframe fixed, the gauge):
//   - an edge per odometry motion X_k^{k-1} and per session link (their means and covariances),
//   - an edge per loop (pose of keyframe j in keyframe i, with its covariance), optionally behind a
//     robust loss (Huber or Cauchy) so that a wrong loop cannot drag the map.
// Each edge's residual is r = W (ẑ ⊖-components g(X_i, X_j)) with g = ⊖X_i ⊕ X_j and W the upper
// Cholesky factor of the edge's information R⁻¹, yaw wrapped, so that the cost is the sum of the
// squared Mahalanobis distances the IEKF minimises (paper 000 (12)-(20) as batch least squares).
// Solved by Levenberg-Marquardt with a sparse Cholesky factorisation (SuiteSparse), warm-started
// from the current estimate. Marginal covariances of chosen poses come from ceres::Covariance.
#pragma once

#include <Eigen/Core>

#include <string>
#include <vector>

#include "uw_multislam/core/backend/position_prior.h"
#include "uw_multislam/core/geometry/uncertain_pose.h"

namespace uw_multislam {
namespace core {

enum class RobustLoss { kNone, kHuber, kCauchy };
const char* robustLossName(RobustLoss l);
/// "none", "huber", "cauchy"; false otherwise.
bool parseRobustLoss(const std::string& name, RobustLoss* out);

struct SparseOptions {
  int max_iterations = 50;
  double function_tolerance = 1e-10;            // relative cost change that stops the solver
  RobustLoss robust_loss = RobustLoss::kHuber;  // Cauchy under-weighted true loops (over-confident covariances)
  double loss_scale = 3.0;                      // in standard deviations: loops beyond it are down-weighted

  std::string validate() const;
};

struct PoseGraphEdge {
  int from = 0;         // index of keyframe i
  int to = 0;           // index of keyframe j
  UncertainPose2 z;     // the measured pose of j in i's frame, X_j^i
  bool robust = false;  // behind the robust loss (loops), or plain least squares (odometry, links)
};

struct SparseResult {
  int iterations = 0;
  double initial_cost = 0.0;  // ½ Σ |r|² before and after
  double final_cost = 0.0;
  bool converged = false;
  double solve_ms = 0.0;
};

/// Optimises `poses` in place (absolute poses of one map, all in the frame of poses[fixed]) under
/// the edges and the absolute position priors (each a residual W (t_k − position), W the upper
/// Cholesky factor of its information, never robust). Throws std::invalid_argument on an edge index
/// out of range, i == j, an invalid covariance, or a prior checkPositionPrior refuses (with
/// fixed 0). Poses not reached by any edge or prior keep their values.
SparseResult optimisePoseGraph(std::vector<Pose2>* poses, const std::vector<PoseGraphEdge>& edges,
                               const SparseOptions& options, int fixed = 0,
                               const std::vector<PositionPrior>& priors = {});

/// The marginal covariances of poses `which` (relative to the fixed pose) at the given estimate,
/// from the graph's information matrix. Throws std::runtime_error when the graph leaves one of
/// them unconstrained.
std::vector<Eigen::Matrix3d> poseGraphMarginals(const std::vector<Pose2>& poses,
                                                const std::vector<PoseGraphEdge>& edges, const std::vector<int>& which,
                                                int fixed = 0);

}  // namespace core
}  // namespace uw_multislam
