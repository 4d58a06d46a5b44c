// navToEnu (ros/nav_input.h): the nav topic's frames checked, a REP-103 NED reading turned into ENU.
#include <gtest/gtest.h>

#include <tf2/LinearMath/Matrix3x3.h>
#include <tf2/LinearMath/Quaternion.h>
#include <tf2_geometry_msgs/tf2_geometry_msgs.h>

#include <cmath>

#include "uw_multislam/ros/nav_input.h"

namespace uw_multislam {
namespace ros_inputs {
namespace {

nav_msgs::Odometry reading(const std::string& parent, const std::string& child, double x, double y, double yaw) {
  nav_msgs::Odometry m;
  m.header.frame_id = parent;
  m.child_frame_id = child;
  m.pose.pose.position.x = x;
  m.pose.pose.position.y = y;
  m.pose.pose.position.z = -1.0;
  tf2::Quaternion q;
  q.setRPY(0, 0, yaw);
  m.pose.pose.orientation = tf2::toMsg(q);
  m.pose.covariance[0] = 4.0;    // x
  m.pose.covariance[7] = 1.0;    // y
  m.pose.covariance[35] = 0.01;  // yaw
  return m;
}

double yawOf(const geometry_msgs::Quaternion& q) {
  double r, p, y;
  tf2::Matrix3x3(tf2::Quaternion(q.x, q.y, q.z, q.w)).getRPY(r, p, y);
  return y;
}

TEST(NavToEnu, AnEnuReadingPassesUnchanged) {
  nav_msgs::Odometry out;
  std::string why;
  const nav_msgs::Odometry in = reading("odom", "base_link", 3.0, 1.0, 0.3);
  ASSERT_TRUE(navToEnu(in, "odom", "base_link", &out, &why)) << why;
  EXPECT_EQ(out.pose.pose.position.x, 3.0);
  EXPECT_EQ(out.pose.covariance, in.pose.covariance);
}

TEST(NavToEnu, ANedReadingOfAnFrdBodyIsTheSameVehiclePoseInEnu) {
  // The vehicle 3 m north and 1 m east of the origin, heading 30 degrees east of north, 1 m deep:
  // in NED/FRD x north, y east, z down, yaw from north towards east; in ENU/FLU x east, y north,
  // z up, yaw from east towards north.
  const double heading = M_PI / 6;
  nav_msgs::Odometry ned = reading("odom_ned", "base_link_frd", 3.0, 1.0, heading);
  ned.pose.pose.position.z = 1.0;
  nav_msgs::Odometry out;
  std::string why;
  ASSERT_TRUE(navToEnu(ned, "odom", "base_link", &out, &why)) << why;
  EXPECT_EQ(out.header.frame_id, "odom");
  EXPECT_EQ(out.child_frame_id, "base_link");
  EXPECT_NEAR(out.pose.pose.position.x, 1.0, 1e-12);
  EXPECT_NEAR(out.pose.pose.position.y, 3.0, 1e-12);
  EXPECT_NEAR(out.pose.pose.position.z, -1.0, 1e-12);
  EXPECT_NEAR(yawOf(out.pose.pose.orientation), M_PI / 2 - heading, 1e-12);
  // Level: roll and pitch stay zero.
  double r, p, y;
  const auto& q = out.pose.pose.orientation;
  tf2::Matrix3x3(tf2::Quaternion(q.x, q.y, q.z, q.w)).getRPY(r, p, y);
  EXPECT_NEAR(r, 0.0, 1e-12);
  EXPECT_NEAR(p, 0.0, 1e-12);
  // North's variance (4) becomes y's, east's (1) x's; the yaw's is unchanged.
  EXPECT_NEAR(out.pose.covariance[0], 1.0, 1e-12);
  EXPECT_NEAR(out.pose.covariance[7], 4.0, 1e-12);
  EXPECT_NEAR(out.pose.covariance[35], 0.01, 1e-12);
}

TEST(NavToEnu, OtherFramesAreRefusedNamingTheExpectedOnes) {
  nav_msgs::Odometry out;
  std::string why;
  EXPECT_FALSE(navToEnu(reading("map", "base_link", 0, 0, 0), "odom", "base_link", &out, &why));
  EXPECT_NE(why.find("'map', expected odom (ENU) or odom_ned (NED)"), std::string::npos) << why;
  EXPECT_FALSE(navToEnu(reading("", "base_link", 0, 0, 0), "odom", "base_link", &out, &why));
  EXPECT_FALSE(navToEnu(reading("odom", "imu", 0, 0, 0), "odom", "base_link", &out, &why));
  EXPECT_NE(why.find("'imu', expected base_link or base_link_frd"), std::string::npos) << why;
  EXPECT_TRUE(navToEnu(reading("nav", "auv", 0, 0, 0), "nav", "auv", &out, &why)) << "the frames/ names count";
}

}  // namespace
}  // namespace ros_inputs
}  // namespace uw_multislam
