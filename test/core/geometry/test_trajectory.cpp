// The trajectory of relative motions (paper 000 (1)) and X_j^i of (2) for j > i, j < i, j = i.
#include <gtest/gtest.h>

#include <Eigen/Dense>

#include <random>
#include <stdexcept>

#include "uw_multislam/core/geometry/trajectory.h"

namespace uw_multislam {
namespace core {
namespace {

Eigen::Matrix3d diag(double sx, double sy, double st) {
  return Eigen::Vector3d(sx * sx, sy * sy, st * st).asDiagonal();
}

Trajectory randomTrajectory(int motions, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> fwd(0.2, 1.5), side(-0.3, 0.3), turn(-1.2, 1.2), sig(0.01, 0.05);
  Trajectory t;
  for (int k = 0; k < motions; ++k) {
    Eigen::Matrix3d p = diag(sig(rng), sig(rng), sig(rng) / 2);
    p(0, 1) = p(1, 0) = 0.3 * std::sqrt(p(0, 0) * p(1, 1));
    t.append(UncertainPose2(Pose2(fwd(rng), side(rng), turn(rng)), p));
  }
  return t;
}

// Brute force: X_j^i = M_i^{-1} M_j with M_k the homogeneous matrix product of the motions.
Eigen::Matrix3d bruteForce(const Trajectory& t, std::size_t i, std::size_t j) {
  auto absolute = [&](std::size_t k) {
    Eigen::Matrix3d m = Eigen::Matrix3d::Identity();
    for (std::size_t q = 1; q <= k; ++q) m = m * t.motion(q).mean.matrix();
    return m;
  };
  return absolute(i).inverse() * absolute(j);
}

TEST(Trajectory, StartsWithOneKeyframeAtTheOrigin) {
  Trajectory t;
  EXPECT_EQ(t.numKeyframes(), 1u);
  EXPECT_EQ(t.numMotions(), 0u);
  EXPECT_TRUE(approxEqual(t.absolutePose(0), Pose2::identity()));
  const UncertainPose2 r = t.relative(0, 0);
  EXPECT_TRUE(approxEqual(r.mean, Pose2::identity()));
  EXPECT_TRUE(r.covariance.isZero(0.0));
  EXPECT_EQ(t.stateVector().size(), 0);
}

TEST(Trajectory, StateVectorIsEquationOne) {
  Trajectory t = randomTrajectory(5, 1);
  const Eigen::VectorXd x = t.stateVector();
  ASSERT_EQ(x.size(), 15);
  for (std::size_t k = 1; k <= 5; ++k) EXPECT_TRUE(x.segment<3>(3 * (k - 1)).isApprox(t.motion(k).mean.vector()));
  const Eigen::MatrixXd p = t.stateCovariance();
  EXPECT_TRUE((p.block<3, 3>(3, 3).isApprox(t.motion(2).covariance)));
  EXPECT_TRUE((p.block<3, 3>(0, 3).isZero(0.0)));
}

TEST(Trajectory, SquareClosesExactly) {
  Trajectory t;
  for (int k = 0; k < 4; ++k) t.append(UncertainPose2(Pose2(2.0, 0.0, M_PI / 2), diag(0.01, 0.01, 0.01)));
  EXPECT_TRUE(approxEqual(t.absolutePose(4), Pose2::identity(), 1e-12, 1e-12)) << t.absolutePose(4);
  EXPECT_TRUE(approxEqual(t.absolutePose(2), Pose2(2.0, 2.0, M_PI), 1e-12, 1e-12)) << t.absolutePose(2);
  // Going round the square the uncertainty has grown even though the mean is back at 0.
  EXPECT_GT(t.absolute(4).covariance.trace(), t.absolute(1).covariance.trace());
}

TEST(Trajectory, RelativeMatchesBruteForceMatrixProducts) {
  const Trajectory t = randomTrajectory(12, 2);
  for (std::size_t i = 0; i < t.numKeyframes(); ++i) {
    for (std::size_t j = 0; j < t.numKeyframes(); ++j) {
      const Pose2 r = t.relative(i, j).mean;
      EXPECT_TRUE(r.matrix().isApprox(bruteForce(t, i, j), 1e-10)) << "i=" << i << " j=" << j;
    }
  }
}

TEST(Trajectory, RelativeChainsAndInverts) {
  const Trajectory t = randomTrajectory(10, 3);
  for (std::size_t i = 0; i < 11; i += 2) {
    for (std::size_t j = 0; j < 11; j += 3) {
      for (std::size_t k = 0; k < 11; k += 5) {
        EXPECT_TRUE(
            approxEqual(compose(t.relative(i, j).mean, t.relative(j, k).mean), t.relative(i, k).mean, 1e-10, 1e-10));
      }
      EXPECT_TRUE(approxEqual(t.relative(j, i).mean, invert(t.relative(i, j).mean), 1e-10, 1e-10));
    }
    EXPECT_TRUE(approxEqual(t.absolute(i).mean, t.absolutePose(i), 1e-10, 1e-10));
  }
}

TEST(Trajectory, CovarianceMatchesSequentialPropagation) {
  const Trajectory t = randomTrajectory(8, 4);
  // Forward (j > i): ((X_{i+1}^i ⊕ X_{i+2}^{i+1}) ⊕ ...) with the pairwise SSC formulas.
  UncertainPose2 acc = UncertainPose2::exact(Pose2::identity());
  for (std::size_t j = 3; j <= 8; ++j) {
    acc = compose(acc, t.motion(j));
    const UncertainPose2 r = t.relative(2, j);
    EXPECT_TRUE(r.covariance.isApprox(acc.covariance, 1e-10)) << r.covariance << "\n" << acc.covariance;
    // Backward (j < i): ⊖X_j^{j-1}-style chain equals the inversion of the forward one.
    const UncertainPose2 back = t.relative(j, 2);
    EXPECT_TRUE(back.covariance.isApprox(invert(acc).covariance, 1e-10));
    EXPECT_TRUE(approxEqual(back.mean, invert(acc).mean, 1e-10, 1e-10));
  }
}

TEST(Trajectory, RelativeJacobianMatchesNumeric) {
  const Trajectory t = randomTrajectory(6, 5);
  for (const auto& ij : std::vector<std::pair<std::size_t, std::size_t>>{{1, 5}, {5, 1}, {0, 6}, {6, 0}, {3, 4}}) {
    const std::size_t i = ij.first, j = ij.second, lo = std::min(i, j), hi = std::max(i, j);
    const Eigen::MatrixXd analytic = t.relativeJacobian(i, j);
    ASSERT_EQ(analytic.rows(), 3);
    ASSERT_EQ(analytic.cols(), static_cast<Eigen::Index>(3 * (hi - lo)));
    const double h = 1e-6;
    for (std::size_t k = lo + 1; k <= hi; ++k) {
      for (int c = 0; c < 3; ++c) {
        Trajectory plus = t, minus = t;
        Eigen::Vector3d d = Eigen::Vector3d::Zero();
        d(c) = h;
        plus.setMotion(k, UncertainPose2(Pose2::fromVector(t.motion(k).mean.vector() + d), t.motion(k).covariance));
        minus.setMotion(k, UncertainPose2(Pose2::fromVector(t.motion(k).mean.vector() - d), t.motion(k).covariance));
        const Eigen::Vector3d numeric = poseError(plus.relative(i, j).mean, minus.relative(i, j).mean) / (2 * h);
        const Eigen::Vector3d col = analytic.col(static_cast<Eigen::Index>(3 * (k - lo - 1)) + c);
        EXPECT_TRUE(col.isApprox(numeric, 1e-6) || (col - numeric).norm() < 1e-8)
            << "i=" << i << " j=" << j << " motion " << k << " comp " << c << "\n"
            << col.transpose() << "\n"
            << numeric.transpose();
      }
    }
  }
  EXPECT_EQ(t.relativeJacobian(3, 3).cols(), 0);
}

TEST(Trajectory, ChainCovarianceMatchesMonteCarlo) {
  // Five motions; tolerance as in test_uncertain_pose.cpp (5 standard errors per entry).
  const Trajectory t = randomTrajectory(5, 6);
  const UncertainPose2 predicted = t.relative(0, 5);
  std::mt19937_64 rng(7);
  std::normal_distribution<double> n(0.0, 1.0);
  const int kSamples = 60000;
  std::vector<Eigen::Vector3d> errors;
  errors.reserve(kSamples);
  for (int s = 0; s < kSamples; ++s) {
    Pose2 p;
    for (std::size_t k = 1; k <= 5; ++k) {
      const Eigen::Matrix3d l = t.motion(k).covariance.llt().matrixL();
      p = compose(p, Pose2::fromVector(t.motion(k).mean.vector() + l * Eigen::Vector3d(n(rng), n(rng), n(rng))));
    }
    errors.push_back(poseError(p, predicted.mean));
  }
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& e : errors) mean += e;
  mean /= kSamples;
  Eigen::Matrix3d sampled = Eigen::Matrix3d::Zero();
  for (const auto& e : errors) sampled += (e - mean) * (e - mean).transpose();
  sampled /= kSamples - 1;
  const Eigen::Matrix3d& p = predicted.covariance;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) {
      const double se = std::sqrt((p(r, r) * p(c, c) + p(r, c) * p(r, c)) / kSamples);
      EXPECT_NEAR(sampled(r, c), p(r, c), 5 * se) << "entry (" << r << "," << c << ")";
    }
  }
}

TEST(Trajectory, SetMotionUpdatesLaterAbsolutePoses) {
  Trajectory t = randomTrajectory(6, 8);
  const Pose2 before2 = t.absolutePose(2);
  t.setMotion(3, UncertainPose2(Pose2(1.0, 0.0, 0.0), diag(0.1, 0.1, 0.1)));
  EXPECT_TRUE(approxEqual(t.absolutePose(2), before2));
  EXPECT_TRUE(approxEqual(t.absolutePose(3), compose(before2, Pose2(1.0, 0.0, 0.0)), 1e-12, 1e-12));
  EXPECT_TRUE(t.absolutePose(6).matrix().isApprox(bruteForce(t, 0, 6), 1e-10));
}

TEST(Trajectory, OutOfRangeIndicesThrowWithAReason) {
  Trajectory t = randomTrajectory(3, 9);
  EXPECT_THROW(t.relative(0, 4), std::out_of_range);
  EXPECT_THROW(t.relative(7, 0), std::out_of_range);
  EXPECT_THROW(t.motion(0), std::out_of_range);
  EXPECT_THROW(t.motion(4), std::out_of_range);
  EXPECT_THROW(t.absolutePose(4), std::out_of_range);
  EXPECT_THROW(t.setMotion(0, UncertainPose2()), std::out_of_range);
  try {
    t.relative(0, 9);
    FAIL() << "no exception";
  } catch (const std::out_of_range& e) {
    EXPECT_NE(std::string(e.what()).find("keyframe 9"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
