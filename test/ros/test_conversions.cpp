// Core <-> ROS message conversions (no master needed).
#include <gtest/gtest.h>

#include <tf2/LinearMath/Quaternion.h>

#include <cmath>
#include <limits>

#include <Eigen/Geometry>
#include <random>

#include "uw_multislam/ros/camera_mount.h"
#include "uw_multislam/ros/conversions.h"

namespace uw_multislam {
namespace {

using core::Pose2;
using core::UncertainPose2;
namespace rc = ros_conversions;

TEST(Conversions, Pose2DRoundTrip) {
  const Pose2 p(1.5, -2.25, 3.0);
  const auto m = rc::toPose2DMsg(p);
  EXPECT_DOUBLE_EQ(m.x, 1.5);
  EXPECT_DOUBLE_EQ(m.theta, 3.0);
  EXPECT_TRUE(core::approxEqual(rc::fromMsg(m), p));
}

TEST(Conversions, PoseRoundTripKeepsYawAcrossPi) {
  for (double yaw : {0.0, 0.5, -1.2, M_PI, M_PI - 1e-7, -M_PI + 1e-7}) {
    const Pose2 p(-3.0, 4.0, yaw);
    const auto m = rc::toPoseMsg(p);
    EXPECT_DOUBLE_EQ(m.position.z, 0.0);
    EXPECT_NEAR(m.orientation.x * m.orientation.x + m.orientation.y * m.orientation.y +
                    m.orientation.z * m.orientation.z + m.orientation.w * m.orientation.w,
                1.0, 1e-12);
    Pose2 back;
    ASSERT_TRUE(rc::fromMsg(m, &back));
    EXPECT_TRUE(core::approxEqual(back, p, 1e-12, 1e-9)) << back << " vs " << p;
  }
}

TEST(Conversions, PoseFromUnnormalisedQuaternionAndRejectsBroken) {
  geometry_msgs::Pose m;
  tf2::Quaternion q;
  q.setRPY(0.0, 0.0, 0.8);
  m.orientation.x = 2 * q.x();
  m.orientation.y = 2 * q.y();
  m.orientation.z = 2 * q.z();
  m.orientation.w = 2 * q.w();
  Pose2 out;
  ASSERT_TRUE(rc::fromMsg(m, &out));
  EXPECT_NEAR(out.yaw(), 0.8, 1e-12);

  geometry_msgs::Pose zero;  // all-zero quaternion
  zero.orientation.w = 0.0;
  const Pose2 untouched(9, 9, 0.1);
  out = untouched;
  EXPECT_FALSE(rc::fromMsg(zero, &out));
  EXPECT_TRUE(core::approxEqual(out, untouched));
  geometry_msgs::Pose nan = rc::toPoseMsg(Pose2(0, 0, 0));
  nan.position.x = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(rc::fromMsg(nan, &out));
}

TEST(Conversions, CovarianceLandsInXYYawSlots) {
  Eigen::Matrix3d c;
  c << 0.04, 0.01, 0.002,  //
      0.01, 0.09, -0.003,  //
      0.002, -0.003, 0.01;
  const UncertainPose2 p(Pose2(1, 2, 0.3), c);
  const auto m = rc::toPoseWithCovarianceMsg(p);
  EXPECT_DOUBLE_EQ(m.covariance[0], 0.04);                      // x,x
  EXPECT_DOUBLE_EQ(m.covariance[1], 0.01);                      // x,y
  EXPECT_DOUBLE_EQ(m.covariance[5], 0.002);                     // x,yaw
  EXPECT_DOUBLE_EQ(m.covariance[35], 0.01);                     // yaw,yaw
  EXPECT_DOUBLE_EQ(m.covariance[30], 0.002);                    // yaw,x
  EXPECT_DOUBLE_EQ(m.covariance[14], rc::kUnobservedVariance);  // z,z
  UncertainPose2 back;
  ASSERT_TRUE(rc::fromMsg(m, &back));
  EXPECT_TRUE(back.covariance.isApprox(c));
  EXPECT_TRUE(core::approxEqual(back.mean, p.mean, 1e-12, 1e-12));

  auto bad = m;
  bad.covariance[35] = -1.0;
  EXPECT_FALSE(rc::fromMsg(bad, &back));
}

TEST(Conversions, PoseWithCovarianceStampedCarriesFrameStampAndCovariance) {
  Eigen::Matrix3d c;
  c << 4e-4, 1e-5, 2e-6, 1e-5, 3e-4, -1e-6, 2e-6, -1e-6, 1e-4;
  const auto m =
      rc::toPoseWithCovarianceStampedMsg(core::UncertainPose2(Pose2(1.0, -2.0, 0.5), c), "map", ros::Time(7.25));
  EXPECT_EQ(m.header.frame_id, "map");
  EXPECT_EQ(m.header.stamp, ros::Time(7.25));
  EXPECT_DOUBLE_EQ(m.pose.pose.position.y, -2.0);
  EXPECT_DOUBLE_EQ(m.pose.covariance[0 * 6 + 5], 2e-6);                     // x-yaw
  EXPECT_DOUBLE_EQ(m.pose.covariance[5 * 6 + 5], 1e-4);                     // yaw-yaw
  EXPECT_DOUBLE_EQ(m.pose.covariance[2 * 6 + 2], rc::kUnobservedVariance);  // z unknown
}

TEST(Conversions, SessionOfFrame) {
  EXPECT_EQ(rc::sessionOfFrame("session_12", "session_"), 12);
  EXPECT_EQ(rc::sessionOfFrame("dive0", "dive"), 0);
  EXPECT_EQ(rc::sessionOfFrame("session_", "session_"), -1);
  EXPECT_EQ(rc::sessionOfFrame("session_1x", "session_"), -1);
  EXPECT_EQ(rc::sessionOfFrame("session_-1", "session_"), -1);
  EXPECT_EQ(rc::sessionOfFrame("odom", "session_"), -1);
  EXPECT_EQ(rc::sessionOfFrame("session_99999999999", "session_"), -1);  // out of range
}

TEST(Conversions, TransformMatchesPose) {
  const Pose2 p(0.5, 0.25, -2.0);
  const auto t = rc::toTransformMsg(p);
  const auto m = rc::toPoseMsg(p);
  EXPECT_DOUBLE_EQ(t.translation.x, m.position.x);
  EXPECT_DOUBLE_EQ(t.rotation.z, m.orientation.z);
  EXPECT_DOUBLE_EQ(t.rotation.w, m.orientation.w);
  Pose2 back;
  ASSERT_TRUE(rc::fromMsg(t, &back));
  EXPECT_NEAR(back.x(), 0.5, 1e-12);
  EXPECT_NEAR(back.y(), 0.25, 1e-12);
  EXPECT_NEAR(back.yaw(), -2.0, 1e-12);
  const auto stamped = rc::toTransformStampedMsg(p, "map", "odom", ros::Time(12.5));
  EXPECT_EQ(stamped.header.frame_id, "map");
  EXPECT_EQ(stamped.child_frame_id, "odom");
  EXPECT_EQ(stamped.header.stamp, ros::Time(12.5));
  EXPECT_DOUBLE_EQ(stamped.transform.translation.y, 0.25);
  geometry_msgs::Transform broken = t;
  broken.rotation.w = broken.rotation.z = 0.0;
  EXPECT_FALSE(rc::fromMsg(broken, &back));
}

TEST(Conversions, OdometryCarriesThePoseCovarianceAndAFiniteDifferenceTwist) {
  Eigen::Matrix3d p;
  p << 0.04, 0.01, 0.002, 0.01, 0.09, -0.003, 0.002, -0.003, 0.01;
  const UncertainPose2 now(Pose2(2.0, 1.0, 0.5), p);
  // 0.5 s earlier the vehicle was 0.2 m behind along its heading, and turned 0.1 rad less.
  const Pose2 before = core::compose(now.mean, core::invert(Pose2(0.2, 0.0, 0.1)));
  const nav_msgs::Odometry m = rc::toOdometryMsg(now, &before, 0.5, "odom", "base_link", ros::Time(7.0));
  EXPECT_EQ(m.header.frame_id, "odom");
  EXPECT_EQ(m.child_frame_id, "base_link");
  EXPECT_EQ(m.header.stamp, ros::Time(7.0));
  UncertainPose2 back;
  ASSERT_TRUE(rc::fromMsg(m.pose, &back));
  EXPECT_TRUE(core::approxEqual(back.mean, now.mean, 1e-12, 1e-12));
  EXPECT_EQ(back.covariance, p);
  EXPECT_GE(m.pose.covariance[7 * 2], rc::kUnobservedVariance);  // z unknown
  // The step in the earlier base_link: 0.2 m along x (rotated by the 0.1 rad turn), over 0.5 s.
  const Pose2 step = core::between(before, now.mean);
  EXPECT_NEAR(m.twist.twist.linear.x, step.x() / 0.5, 1e-12);
  EXPECT_NEAR(m.twist.twist.linear.y, step.y() / 0.5, 1e-12);
  EXPECT_NEAR(std::hypot(m.twist.twist.linear.x, m.twist.twist.linear.y), 0.4, 1e-12);
  EXPECT_NEAR(m.twist.twist.angular.z, 0.2, 1e-12);
  for (int k = 0; k < 6; ++k) EXPECT_EQ(m.twist.covariance[7 * k], rc::kUnobservedVariance);
  // No earlier pose: no twist.
  const nav_msgs::Odometry first = rc::toOdometryMsg(now, nullptr, 0.0, "odom", "base_link", ros::Time(7.0));
  EXPECT_EQ(first.twist.twist.linear.x, 0.0);
  EXPECT_EQ(first.twist.twist.angular.z, 0.0);
}

// --- The camera mount (ros/camera_mount.h) ---

geometry_msgs::Transform transformOf(const Eigen::Vector3d& t, const Eigen::Matrix3d& r) {
  const Eigen::Quaterniond q(r);
  geometry_msgs::Transform m;
  m.translation.x = t.x();
  m.translation.y = t.y();
  m.translation.z = t.z();
  m.rotation.x = q.x();
  m.rotation.y = q.y();
  m.rotation.z = q.z();
  m.rotation.w = q.w();
  return m;
}

TEST(CameraMount, OpticalAxesWrittenByHandGiveTheMount) {
  // Camera 0.5 m forward, 0.1 m to port, 0.2 m below base_link, its image columns along base_link's
  // y (to port): optical x = base y, optical y (rows) = base x, optical z = -base z (down).
  Eigen::Matrix3d r;
  r.col(0) = Eigen::Vector3d::UnitY();
  r.col(1) = Eigen::Vector3d::UnitX();
  r.col(2) = -Eigen::Vector3d::UnitZ();
  core::CameraMount m;
  std::string why;
  ASSERT_TRUE(ros_frames::mountFromTransforms(
      transformOf({0.5, 0.1, -0.2}, r), transformOf({0.0, 0.0, -0.35}, Eigen::Matrix3d::Identity()), 0.1, &m, &why))
      << why;
  EXPECT_TRUE(core::approxEqual(m.base_from_camera, Pose2(0.5, 0.1, M_PI / 2), 1e-12, 1e-12)) << m.base_from_camera;
  EXPECT_NEAR(m.camera_above_altimeter_m, 0.15, 1e-12);
}

TEST(CameraMount, TheLaunchPublishersTransformsReadBackAsTheMount) {
  // scripts/mount_publisher.py: the optical frame is the level frame (yaw about z) turned by pi
  // about x, quaternion (x, y, z, w) = (cos(yaw / 2), sin(yaw / 2), 0, 0); the altimeter unrotated.
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int i = 0; i < 50; ++i) {
    const Eigen::Vector3d camera(u(rng), u(rng), u(rng)), altimeter(u(rng), u(rng), u(rng));
    const double yaw = 3 * u(rng);
    geometry_msgs::Transform c, a;
    c.translation.x = camera.x(), c.translation.y = camera.y(), c.translation.z = camera.z();
    c.rotation.x = std::cos(yaw / 2), c.rotation.y = std::sin(yaw / 2), c.rotation.z = 0, c.rotation.w = 0;
    a.translation.x = altimeter.x(), a.translation.y = altimeter.y(), a.translation.z = altimeter.z();
    a.rotation.w = 1.0;
    // The optical axis points down in base_link (an independent rotation of (0, 0, 1)).
    const Eigen::Vector3d axis =
        Eigen::Quaterniond(c.rotation.w, c.rotation.x, c.rotation.y, c.rotation.z) * Eigen::Vector3d::UnitZ();
    EXPECT_NEAR((axis + Eigen::Vector3d::UnitZ()).norm(), 0.0, 1e-12);
    core::CameraMount m;
    std::string why;
    ASSERT_TRUE(ros_frames::mountFromTransforms(c, a, 1e-6, &m, &why)) << why;
    EXPECT_TRUE(core::approxEqual(m.base_from_camera, Pose2(camera.x(), camera.y(), yaw), 1e-12, 1e-9));
    EXPECT_NEAR(m.camera_above_altimeter_m, camera.z() - altimeter.z(), 1e-12);
  }
}

TEST(CameraMount, TiltedOrBrokenTransformsAreRefusedWithAReason) {
  const Eigen::Matrix3d down = Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).toRotationMatrix();
  const auto alt = transformOf({0, 0, 0}, Eigen::Matrix3d::Identity());
  core::CameraMount m;
  m.camera_above_altimeter_m = 42.0;
  std::string why;
  const Eigen::Matrix3d tilted = Eigen::AngleAxisd(10 * M_PI / 180, Eigen::Vector3d::UnitY()).toRotationMatrix() * down;
  EXPECT_FALSE(ros_frames::mountFromTransforms(transformOf({0, 0, 0}, tilted), alt, 5 * M_PI / 180, &m, &why));
  EXPECT_NE(why.find("10 deg from straight down"), std::string::npos) << why;
  EXPECT_TRUE(ros_frames::mountFromTransforms(transformOf({0, 0, 0}, tilted), alt, 11 * M_PI / 180, &m, &why));
  auto broken = transformOf({0, 0, 0}, down);
  broken.translation.x = std::numeric_limits<double>::quiet_NaN();
  m.camera_above_altimeter_m = 42.0;
  EXPECT_FALSE(ros_frames::mountFromTransforms(broken, alt, 1.0, &m, &why));
  EXPECT_EQ(m.camera_above_altimeter_m, 42.0);  // untouched
}

}  // namespace
}  // namespace uw_multislam
