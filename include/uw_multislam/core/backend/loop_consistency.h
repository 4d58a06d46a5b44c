// Which loops between two maps agree with each other: pairwise consistency and the largest
// consistent set (PCM: Mangelson, Dominic, Eustice and Vasudevan, "Pairwise Consistent
// Measurement Set Maximization for Robust Multi-robot Map Merging", ICRA 2018).
//
// Loop i measures Z_i, the pose of keyframe c_i of the current map in keyframe p_i of the
// previous one. Two loops i, j are consistent when the cycle they close with the two maps'
// chains is the identity within its uncertainty:
//   E_ij = Z_i (+) X_cj^ci (+) (-)Z_j (+) X_pi^pj  ~  identity,
// where X_cj^ci and X_pi^pj are the odometry chains between the loops' keyframes in each map
// (Trajectory::relative, paper 000 (2)). The squared Mahalanobis distance of E_ij (covariance by
// first-order propagation, the four terms independent) is compared with the chi-square quantile
// of 3 degrees of freedom at `confidence`. Unlike a test of each loop's implied link against the
// link, it involves only the chain between the two loops, not the whole chain to the join point,
// so long sessions do not make the test blind or over-strict. The odometry's covariances are
// first-order and can be over-confident: min_sigma_m / min_sigma_rad add a floor to the cycle's
// variance (documented defaults, config/slam.yaml backend.consistency_*).
//
// The largest set of mutually consistent loops is a maximum clique of the consistency graph,
// found exactly (Bron-Kerbosch with pivoting; ties broken by total inliers). Used by the
// back-end's join_policy "consistent" (core/backend/backend.h).
#pragma once

#include <string>
#include <vector>

#include "uw_multislam/core/geometry/trajectory.h"
#include "uw_multislam/core/geometry/uncertain_pose.h"

namespace uw_multislam {
namespace core {

struct ConsistencyOptions {
  double confidence = 0.99;     // of the pairwise chi-square test (3 degrees of freedom)
  double min_sigma_m = 0.02;    // floor added to the cycle's x and y standard deviation
  double min_sigma_rad = 0.01;  // and to its yaw
  int max_loops = 200;          // more candidates: the ones with the most inliers are tested
  std::string validate() const;
};

/// One loop between two maps: keyframe indexes in each map's chain, the measured pose of the
/// current map's keyframe in the previous map's keyframe, and RANSAC's inlier count.
struct CrossLoop {
  int previous_index = 0;
  int current_index = 0;
  UncertainPose2 z;
  int inliers = 0;
};

/// The cycle E_ij above, with its first-order covariance (floors not added).
UncertainPose2 loopCycle(const CrossLoop& a, const CrossLoop& b, const Trajectory& previous, const Trajectory& current);
/// The squared Mahalanobis distance of a pose error (x, y, yaw; yaw wrapped) from the identity
/// under `covariance` plus the options' floors (min_sigma_m on x and y, min_sigma_rad on yaw);
/// infinite for a non-zero error under a singular covariance. The pairwise test below and the
/// back-end's gate inside a map both use it.
double mahalanobis2(const Pose2& error, const Eigen::Matrix3d& covariance, const ConsistencyOptions& options);
/// The cycle's squared Mahalanobis distance from the identity, with the options' floors.
double cycleDistance2(const CrossLoop& a, const CrossLoop& b, const Trajectory& previous, const Trajectory& current,
                      const ConsistencyOptions& options);
/// The chi-square quantile of 3 degrees of freedom at `confidence` (boost::math).
double chiSquare3Quantile(double confidence);

/// A maximum clique of the undirected graph `adjacent` (symmetric, no self loops needed); among
/// cliques of the largest size, the one with the largest sum of `weights` (equal weights when
/// empty). Exact. Indexes in increasing order.
std::vector<int> maximumClique(const std::vector<std::vector<bool>>& adjacent, const std::vector<int>& weights = {});

struct ConsistentSet {
  std::vector<int> loops;  // indexes into the candidates, increasing
  int inliers = 0;         // their total inliers
  double spread_m = 0.0;   // largest distance between two of their keyframes, the smaller of the two maps'
                           // (two loops from one keyframe, or to one, are one place)
  double spread_previous_m = 0.0, spread_current_m = 0.0;  // each map's
  int pairs = 0, consistent_pairs = 0;
};

/// The largest mutually consistent subset of `loops` (keyframe indexes must be valid in the
/// two trajectories: std::out_of_range otherwise).
ConsistentSet largestConsistentSet(const std::vector<CrossLoop>& loops, const Trajectory& previous,
                                   const Trajectory& current, const ConsistencyOptions& options);

}  // namespace core
}  // namespace uw_multislam
