// SE(2) operators: algebraic identities, analytic vs numeric Jacobians, brute-force matrix
// products and angle wrap-around (paper 000 §4).
#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <limits>
#include <random>

#include <Eigen/Dense>

#include "uw_multislam/core/geometry/se2.h"

namespace uw_multislam {
namespace core {
namespace {

constexpr double kPi = M_PI;

// Central differences of a pose-valued function of a 3-vector; the yaw difference is wrapped
// so that functions whose output crosses ±pi are differentiated correctly.
Eigen::Matrix3d numericJacobian(const std::function<Pose2(const Eigen::Vector3d&)>& f, const Eigen::Vector3d& x0,
                                double h = 1e-6) {
  Eigen::Matrix3d j;
  for (int c = 0; c < 3; ++c) {
    Eigen::Vector3d dx = Eigen::Vector3d::Zero();
    dx(c) = h;
    j.col(c) = poseError(f(x0 + dx), f(x0 - dx)) / (2 * h);
  }
  return j;
}

std::vector<Pose2> samplePoses(int n, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> xy(-20.0, 20.0), yaw(-kPi, kPi);
  std::vector<Pose2> poses;
  for (int i = 0; i < n; ++i) poses.emplace_back(xy(rng), xy(rng), yaw(rng));
  // Include poses at and near the wrap-around.
  poses.emplace_back(1.0, -2.0, kPi);
  poses.emplace_back(-3.0, 0.5, kPi - 1e-9);
  poses.emplace_back(0.0, 0.0, -kPi + 1e-9);
  return poses;
}

TEST(NormalizeAngle, RangeIsHalfOpenMinusPiToPi) {
  EXPECT_DOUBLE_EQ(normalizeAngle(kPi), kPi);
  EXPECT_DOUBLE_EQ(normalizeAngle(-kPi), kPi);
  EXPECT_DOUBLE_EQ(normalizeAngle(3 * kPi), kPi);
  EXPECT_DOUBLE_EQ(normalizeAngle(-3 * kPi), kPi);
  EXPECT_DOUBLE_EQ(normalizeAngle(0.0), 0.0);
  EXPECT_NEAR(normalizeAngle(2 * kPi + 0.1), 0.1, 1e-12);
  EXPECT_NEAR(normalizeAngle(-2 * kPi - 0.1), -0.1, 1e-12);
  EXPECT_NEAR(normalizeAngle(kPi + 0.25), -kPi + 0.25, 1e-12);
  EXPECT_NEAR(normalizeAngle(-kPi - 0.25), kPi - 0.25, 1e-12);
  EXPECT_NEAR(normalizeAngle(1000.0), std::atan2(std::sin(1000.0), std::cos(1000.0)), 1e-9);
  EXPECT_TRUE(std::isnan(normalizeAngle(std::numeric_limits<double>::quiet_NaN())));
  EXPECT_TRUE(std::isnan(normalizeAngle(std::numeric_limits<double>::infinity())));
}

TEST(NormalizeAngle, EveryOutputInRange) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> a(-100.0, 100.0);
  for (int i = 0; i < 10000; ++i) {
    const double in = a(rng);
    const double r = normalizeAngle(in);
    ASSERT_GT(r, -kPi);
    ASSERT_LE(r, kPi);
    ASSERT_NEAR(std::cos(r), std::cos(in), 1e-9);
    ASSERT_NEAR(std::sin(r), std::sin(in), 1e-9);
  }
}

TEST(Pose2, ConstructorNormalisesYaw) {
  EXPECT_NEAR(Pose2(0, 0, 3 * kPi / 2).yaw(), -kPi / 2, 1e-12);
  EXPECT_DOUBLE_EQ(Pose2(0, 0, -kPi).yaw(), kPi);
  EXPECT_FALSE(Pose2(std::numeric_limits<double>::quiet_NaN(), 0, 0).isFinite());
  EXPECT_TRUE(Pose2(1, 2, 3).isFinite());
}

TEST(Pose2, ComposeKnownValues) {
  // Quarter turn then one metre forward ends at (0, 1) facing +y.
  const Pose2 r = compose(Pose2(0, 0, kPi / 2), Pose2(1, 0, 0));
  EXPECT_TRUE(approxEqual(r, Pose2(0, 1, kPi / 2), 1e-12, 1e-12)) << r;
  // Yaws summing past pi wrap.
  const Pose2 w = compose(Pose2(0, 0, 3.0), Pose2(0, 0, 0.5));
  EXPECT_NEAR(w.yaw(), 3.5 - 2 * kPi, 1e-12);
  const Pose2 v = compose(Pose2(0, 0, -3.0), Pose2(0, 0, -0.5));
  EXPECT_NEAR(v.yaw(), -3.5 + 2 * kPi, 1e-12);
}

TEST(Pose2, InverseIdentities) {
  for (const Pose2& x : samplePoses(200, 1)) {
    EXPECT_TRUE(approxEqual(compose(x, invert(x)), Pose2::identity(), 1e-12, 1e-12)) << x;
    EXPECT_TRUE(approxEqual(compose(invert(x), x), Pose2::identity(), 1e-12, 1e-12)) << x;
    EXPECT_TRUE(approxEqual(invert(invert(x)), x, 1e-12, 1e-12)) << x;
    EXPECT_TRUE(approxEqual(between(x, x), Pose2::identity(), 1e-12, 1e-12)) << x;
  }
}

TEST(Pose2, ComposeIsAssociative) {
  const auto p = samplePoses(60, 2);
  for (std::size_t i = 0; i + 2 < p.size(); ++i) {
    EXPECT_TRUE(approxEqual(compose(compose(p[i], p[i + 1]), p[i + 2]), compose(p[i], compose(p[i + 1], p[i + 2])),
                            1e-10, 1e-12));
  }
}

TEST(Pose2, ComposeMatchesHomogeneousMatrixProduct) {
  const auto p = samplePoses(100, 3);
  for (std::size_t i = 0; i + 1 < p.size(); ++i) {
    const Eigen::Matrix3d m = p[i].matrix() * p[i + 1].matrix();
    const Pose2 c = compose(p[i], p[i + 1]);
    EXPECT_TRUE(c.matrix().isApprox(m, 1e-12)) << c;
    EXPECT_TRUE(invert(p[i]).matrix().isApprox(p[i].matrix().inverse(), 1e-12));
  }
}

TEST(Pose2, TransformPointMatchesMatrix) {
  const Pose2 a(2.0, -1.0, 0.7);
  const Eigen::Vector2d p(0.3, 4.0);
  const Eigen::Vector3d h = a.matrix() * Eigen::Vector3d(p.x(), p.y(), 1.0);
  EXPECT_TRUE(transformPoint(a, p).isApprox(h.head<2>(), 1e-12));
}

TEST(Jacobians, ComposeAnalyticMatchesNumeric) {
  const auto p = samplePoses(100, 4);
  for (std::size_t i = 0; i + 1 < p.size(); ++i) {
    const Pose2 a = p[i], b = p[i + 1];
    const Eigen::Matrix3d n1 =
        numericJacobian([&](const Eigen::Vector3d& v) { return compose(Pose2::fromVector(v), b); }, a.vector());
    const Eigen::Matrix3d n2 =
        numericJacobian([&](const Eigen::Vector3d& v) { return compose(a, Pose2::fromVector(v)); }, b.vector());
    EXPECT_TRUE(composeJacobianFirst(a, b).isApprox(n1, 1e-6)) << composeJacobianFirst(a, b) << "\n" << n1;
    EXPECT_TRUE(composeJacobianSecond(a, b).isApprox(n2, 1e-6)) << composeJacobianSecond(a, b) << "\n" << n2;
  }
}

TEST(Jacobians, InvertAnalyticMatchesNumeric) {
  for (const Pose2& a : samplePoses(100, 5)) {
    const Eigen::Matrix3d n =
        numericJacobian([](const Eigen::Vector3d& v) { return invert(Pose2::fromVector(v)); }, a.vector());
    EXPECT_TRUE(invertJacobian(a).isApprox(n, 1e-6)) << invertJacobian(a) << "\n" << n;
  }
}

TEST(Jacobians, TransformPointAnalyticMatchesNumeric) {
  const Pose2 a(1.5, -0.5, 2.9);
  const Eigen::Vector2d p(3.0, -2.0);
  const double h = 1e-6;
  Eigen::Matrix<double, 2, 3> jp;
  for (int c = 0; c < 3; ++c) {
    Eigen::Vector3d d = Eigen::Vector3d::Zero();
    d(c) = h;
    jp.col(c) =
        (transformPoint(Pose2::fromVector(a.vector() + d), p) - transformPoint(Pose2::fromVector(a.vector() - d), p)) /
        (2 * h);
  }
  EXPECT_TRUE(transformPointJacobianPose(a, p).isApprox(jp, 1e-6));
  Eigen::Matrix2d jq;
  for (int c = 0; c < 2; ++c) {
    Eigen::Vector2d d = Eigen::Vector2d::Zero();
    d(c) = h;
    jq.col(c) = (transformPoint(a, p + d) - transformPoint(a, p - d)) / (2 * h);
  }
  EXPECT_TRUE(transformPointJacobianPoint(a).isApprox(jq, 1e-6));
}

TEST(PoseError, WrapsYaw) {
  const Eigen::Vector3d e = poseError(Pose2(0, 0, kPi - 0.01), Pose2(0, 0, -kPi + 0.01));
  EXPECT_NEAR(e.z(), -0.02, 1e-12);
  EXPECT_FALSE(approxEqual(Pose2(0, 0, 0), Pose2(1e-3, 0, 0), 1e-4, 1e-4));
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
