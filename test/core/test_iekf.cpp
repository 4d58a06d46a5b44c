// Intra-map IEKF (paper 000 §8, (10)-(20)).
#include <gtest/gtest.h>

#include <Eigen/Dense>

#include <random>

#include "uw_multislam/core/backend/iekf.h"

namespace uw_multislam {
namespace core {
namespace {

Eigen::Matrix3d diag(double sxy, double syaw) {
  return Eigen::Vector3d(sxy * sxy, sxy * sxy, syaw * syaw).asDiagonal();
}

TEST(Iekf, TrajectoryBuildingIsBlockDiagonal) {
  TrajectoryIekf f;
  f.addMotion(UncertainPose2(Pose2(1, 0, 0.1), diag(0.1, 0.01)));
  f.addMotion(UncertainPose2(Pose2(1, 0, 0.2), diag(0.2, 0.02)));
  ASSERT_EQ(f.covariance().rows(), 6);
  EXPECT_TRUE((f.covariance().block<3, 3>(0, 3).isZero(0.0)));
  EXPECT_TRUE((f.covariance().block<3, 3>(3, 3).isApprox(diag(0.2, 0.02))));
  EXPECT_EQ(f.numKeyframes(), 3u);
}

TEST(Iekf, SquareWithOneExactLoopClosesExactly) {
  // A 2 m square whose odometry over-turns by 0.05 rad and over-measures by 5 % per side.
  TrajectoryIekf f;
  for (int k = 0; k < 4; ++k) f.addMotion(UncertainPose2(Pose2(2.1, 0.0, M_PI / 2 + 0.05), diag(0.05, 0.02)));
  const Pose2 open = f.relative(0, 4).mean;
  EXPECT_GT(open.translation().norm(), 0.2);
  // The vehicle is back at its start: X_4^0 = identity, measured almost exactly.
  const IekfResult r = f.update({{0, 4, UncertainPose2(Pose2(), Eigen::Matrix3d::Identity() * 1e-10)}});
  const UncertainPose2 closed = f.relative(0, 4);
  EXPECT_TRUE(approxEqual(closed.mean, Pose2(), 1e-4, 1e-4)) << closed.mean << " after " << r.iterations;
  EXPECT_LT(closed.covariance.trace(), 1e-6);  // the loop pins it down
  EXPECT_GT(r.iterations, 1);                  // relinearised: a 0.2 rad heading error is not linear
  EXPECT_LT(r.chi2_after, 1e-3 * r.chi2_before);
  // The correction is spread over the sides (equal covariances): all four the same.
  for (int k = 1; k <= 4; ++k) {
    EXPECT_TRUE(approxEqual(f.motions()[k - 1], f.motions()[0], 1e-4, 1e-4)) << f.motions()[k - 1];
  }
  EXPECT_NEAR(f.motions()[0].yaw(), M_PI / 2, 1e-4);
}

TEST(Iekf, ConsistentLoopChangesNothing) {
  TrajectoryIekf f;
  for (int k = 0; k < 5; ++k) f.addMotion(UncertainPose2(Pose2(1.0, 0.1, 0.3), diag(0.05, 0.02)));
  const std::vector<Pose2> before = f.motions();
  const Pose2 z = f.relative(1, 5).mean;
  f.update({{1, 5, UncertainPose2(z, diag(0.01, 0.01))}});
  for (std::size_t k = 0; k < before.size(); ++k) EXPECT_TRUE(approxEqual(f.motions()[k], before[k], 1e-9, 1e-9));
  // ... but the uncertainty of the looped stretch shrinks, and correlations appear.
  EXPECT_LT(f.relative(1, 5).covariance.trace(), 0.01 * 0.01 * 3 + 1e-9);
  EXPECT_FALSE((f.covariance().block<3, 3>(3, 6).isZero(1e-12)));
}

TEST(Iekf, LinearCaseMatchesWeightedLeastSquares) {
  // No rotation: the problem is linear. Two motions along x with variances 1 and 3 (x only
  // matters); a loop says their sum is 1.5 instead of 2.0 with negligible noise. Least squares
  // spreads the 0.5 m in proportion to the variances: 0.125 and 0.375.
  TrajectoryIekf f;
  Eigen::Matrix3d a = Eigen::Vector3d(1.0, 1e-6, 1e-8).asDiagonal(), b = Eigen::Vector3d(3.0, 1e-6, 1e-8).asDiagonal();
  f.addMotion(UncertainPose2(Pose2(1.0, 0, 0), a));
  f.addMotion(UncertainPose2(Pose2(1.0, 0, 0), b));
  f.update({{0, 2, UncertainPose2(Pose2(1.5, 0, 0), Eigen::Matrix3d::Identity() * 1e-12)}});
  EXPECT_NEAR(f.motions()[0].x(), 1.0 - 0.125, 1e-6);
  EXPECT_NEAR(f.motions()[1].x(), 1.0 - 0.375, 1e-6);
}

TEST(Iekf, ReducesTheRelativeErrorBetweenRevisitedPlaces) {
  // Out-and-back with noisy odometry; loops measured between keyframes k and 21 - k for even k.
  // The paper's e_k (35) over the *other* revisits (odd k, not measured) must drop: the update
  // has corrected the trajectory, not just the measured pairs. Five seeds.
  for (unsigned seed = 1; seed <= 5; ++seed) {
    std::mt19937 rng(seed);
    std::normal_distribution<double> n(0.0, 1.0);
    std::vector<Pose2> truth_motions;
    for (int k = 0; k < 10; ++k) truth_motions.push_back(Pose2(0.5, 0, 0));
    truth_motions.push_back(Pose2(0.0, 0.6, M_PI));
    for (int k = 0; k < 10; ++k) truth_motions.push_back(Pose2(0.5, 0, 0));
    Trajectory truth;
    TrajectoryIekf f;
    for (const Pose2& m : truth_motions) {
      truth.append(UncertainPose2::exact(m));
      f.addMotion(UncertainPose2(Pose2(m.x() + 0.02 * n(rng), m.y() + 0.02 * n(rng), m.yaw() + 0.02 * n(rng)),
                                 diag(0.02, 0.02)));
    }
    auto e_k = [&](const Trajectory& t) {
      double e = 0;
      int pairs = 0;
      for (int k = 1; k <= 9; k += 2, ++pairs) {
        e += (t.relative(k, 21 - k).mean.translation() - truth.relative(k, 21 - k).mean.translation()).norm();
      }
      return e / pairs;
    };
    const double before = e_k(f.trajectory());
    std::vector<LoopMeasurement> loops;
    for (int k = 2; k <= 10; k += 2) {
      const Pose2 z = truth.relative(k, 21 - k).mean;
      loops.push_back(
          {k, 21 - k,
           UncertainPose2(Pose2(z.x() + 0.005 * n(rng), z.y() + 0.005 * n(rng), z.yaw()), diag(0.005, 0.005))});
    }
    f.update(loops);
    EXPECT_LT(e_k(f.trajectory()), 0.5 * before) << "seed " << seed;
  }
}

TEST(Iekf, BadLoopsAreRefused) {
  TrajectoryIekf f;
  f.addMotion(UncertainPose2(Pose2(1, 0, 0), diag(0.1, 0.1)));
  EXPECT_THROW(f.update({{0, 0, UncertainPose2()}}), std::invalid_argument);
  EXPECT_THROW(f.update({{0, 5, UncertainPose2()}}), std::invalid_argument);
  Eigen::Matrix3d bad = diag(0.1, 0.1);
  bad(2, 2) = -1;
  EXPECT_THROW(f.update({{0, 1, UncertainPose2(Pose2(), bad)}}), std::invalid_argument);
  EXPECT_THROW(f.addMotion(UncertainPose2(Pose2(std::nan(""), 0, 0), diag(0.1, 0.1))), std::invalid_argument);
  EXPECT_EQ(f.update({}).iterations, 0);
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
