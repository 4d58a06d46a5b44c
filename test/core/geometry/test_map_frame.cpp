// The published map frame against compass arithmetic written here: a datum's heading h is the
// compass heading (clockwise from north) of the first keyframe's z-up x axis, so that axis is
// (sin h, cos h) in (east, north) and its y axis, 90 degrees anticlockwise, (-cos h, sin h).
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "uw_multislam/core/geometry/map_frame.h"

namespace uw_multislam {
namespace core {
namespace {

constexpr double kDeg = M_PI / 180.0;

// Columns: the core map's x and y axes in (east, north).
Eigen::Matrix2d axesInEnu(double heading_deg) {
  const double h = heading_deg * kDeg;
  Eigen::Matrix2d a;
  a.col(0) = Eigen::Vector2d(std::sin(h), std::cos(h));
  a.col(1) = Eigen::Vector2d(-std::cos(h), std::sin(h));
  return a;
}

TEST(MapFrame, WithoutADatumItIsTheCoreMap) {
  const MapFrame f;
  EXPECT_TRUE(f.isIdentity());
  const Pose2 p(3.0, -2.0, 0.4);
  EXPECT_EQ(f.toPublished(p).vector(), p.vector());
  EXPECT_TRUE(MapFrame::enuAtHeading(90.0).isIdentity());  // x already east
}

TEST(MapFrame, AxesGoWhereTheHeadingPointsThem) {
  // heading 0: 1 m along the first keyframe's x axis is 1 m north; along its y axis, 1 m west.
  const MapFrame north = MapFrame::enuAtHeading(0.0);
  EXPECT_NEAR(north.toPublished(Pose2(1.0, 0.0, 0.0)).x(), 0.0, 1e-12);
  EXPECT_NEAR(north.toPublished(Pose2(1.0, 0.0, 0.0)).y(), 1.0, 1e-12);
  EXPECT_NEAR(north.toPublished(Pose2(0.0, 1.0, 0.0)).x(), -1.0, 1e-12);
  EXPECT_NEAR(north.toPublished(Pose2(0.0, 1.0, 0.0)).y(), 0.0, 1e-12);
  // A vehicle along the first keyframe's x axis faces north: ENU yaw 90 degrees.
  EXPECT_NEAR(north.toPublished(Pose2(0.0, 0.0, 0.0)).yaw(), M_PI / 2, 1e-12);
  // heading 180: x points south.
  const Pose2 south = MapFrame::enuAtHeading(180.0).toPublished(Pose2(2.0, 0.0, 0.0));
  EXPECT_NEAR(south.x(), 0.0, 1e-12);
  EXPECT_NEAR(south.y(), -2.0, 1e-12);
  EXPECT_NEAR(std::abs(south.yaw()), M_PI / 2, 1e-12);
  EXPECT_NEAR(MapFrame::enuAtHeading(0.0).theta(), M_PI / 2, 1e-15);
  EXPECT_NEAR(MapFrame::enuAtHeading(30.0).theta(), 60.0 * kDeg, 1e-15);

  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (double h : {-350.0, -90.0, 0.0, 30.0, 45.0, 90.0, 135.0, 200.0, 359.0}) {
    const Eigen::Matrix2d a = axesInEnu(h);
    const MapFrame f = MapFrame::enuAtHeading(h);
    for (int i = 0; i < 20; ++i) {
      const Pose2 p(50 * u(rng), 50 * u(rng), 3 * u(rng));
      const Pose2 q = f.toPublished(p);
      const Eigen::Vector2d en = a * p.translation();
      EXPECT_NEAR(q.x(), en.x(), 1e-9) << h;
      EXPECT_NEAR(q.y(), en.y(), 1e-9) << h;
      // The vehicle's heading direction turns with the axes: (cos yaw, sin yaw) in core axes.
      const Eigen::Vector2d facing = a * Eigen::Vector2d(std::cos(p.yaw()), std::sin(p.yaw()));
      EXPECT_NEAR(normalizeAngle(q.yaw() - std::atan2(facing.y(), facing.x())), 0.0, 1e-12) << h;
    }
  }
}

TEST(MapFrame, TurnsTheCovarianceWithTheAxes) {
  Eigen::Matrix3d p;
  p << 0.04, 0.01, 0.002, 0.01, 0.09, -0.003, 0.002, -0.003, 0.001;
  // heading 0: east = -core y, north = core x.
  const Eigen::Matrix3d n = MapFrame::enuAtHeading(0.0).toPublished(UncertainPose2(Pose2(), p)).covariance;
  EXPECT_NEAR(n(0, 0), p(1, 1), 1e-15);
  EXPECT_NEAR(n(1, 1), p(0, 0), 1e-15);
  EXPECT_NEAR(n(0, 1), -p(0, 1), 1e-15);
  EXPECT_NEAR(n(1, 0), -p(1, 0), 1e-15);
  EXPECT_NEAR(n(0, 2), -p(1, 2), 1e-15);
  EXPECT_NEAR(n(1, 2), p(0, 2), 1e-15);
  EXPECT_NEAR(n(2, 2), p(2, 2), 0.0);
  for (double h : {-120.0, 17.0, 30.0, 250.0}) {
    Eigen::Matrix3d a = Eigen::Matrix3d::Identity();
    a.topLeftCorner<2, 2>() = axesInEnu(h);
    const Eigen::Matrix3d expected = a * p * a.transpose();
    const UncertainPose2 q = MapFrame::enuAtHeading(h).toPublished(UncertainPose2(Pose2(1.0, 2.0, 0.3), p));
    EXPECT_TRUE(q.covariance.isApprox(expected, 1e-12)) << h << "\n" << q.covariance << "\nvs\n" << expected;
  }
}

TEST(MapFrame, RoundTrips) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Eigen::Matrix3d p;
  p << 0.04, 0.01, 0.002, 0.01, 0.09, -0.003, 0.002, -0.003, 0.001;
  for (double h : {-200.0, 0.0, 30.0, 90.0, 300.0}) {
    const MapFrame f = MapFrame::enuAtHeading(h);
    const UncertainPose2 a(Pose2(80 * u(rng), 80 * u(rng), 3 * u(rng)), p);
    const UncertainPose2 back = f.fromPublished(f.toPublished(a));
    EXPECT_TRUE(approxEqual(back.mean, a.mean, 1e-12, 1e-12)) << h;
    EXPECT_TRUE(back.covariance.isApprox(p, 1e-12)) << h;
    const Pose2 in_published(4.0, -7.0, 1.0);
    EXPECT_TRUE(approxEqual(f.toPublished(f.fromPublished(in_published)), in_published, 1e-12, 1e-12)) << h;
  }
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
