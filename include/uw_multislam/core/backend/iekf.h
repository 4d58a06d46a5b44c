// Intra-map trajectory optimisation with an iterated EKF (paper 000 §8, equations (10)-(20)).
//
// The state is the trajectory of (1): the stacked relative motions X_1^0 ... X_N^{N-1}, with a
// dense covariance P (3N x 3N). Trajectory building (10)(11) appends each odometry motion with
// its covariance (block-diagonal growth). A loop is a measurement Z = N(ẑ, R) of X_j^i, the pose
// of keyframe j in keyframe i, predicted by g(x) = X_{i+1}^i ⊕ ... ⊕ X_j^{j-1} (14) with the
// Jacobian of (18) (Trajectory::relativeJacobian). Loops are stacked (12)(13)(15)(16).
//
// The update iterates the EKF, relinearising at the latest estimate (Gauss-Newton form of the
// IEKF, Bell & Cathey 1993):
//   K_j = P⁻ G_jᵀ (G_j P⁻ G_jᵀ + R)⁻¹
//   x_{j+1} = x⁻ + K_j (ẑ − g(x_j) − G_j (x⁻ − x_j))
//   P = P⁻ − K_j G_j P⁻                                  ((20) at the last iteration)
// until |x_{j+1} − x_j| < tolerance or max_iterations. This is (19) with the innovation taken at
// the current iterate; the printed (19) writes g_t(X̂_t^-) there, which would not relinearise
// the prediction itself (we read it as a typo). Yaw residuals are wrapped to (−π, π].
//
// Memory O(N²), update O(N² · m) for m loop rows: the paper's method for sessions of up to a few
// thousand keyframes; the sparse back-end is the scalable one (pose_graph.h).
#pragma once

#include <Eigen/Core>

#include <string>
#include <vector>

#include "uw_multislam/core/backend/position_prior.h"
#include "uw_multislam/core/geometry/trajectory.h"

namespace uw_multislam {
namespace core {

struct IekfOptions {
  int max_iterations = 10;
  double tolerance = 1e-6;  // on the max-norm of the state change between iterations

  std::string validate() const;
};

/// A loop between keyframes i and j of the same trajectory: ẑ ~ X_j^i with covariance R.
struct LoopMeasurement {
  int i = 0;
  int j = 0;
  UncertainPose2 z;
};

struct IekfResult {
  int iterations = 0;
  double last_step = 0.0;    // max-norm of the final state change
  double chi2_before = 0.0;  // Σ innovationᵀ (G P Gᵀ + R)⁻¹ innovation at the prior
  double chi2_after = 0.0;   // Σ residualᵀ R⁻¹ residual at the result
};

class TrajectoryIekf {
 public:
  explicit TrajectoryIekf(const IekfOptions& options = IekfOptions());
  /// Starts from a given state: the motions and their joint covariance (3N x 3N). Throws
  /// std::invalid_argument when the sizes disagree.
  TrajectoryIekf(const IekfOptions& options, std::vector<Pose2> motions, Eigen::MatrixXd covariance);

  /// Trajectory building, (10)(11): x⁻ = (x, X_t^{t-1}), P⁻ = blkdiag(P, P_t^{t-1}).
  void addMotion(const UncertainPose2& motion);

  /// Intra-map optimisation with the loops as measurements. Throws std::invalid_argument for a
  /// loop with i == j, an index past the trajectory, or an invalid covariance.
  /// Position priors are measurements too: ẑ ~ the (x, y) of X_k^0, predicted by the first two
  /// rows of g for the loop 0 -> k (checkPositionPrior refuses a bad one, std::invalid_argument).
  IekfResult update(const std::vector<LoopMeasurement>& loops, const std::vector<PositionPrior>& positions = {});

  std::size_t numKeyframes() const { return motions_.size() + 1; }
  /// The current estimate as a Trajectory: means, and the diagonal 3x3 blocks of P as the
  /// motions' covariances.
  Trajectory trajectory() const;
  const std::vector<Pose2>& motions() const { return motions_; }
  /// P, 3N x 3N (a view into a buffer with spare capacity).
  Eigen::Block<const Eigen::MatrixXd> covariance() const {
    const auto n = static_cast<Eigen::Index>(3 * motions_.size());
    return storage_.topLeftCorner(n, n);
  }
  /// X_j^i with its covariance under the full (correlated) P.
  UncertainPose2 relative(int i, int j) const;
  const IekfOptions& options() const { return options_; }

 private:
  Trajectory meansOnly(const std::vector<Pose2>& motions) const;
  IekfOptions options_;
  std::vector<Pose2> motions_;
  Eigen::Block<Eigen::MatrixXd> state() {
    const auto n = static_cast<Eigen::Index>(3 * motions_.size());
    return storage_.topLeftCorner(n, n);
  }
  Eigen::MatrixXd storage_;  // P in its top-left 3N x 3N corner
};

}  // namespace core
}  // namespace uw_multislam
