// ros_bag::MessageFields: a field of a serialized message read by its path from the message definition,
// checked against the C++ message's own values (ros/message_field.h).
#include <gtest/gtest.h>
#include <nav_msgs/Odometry.h>
#include <ros/message_traits.h>
#include <ros/serialization.h>
#include <sensor_msgs/CameraInfo.h>

#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

#include "uw_multislam/ros/message_field.h"

namespace uw_multislam {
namespace {

template <typename M>
std::vector<std::uint8_t> serialize(const M& m) {
  std::vector<std::uint8_t> bytes(ros::serialization::serializationLength(m));
  ros::serialization::OStream s(bytes.data(), static_cast<std::uint32_t>(bytes.size()));
  ros::serialization::serialize(s, m);
  return bytes;
}

template <typename M>
ros_bag::MessageFields fieldsOf() {
  return ros_bag::MessageFields(ros::message_traits::datatype<M>(), ros::message_traits::definition<M>());
}

TEST(MessageFields, ReadsNumbersStringsAndStampsThroughNestedMessagesAndArrays) {
  nav_msgs::Odometry o;
  o.header.stamp = ros::Time(1700000012, 250000000);
  o.header.frame_id = "dvl_link";
  o.child_frame_id = "base_link";
  o.pose.pose.position.z = -7.25;
  o.pose.covariance[35] = 0.125;
  o.twist.twist.linear.x = 0.5;
  const std::vector<std::uint8_t> b = serialize(o);
  const ros_bag::MessageFields f = fieldsOf<nav_msgs::Odometry>();
  ASSERT_TRUE(f.ok()) << f.why();
  EXPECT_TRUE(f.hasHeader());
  double v = 0.0;
  std::string s, why;
  ASSERT_TRUE(f.number(b.data(), b.size(), "pose.pose.position.z", &v, &why)) << why;
  EXPECT_EQ(v, -7.25);
  ASSERT_TRUE(f.number(b.data(), b.size(), "m.pose.covariance[35]", &v, &why)) << why;  // the relay's spelling
  EXPECT_EQ(v, 0.125);
  ASSERT_TRUE(f.number(b.data(), b.size(), "twist.twist.linear.x", &v, &why)) << why;  // after two strings
  EXPECT_EQ(v, 0.5);
  ASSERT_TRUE(f.number(b.data(), b.size(), "header.stamp", &v, &why)) << why;
  EXPECT_DOUBLE_EQ(v, 1700000012.25);
  ASSERT_TRUE(f.text(b.data(), b.size(), "child_frame_id", &s, &why)) << why;
  EXPECT_EQ(s, "base_link");
  ASSERT_TRUE(f.text(b.data(), b.size(), "header.frame_id", &s, &why)) << why;
  EXPECT_EQ(s, "dvl_link");
}

TEST(MessageFields, SkipsVariableArraysBeforeTheField) {
  sensor_msgs::CameraInfo c;
  c.distortion_model = "plumb_bob";
  c.D = {0.1, -0.2, 0.0, 0.0, 0.3};  // variable length, before K[9], R[9], P[12]
  c.P[11] = 4.5;
  c.binning_y = 3;
  c.roi.width = 77;
  c.roi.do_rectify = true;
  const std::vector<std::uint8_t> b = serialize(c);
  const ros_bag::MessageFields f = fieldsOf<sensor_msgs::CameraInfo>();
  double v = 0.0;
  std::string why;
  ASSERT_TRUE(f.number(b.data(), b.size(), "D[4]", &v, &why)) << why;
  EXPECT_DOUBLE_EQ(v, 0.3);
  ASSERT_TRUE(f.number(b.data(), b.size(), "P[11]", &v, &why)) << why;
  EXPECT_EQ(v, 4.5);
  ASSERT_TRUE(f.number(b.data(), b.size(), "binning_y", &v, &why)) << why;
  EXPECT_EQ(v, 3.0);
  ASSERT_TRUE(f.number(b.data(), b.size(), "roi.width", &v, &why)) << why;
  EXPECT_EQ(v, 77.0);
  ASSERT_TRUE(f.number(b.data(), b.size(), "roi.do_rectify", &v, &why)) << why;
  EXPECT_EQ(v, 1.0);
}

TEST(MessageFields, ADamagedArrayLengthIsRefusedAtOnce) {
  sensor_msgs::CameraInfo c;
  c.distortion_model = "plumb_bob";
  c.D = {0.1, 0.2};
  std::vector<std::uint8_t> b = serialize(c);
  // D's length follows the header, height, width and the distortion model's string.
  const std::size_t at = ros::serialization::serializationLength(c.header) + 8 + 4 + c.distortion_model.size();
  const std::uint32_t two = 2, huge = 0xffffffffu;
  ASSERT_EQ(std::memcmp(b.data() + at, &two, 4), 0);
  std::memcpy(b.data() + at, &huge, 4);
  double v = 0.0;
  std::string why;
  EXPECT_FALSE(
      ros_bag::MessageFields(fieldsOf<sensor_msgs::CameraInfo>()).number(b.data(), b.size(), "binning_y", &v, &why));
  EXPECT_NE(why.find("shorter than its type"), std::string::npos) << why;
}

TEST(MessageFields, APathTheTypeLacksOrShortBytesAreRefusedWithTheReason) {
  nav_msgs::Odometry o;
  const std::vector<std::uint8_t> b = serialize(o);
  const ros_bag::MessageFields f = fieldsOf<nav_msgs::Odometry>();
  double v = 0.0;
  std::string why;
  EXPECT_FALSE(f.number(b.data(), b.size(), "altitude", &v, &why));
  EXPECT_NE(why.find("nav_msgs/Odometry has no field 'altitude' (it has header, child_frame_id, pose, twist)"),
            std::string::npos)
      << why;
  EXPECT_FALSE(f.number(b.data(), b.size(), "pose.pose.position.w", &v, &why));
  EXPECT_NE(why.find("geometry_msgs/Point has no field 'w'"), std::string::npos) << why;
  EXPECT_FALSE(f.number(b.data(), b.size(), "pose.covariance", &v, &why));
  EXPECT_NE(why.find("is an array"), std::string::npos) << why;
  EXPECT_FALSE(f.number(b.data(), b.size(), "child_frame_id", &v, &why));
  EXPECT_NE(why.find("not a number"), std::string::npos) << why;
  EXPECT_FALSE(f.number(b.data(), b.size() / 2, "twist.twist.angular.z", &v, &why));
  EXPECT_NE(why.find("shorter than its type"), std::string::npos) << why;
  EXPECT_FALSE(ros_bag::MessageFields("x/Y", "float64 a\nMissing b\n").ok());
}

}  // namespace
}  // namespace uw_multislam
