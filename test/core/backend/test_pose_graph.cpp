// The sparse back-end (core/backend/pose_graph.h): Ceres pose graph, robust loss, marginals, and its
// agreement with the paper's IEKF on small problems.
#include <gtest/gtest.h>

#include <Eigen/Dense>

#include <random>

#include "uw_multislam/core/backend/iekf.h"
#include "uw_multislam/core/backend/pose_graph.h"
#include "uw_multislam/core/geometry/trajectory.h"

namespace uw_multislam {
namespace core {
namespace {

Eigen::Matrix3d diag(double sxy, double syaw) {
  return Eigen::Vector3d(sxy * sxy, sxy * sxy, syaw * syaw).asDiagonal();
}

// Absolute poses of a chain of motions, and its odometry edges.
std::vector<Pose2> chainPoses(const std::vector<UncertainPose2>& motions) {
  std::vector<Pose2> p{Pose2()};
  for (const auto& m : motions) p.push_back(compose(p.back(), m.mean));
  return p;
}
std::vector<PoseGraphEdge> chainEdges(const std::vector<UncertainPose2>& motions) {
  std::vector<PoseGraphEdge> e;
  for (int k = 0; k < static_cast<int>(motions.size()); ++k) e.push_back({k, k + 1, motions[k], false});
  return e;
}

TEST(PoseGraph, SquareWithOneExactLoopClosesExactly) {
  std::vector<UncertainPose2> motions(4, UncertainPose2(Pose2(2.1, 0.0, M_PI / 2 + 0.05), diag(0.05, 0.02)));
  std::vector<Pose2> poses = chainPoses(motions);
  EXPECT_GT(poses[4].translation().norm(), 0.2);
  auto edges = chainEdges(motions);
  edges.push_back({0, 4, UncertainPose2(Pose2(), Eigen::Matrix3d::Identity() * 1e-10), false});
  const SparseResult r = optimisePoseGraph(&poses, edges, SparseOptions());
  EXPECT_TRUE(approxEqual(poses[4], Pose2(), 1e-4, 1e-4)) << poses[4];
  EXPECT_TRUE(approxEqual(poses[0], Pose2(), 0.0, 0.0));  // the gauge stays put
  EXPECT_LT(r.final_cost, 1e-3 * r.initial_cost);
  // The correction is spread: every side is still about 2.1 m long.
  for (int k = 0; k < 4; ++k) EXPECT_NEAR(between(poses[k], poses[k + 1]).translation().norm(), 2.1, 0.1);
}

TEST(PoseGraph, AgreesWithTheIekfOnASmallProblem) {
  // An out-and-back corridor with noisy odometry and three noisy loops: the batch optimum and
  // the IEKF (relinearised) reach the same trajectory within a millimetre.
  std::mt19937 rng(5);
  std::normal_distribution<double> n01(0.0, 1.0);
  std::vector<Pose2> truth{Pose2()};
  for (int k = 0; k < 12; ++k) truth.push_back(compose(truth.back(), Pose2(0.5, 0.0, k == 5 ? M_PI : 0.0)));
  std::vector<UncertainPose2> motions;
  for (int k = 1; k < static_cast<int>(truth.size()); ++k) {
    const Pose2 m = between(truth[k - 1], truth[k]);
    motions.emplace_back(Pose2(m.x() + 0.02 * n01(rng), m.y() + 0.02 * n01(rng), m.yaw() + 0.01 * n01(rng)),
                         diag(0.02, 0.01));
  }
  std::vector<std::pair<int, int>> pairs{{1, 11}, {3, 9}, {0, 12}};
  std::vector<LoopMeasurement> loops;
  std::vector<PoseGraphEdge> edges = chainEdges(motions);
  for (auto [i, j] : pairs) {
    const Pose2 z = between(truth[i], truth[j]);
    const UncertainPose2 zz(Pose2(z.x() + 0.005 * n01(rng), z.y() + 0.005 * n01(rng), z.yaw()), diag(0.005, 0.005));
    loops.push_back({i, j, zz});
    edges.push_back({i, j, zz, false});
  }
  TrajectoryIekf f;
  for (const auto& m : motions) f.addMotion(m);
  f.update(loops);
  std::vector<Pose2> poses = chainPoses(motions);
  SparseOptions o;
  o.robust_loss = RobustLoss::kNone;
  optimisePoseGraph(&poses, edges, o);
  const Trajectory t = f.trajectory();
  for (std::size_t k = 0; k < poses.size(); ++k) {
    EXPECT_TRUE(approxEqual(poses[k], t.absolutePose(k), 1e-3, 1e-3)) << k << ": " << poses[k] << " vs " << t.absolutePose(k);
  }
  // The far end is measured from the origin by the loop {0, 12} (position noise 5 mm per axis),
  // so its estimate errs by at most that much per axis (more information only shrinks the
  // covariance): beyond 4 x 5 mm with probability below exp(-8) = 3e-4. The odometry, 12
  // noisy motions, is further off (6.4 cm here, 2.4 mm optimised).
  const double far_bound = 4 * 0.005;
  const std::vector<Pose2> odo = chainPoses(motions);
  EXPECT_LT(between(truth[12], poses[12]).translation().norm(), far_bound);
  EXPECT_GT(between(truth[12], odo[12]).translation().norm(), far_bound);  // what the bound refuses
  // Their uncertainties agree too: the marginal of the far end vs the IEKF's X_12^0. Both are the
  // inverse information of the same graph, linearised where each solver stopped (the trajectories
  // agree to the solvers' tolerances, 1e-6 for the IEKF's step), so the matrices agree to that
  // order, entry by entry, not just in trace (measured: 1.4e-11 relative).
  const Eigen::Matrix3d marginal = poseGraphMarginals(poses, edges, {12}).front();
  const Eigen::Matrix3d iekf = f.relative(0, 12).covariance;
  EXPECT_LT((marginal - iekf).norm(), 1e-6 * iekf.norm()) << "marginal\n" << marginal << "\nIEKF\n" << iekf;
}

TEST(PoseGraph, MarginalsOfAnOpenChainAreTheCompoundedCovariances) {
  std::vector<UncertainPose2> motions;
  Trajectory t;
  for (int k = 0; k < 6; ++k) {
    motions.emplace_back(Pose2(1.0, 0.1 * k, 0.2), diag(0.05 + 0.01 * k, 0.02));
    t.append(motions.back());
  }
  const std::vector<Pose2> poses = chainPoses(motions);
  const auto m = poseGraphMarginals(poses, chainEdges(motions), {0, 3, 6});
  EXPECT_TRUE(m[0].isZero(0.0));  // the fixed pose
  EXPECT_TRUE(m[1].isApprox(t.absolute(3).covariance, 1e-6)) << m[1] << "\nvs\n" << t.absolute(3).covariance;
  EXPECT_TRUE(m[2].isApprox(t.absolute(6).covariance, 1e-6));
}

TEST(PoseGraph, RobustLossKeepsAWrongLoopFromBendingTheMap) {
  // A straight corridor walked twice (out and back) with exact odometry and good loops, plus one
  // wrong loop claiming a 1 m offset. Without a robust loss it bends the map; with Cauchy not.
  std::vector<Pose2> truth{Pose2()};
  for (int k = 0; k < 20; ++k) truth.push_back(compose(truth.back(), Pose2(0.5, 0.0, k == 9 ? M_PI : 0.0)));
  std::vector<UncertainPose2> motions;
  for (int k = 1; k < 21; ++k) motions.emplace_back(between(truth[k - 1], truth[k]), diag(0.02, 0.01));
  std::vector<PoseGraphEdge> edges = chainEdges(motions);
  for (int i = 0; i < 8; ++i) edges.push_back({i, 19 - i, UncertainPose2(between(truth[i], truth[19 - i]), diag(0.01, 0.01)), true});
  edges.push_back({2, 15, UncertainPose2(compose(between(truth[2], truth[15]), Pose2(1.0, 0.0, 0.0)), diag(0.01, 0.01)), true});
  double wrong_residual = 0.0;  // whitened, at the last solution
  auto error = [&](RobustLoss loss) {
    std::vector<Pose2> p = chainPoses(motions);
    SparseOptions o;
    o.robust_loss = loss;
    optimisePoseGraph(&p, edges, o);
    double worst = 0.0;
    for (int k = 0; k < 21; ++k) worst = std::max(worst, between(truth[k], p[k]).translation().norm());
    const Eigen::Vector3d r = poseError(edges.back().z.mean, between(p[2], p[15]));
    wrong_residual = std::sqrt(r.dot(edges.back().z.covariance.inverse() * r));
    return worst;
  };
  const double plain = error(RobustLoss::kNone);
  const double plain_residual = wrong_residual;
  const double cauchy = error(RobustLoss::kCauchy), huber = error(RobustLoss::kHuber);
  EXPECT_GT(plain, 0.1);
  EXPECT_LT(cauchy, 0.02);
  // Huber caps the wrong loop's pull at loss_scale (a = 3) standard deviations, where least
  // squares lets it pull with its whole whitened residual at the plain optimum (18.5 here). The
  // map is otherwise exact and the bend is linear in the pull, so Huber bends it by
  // plain x a / residual (12.6 cm): within 5 % for what the rotations add.
  const double huber_expected = plain * SparseOptions().loss_scale / plain_residual;
  EXPECT_NEAR(huber, huber_expected, 0.05 * huber_expected) << "plain " << plain << ", its residual " << plain_residual;
}

TEST(PoseGraph, RefusesBadEdgesAndOptions) {
  std::vector<Pose2> p(3);
  const UncertainPose2 ok(Pose2(1, 0, 0), diag(0.1, 0.1));
  EXPECT_THROW(optimisePoseGraph(&p, {{0, 3, ok, false}}, SparseOptions()), std::invalid_argument);
  EXPECT_THROW(optimisePoseGraph(&p, {{1, 1, ok, false}}, SparseOptions()), std::invalid_argument);
  EXPECT_THROW(optimisePoseGraph(&p, {{0, 1, UncertainPose2(Pose2(1, 0, 0), Eigen::Matrix3d::Zero()), false}},
                                 SparseOptions()),
               std::invalid_argument);
  EXPECT_THROW(optimisePoseGraph(&p, {{0, 1, UncertainPose2(Pose2(NAN, 0, 0), diag(0.1, 0.1)), false}}, SparseOptions()),
               std::invalid_argument);
  SparseOptions bad;
  bad.loss_scale = 0.0;
  EXPECT_THROW(optimisePoseGraph(&p, {{0, 1, ok, false}}, bad), std::invalid_argument);
  // A pose no edge reaches has no marginal.
  EXPECT_THROW(poseGraphMarginals(p, {{0, 1, ok, false}}, {2}), std::runtime_error);
  RobustLoss l;
  EXPECT_TRUE(parseRobustLoss("huber", &l) && l == RobustLoss::kHuber);
  EXPECT_FALSE(parseRobustLoss("tukey", &l));
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
