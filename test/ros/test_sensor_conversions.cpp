// Image, CameraInfo and Range messages -> the odometry's inputs (no master needed).
#include <gtest/gtest.h>

#include <sensor_msgs/image_encodings.h>

#include <boost/make_shared.hpp>

#include <limits>

#include "uw_multislam/ros/sensor_conversions.h"

namespace uw_multislam {
namespace {

namespace rc = ros_conversions;
namespace enc = sensor_msgs::image_encodings;

sensor_msgs::ImagePtr image(const std::string& encoding, int width, int height, int bytes_per_pixel) {
  auto m = boost::make_shared<sensor_msgs::Image>();
  m->encoding = encoding;
  m->width = width;
  m->height = height;
  m->step = width * bytes_per_pixel;
  m->data.resize(m->step * height);
  for (std::size_t i = 0; i < m->data.size(); ++i) m->data[i] = static_cast<std::uint8_t>(i % 251);
  return m;
}

TEST(SensorConversions, Mono8AndBgr8AreSharedNotCopied) {
  for (const auto& [e, bpp] : {std::pair<std::string, int>{enc::MONO8, 1}, {enc::BGR8, 3}}) {
    const sensor_msgs::ImageConstPtr m = image(e, 40, 30, bpp);
    cv::Mat out;
    std::string why;
    ASSERT_TRUE(rc::imageFromMsg(m, &out, &why)) << why;
    EXPECT_EQ(out.cols, 40);
    EXPECT_EQ(out.rows, 30);
    EXPECT_EQ(out.channels(), bpp);
    EXPECT_EQ(out.data, m->data.data()) << e;
  }
}

TEST(SensorConversions, RgbIsTurnedIntoBgrAndMono16IntoMono8) {
  auto rgb = image(enc::RGB8, 4, 2, 3);
  rgb->data[0] = 10;  // R of pixel 0
  rgb->data[2] = 200;  // B
  cv::Mat out;
  ASSERT_TRUE(rc::imageFromMsg(rgb, &out));
  ASSERT_EQ(out.type(), CV_8UC3);
  EXPECT_EQ(out.at<cv::Vec3b>(0, 0)[0], 200);  // B first
  EXPECT_EQ(out.at<cv::Vec3b>(0, 0)[2], 10);
  ASSERT_TRUE(rc::imageFromMsg(image(enc::MONO16, 4, 2, 2), &out));
  EXPECT_EQ(out.type(), CV_8UC1);
  ASSERT_TRUE(rc::imageFromMsg(image(enc::BGRA8, 4, 2, 4), &out));
  EXPECT_EQ(out.type(), CV_8UC3);
}

TEST(SensorConversions, UnusableImagesAreRefusedWithAReason) {
  cv::Mat out;
  std::string why;
  EXPECT_FALSE(rc::imageFromMsg(image(enc::BAYER_RGGB8, 8, 8, 1), &out, &why));
  EXPECT_NE(why.find("bayer_rggb8"), std::string::npos) << why;
  EXPECT_FALSE(rc::imageFromMsg(image(enc::TYPE_32FC1, 8, 8, 4), &out, &why));
  EXPECT_FALSE(rc::imageFromMsg(image(enc::MONO8, 0, 0, 1), &out, &why));
  EXPECT_NE(why.find("empty"), std::string::npos) << why;
  auto short_data = image(enc::BGR8, 8, 8, 3);
  short_data->data.resize(10);
  EXPECT_FALSE(rc::imageFromMsg(short_data, &out, &why));
  EXPECT_NE(why.find("does not fit"), std::string::npos) << why;
  auto bad_step = image(enc::BGR8, 8, 8, 3);
  bad_step->step = 8;  // less than width x 3
  EXPECT_FALSE(rc::imageFromMsg(bad_step, &out, &why));
  EXPECT_FALSE(rc::imageFromMsg(sensor_msgs::ImageConstPtr(), &out, &why));
}

sensor_msgs::CameraInfo cameraInfo() {
  sensor_msgs::CameraInfo c;
  c.width = 320;
  c.height = 240;
  c.K = {300, 0, 159.5, 0, 310, 119.5, 0, 0, 1};
  c.D = {0, 0, 0, 0, 0};
  return c;
}

TEST(SensorConversions, CameraFromK) {
  core::CameraIntrinsics cam;
  bool distorted = true;
  ASSERT_TRUE(rc::cameraFromMsg(cameraInfo(), &cam, &distorted));
  EXPECT_EQ(cam.width, 320);
  EXPECT_DOUBLE_EQ(cam.fy, 310);
  EXPECT_DOUBLE_EQ(cam.cx, 159.5);
  EXPECT_FALSE(distorted);
  auto d = cameraInfo();
  d.D[0] = -0.1;
  ASSERT_TRUE(rc::cameraFromMsg(d, &cam, &distorted));
  EXPECT_TRUE(distorted);

  std::string why;
  auto zero = cameraInfo();
  zero.K[0] = 0.0;
  EXPECT_FALSE(rc::cameraFromMsg(zero, &cam, nullptr, &why));
  EXPECT_NE(why.find("focal"), std::string::npos) << why;
  auto no_size = cameraInfo();
  no_size.width = 0;
  EXPECT_FALSE(rc::cameraFromMsg(no_size, &cam, nullptr, &why));
  auto outside = cameraInfo();
  outside.K[2] = 900;
  EXPECT_FALSE(rc::cameraFromMsg(outside, &cam, nullptr, &why));
  EXPECT_NE(why.find("principal point"), std::string::npos) << why;
}

TEST(SensorConversions, AltitudeFromRange) {
  sensor_msgs::Range r;
  r.min_range = 0.1;
  r.max_range = 100;
  r.range = 2.5;
  double a = 0;
  ASSERT_TRUE(rc::altitudeFromMsg(r, &a));
  EXPECT_DOUBLE_EQ(a, 2.5);
  std::string why;
  for (float bad : {std::numeric_limits<float>::quiet_NaN(), std::numeric_limits<float>::infinity(), -1.0f, 0.0f,
                    0.05f, 150.0f}) {
    r.range = bad;
    a = 7;
    EXPECT_FALSE(rc::altitudeFromMsg(r, &a, &why)) << bad;
    EXPECT_DOUBLE_EQ(a, 7) << "untouched on failure";
    EXPECT_FALSE(why.empty());
  }
}

}  // namespace
}  // namespace uw_multislam
