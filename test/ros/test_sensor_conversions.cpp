// Image, CameraInfo and Range messages -> the odometry's inputs (no master needed).
#include <gtest/gtest.h>

#include <sensor_msgs/image_encodings.h>

#include <boost/make_shared.hpp>

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <limits>

#include "uw_multislam/core/frontend/camera_model.h"
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
    const sensor_msgs::ImageConstPtr m = image(e, 40, 32, bpp);
    cv::Mat out;
    std::string why;
    ASSERT_TRUE(rc::imageFromMsg(m, &out, &why)) << why;
    EXPECT_EQ(out.cols, 40);
    EXPECT_EQ(out.rows, 32);
    EXPECT_EQ(out.channels(), bpp);
    EXPECT_EQ(out.data, m->data.data()) << e;
  }
}

TEST(SensorConversions, RgbIsTurnedIntoBgrAndAlphaDropped) {
  auto rgb = image(enc::RGB8, 40, 32, 3);
  rgb->data[0] = 10;   // R of pixel 0
  rgb->data[2] = 200;  // B
  cv::Mat out;
  ASSERT_TRUE(rc::imageFromMsg(rgb, &out));
  ASSERT_EQ(out.type(), CV_8UC3);
  EXPECT_EQ(out.at<cv::Vec3b>(0, 0)[0], 200);  // B first
  EXPECT_EQ(out.at<cv::Vec3b>(0, 0)[2], 10);
  for (const std::string& e : {enc::BGRA8, enc::RGBA8, enc::TYPE_8UC4}) {
    auto m = image(e, 40, 32, 4);
    m->data[0] = 30, m->data[1] = 60, m->data[2] = 90, m->data[3] = 7;  // pixel 0, alpha 7
    std::string why;
    ASSERT_TRUE(rc::imageFromMsg(m, &out, &why)) << e << ": " << why;
    ASSERT_EQ(out.type(), CV_8UC3) << e;
    const cv::Vec3b p = out.at<cv::Vec3b>(0, 0);
    if (e == enc::RGBA8) {
      EXPECT_EQ(p, cv::Vec3b(90, 60, 30)) << e;
    } else {
      EXPECT_EQ(p, cv::Vec3b(30, 60, 90)) << e;
    }
  }
}

sensor_msgs::ImagePtr image16(const std::string& encoding, int channels, std::uint16_t first, std::uint16_t rest) {
  auto m = image(encoding, 40, 32, 2 * channels);
  auto* p = reinterpret_cast<std::uint16_t*>(m->data.data());
  for (std::size_t i = 0; i < m->data.size() / 2; ++i) p[i] = i == 0 ? first : rest;
  m->is_bigendian = false;
  return m;
}

TEST(SensorConversions, SixteenBitsAreScaledByThePowerOfTwoRangeOfTheFrame) {
  cv::Mat out;
  // A 12-bit sensor in mono16: 4000 is near its top, so near 255, not 4000 / 257 = 15.
  ASSERT_TRUE(rc::imageFromMsg(image16(enc::MONO16, 1, 4000, 1000), &out));
  ASSERT_EQ(out.type(), CV_8UC1);
  EXPECT_EQ(out.at<std::uint8_t>(0, 0), 249);  // 4000 * 255 / 4095
  EXPECT_EQ(out.at<std::uint8_t>(0, 1), 62);   // 1000 * 255 / 4095
  // A full 16-bit frame.
  ASSERT_TRUE(rc::imageFromMsg(image16(enc::TYPE_16UC1, 1, 65535, 257), &out));
  EXPECT_EQ(out.at<std::uint8_t>(0, 0), 255);
  EXPECT_EQ(out.at<std::uint8_t>(0, 1), 1);
  // An 8-bit range in 16 bits stays as it is.
  ASSERT_TRUE(rc::imageFromMsg(image16(enc::MONO16, 1, 200, 100), &out));
  EXPECT_EQ(out.at<std::uint8_t>(0, 0), 200);
  // Colour: rgb16 -> bgr8.
  ASSERT_TRUE(rc::imageFromMsg(image16(enc::RGB16, 3, 65535, 0), &out));
  ASSERT_EQ(out.type(), CV_8UC3);
  EXPECT_EQ(out.at<cv::Vec3b>(0, 0), cv::Vec3b(0, 0, 255));  // R of pixel 0 is now its third channel
}

TEST(SensorConversions, BayerIsDebayered) {
  // An RGGB mosaic of a flat colour: R = 200, G = 100, B = 50.
  auto m = image(enc::BAYER_RGGB8, 40, 32, 1);
  for (int r = 0; r < 32; ++r) {
    for (int c = 0; c < 40; ++c) {
      m->data[r * 40 + c] = (r % 2 == 0 && c % 2 == 0) ? 200 : (r % 2 == 1 && c % 2 == 1) ? 50 : 100;
    }
  }
  cv::Mat out;
  std::string why;
  ASSERT_TRUE(rc::imageFromMsg(m, &out, &why)) << why;
  ASSERT_EQ(out.type(), CV_8UC3);
  EXPECT_EQ(out.at<cv::Vec3b>(16, 20), cv::Vec3b(50, 100, 200));  // B, G, R
  // The other patterns and 16 bits are accepted too.
  for (const std::string& e : {enc::BAYER_BGGR8, enc::BAYER_GBRG8, enc::BAYER_GRBG8}) {
    EXPECT_TRUE(rc::imageFromMsg(image(e, 40, 32, 1), &out, &why)) << e << ": " << why;
  }
  ASSERT_TRUE(rc::imageFromMsg(image16(enc::BAYER_GRBG16, 1, 1000, 500), &out, &why)) << why;
  EXPECT_EQ(out.type(), CV_8UC3);
}

TEST(SensorConversions, UnusableImagesAreRefusedWithAReasonAndAKind) {
  cv::Mat out;
  std::string why;
  rc::ImageRefusal kind = rc::ImageRefusal::kNone;
  for (const auto& [e, bpp] : {std::pair<std::string, int>{enc::TYPE_32FC1, 4}, {enc::YUV422, 2}, {enc::TYPE_8SC1, 1},
                               {enc::TYPE_8UC2, 2}, {"h264", 1}}) {
    EXPECT_FALSE(rc::imageFromMsg(image(e, 40, 32, bpp), &out, &why, &kind)) << e;
    EXPECT_EQ(kind, rc::ImageRefusal::kEncoding) << e;
    EXPECT_NE(why.find(e), std::string::npos) << why;
  }
  EXPECT_FALSE(rc::imageFromMsg(image(enc::MONO8, 0, 0, 1), &out, &why, &kind));
  EXPECT_EQ(kind, rc::ImageRefusal::kEmpty);
  EXPECT_NE(why.find("empty"), std::string::npos) << why;
  auto no_data = image(enc::MONO8, 40, 32, 1);
  no_data->data.clear();
  EXPECT_FALSE(rc::imageFromMsg(no_data, &out, &why, &kind));
  EXPECT_EQ(kind, rc::ImageRefusal::kEmpty);
  auto short_data = image(enc::BGR8, 40, 32, 3);
  short_data->data.resize(10);
  EXPECT_FALSE(rc::imageFromMsg(short_data, &out, &why, &kind));
  EXPECT_NE(why.find("does not fit"), std::string::npos) << why;
  EXPECT_EQ(kind, rc::ImageRefusal::kLayout);
  auto bad_step = image(enc::BGR8, 40, 32, 3);
  bad_step->step = 40;  // less than width x 3
  EXPECT_FALSE(rc::imageFromMsg(bad_step, &out, &why, &kind));
  EXPECT_EQ(kind, rc::ImageRefusal::kLayout);
  for (const auto& [w, h] : {std::pair<int, int>{8, 8}, {1, 1}, {640, 8}, {31, 480}}) {
    EXPECT_FALSE(rc::imageFromMsg(image(enc::MONO8, w, h, 1), &out, &why, &kind)) << w << "x" << h;
    EXPECT_EQ(kind, rc::ImageRefusal::kTooSmall);
    EXPECT_NE(why.find("smaller"), std::string::npos) << why;
  }
  EXPECT_TRUE(rc::imageFromMsg(image(enc::MONO8, 32, 32, 1), &out, &why, &kind)) << why;
  EXPECT_EQ(kind, rc::ImageRefusal::kNone);
  EXPECT_FALSE(rc::imageFromMsg(sensor_msgs::ImageConstPtr(), &out, &why, &kind));
  EXPECT_EQ(rc::imageRefusalName(rc::ImageRefusal::kTooSmall), "too_small");
}

TEST(SensorConversions, ImagesLargerThanTheLimitAreRefusedBeforeAnyConversion) {
  cv::Mat out;
  std::string why;
  rc::ImageRefusal kind = rc::ImageRefusal::kNone;
  // 200 x 100 = 20000 pixels: one over the limit is refused, at the limit converted.
  EXPECT_FALSE(rc::imageFromMsg(image(enc::BGR8, 200, 100, 3), &out, &why, &kind, 19999));
  EXPECT_EQ(kind, rc::ImageRefusal::kTooLarge);
  EXPECT_NE(why.find("200x100"), std::string::npos) << why;
  EXPECT_NE(why.find("19999"), std::string::npos) << why;
  EXPECT_TRUE(out.empty());
  EXPECT_TRUE(rc::imageFromMsg(image(enc::BGR8, 200, 100, 3), &out, &why, &kind, 20000)) << why;
  EXPECT_EQ(kind, rc::ImageRefusal::kNone);
  // The default limit (a survey camera's 25 Mpx) refuses the probe's 10000 x 10000 image by its
  // header alone: the check needs neither its data nor any allocation.
  auto huge = image(enc::MONO8, 32, 32, 1);
  huge->width = huge->height = huge->step = 10000;
  EXPECT_FALSE(rc::imageFromMsg(huge, &out, &why, &kind));
  EXPECT_EQ(kind, rc::ImageRefusal::kTooLarge) << why;
  EXPECT_GE(rc::kDefaultMaxImagePixels, 4096u * 4096u);
  EXPECT_LT(rc::kDefaultMaxImagePixels, 10000u * 10000u);
  EXPECT_EQ(rc::imageRefusalName(rc::ImageRefusal::kTooLarge), "too_large");
}

sensor_msgs::CameraInfo cameraInfo() {
  sensor_msgs::CameraInfo c;
  c.width = 320;
  c.height = 240;
  c.distortion_model = "plumb_bob";
  c.K = {300, 0, 159.5, 0, 310, 119.5, 0, 0, 1};
  c.D = {0, 0, 0, 0, 0};
  c.R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  c.P = {280, 0, 150.5, 0, 0, 290, 110.5, 0, 0, 0, 1, 0};
  return c;
}

TEST(SensorConversions, CameraFromK) {
  core::CameraIntrinsics cam;
  ASSERT_TRUE(rc::cameraFromMsg(cameraInfo(), false, &cam));
  EXPECT_EQ(cam.width, 320);
  EXPECT_DOUBLE_EQ(cam.fy, 310);
  EXPECT_DOUBLE_EQ(cam.cx, 159.5);
  EXPECT_FALSE(cam.distorted());
  EXPECT_EQ(cam.distortion_model, core::DistortionModel::kNone) << "zero D: nothing to undistort";

  std::string why;
  auto zero = cameraInfo();
  zero.K[0] = 0.0;
  EXPECT_FALSE(rc::cameraFromMsg(zero, false, &cam, &why));
  EXPECT_NE(why.find("focal"), std::string::npos) << why;
  auto no_size = cameraInfo();
  no_size.width = 0;
  EXPECT_FALSE(rc::cameraFromMsg(no_size, false, &cam, &why));
  auto outside = cameraInfo();
  outside.K[2] = 900;
  EXPECT_FALSE(rc::cameraFromMsg(outside, false, &cam, &why));
  EXPECT_NE(why.find("principal point"), std::string::npos) << why;
}

TEST(SensorConversions, CameraKeepsTheDistortionOfRawImages) {
  core::CameraIntrinsics cam;
  auto d = cameraInfo();
  d.D = {-0.25, 0.08, 0.001, -0.002, 0.01};
  ASSERT_TRUE(rc::cameraFromMsg(d, false, &cam));
  EXPECT_EQ(cam.distortion_model, core::DistortionModel::kPlumbBob);
  EXPECT_EQ(cam.distortion, d.D);
  EXPECT_DOUBLE_EQ(cam.fx, 300) << "raw images: K, not P";
  d.distortion_model = "rational_polynomial";
  d.D = {-0.25, 0.08, 0.001, -0.002, 0.01, 0.1, 0.02, 0.003};
  ASSERT_TRUE(rc::cameraFromMsg(d, false, &cam));
  EXPECT_EQ(cam.distortion_model, core::DistortionModel::kRationalPolynomial);
  EXPECT_EQ(cam.distortion, d.D);

  std::string why;
  d.distortion_model = "equidistant";
  d.D = {0.1, 0.01, 0.0, 0.0};
  EXPECT_FALSE(rc::cameraFromMsg(d, false, &cam, &why));
  EXPECT_NE(why.find("'equidistant' is not supported"), std::string::npos) << why;
  d.distortion_model = "plumb_bob";
  d.D = {0.1, 0.01, 0.0};
  EXPECT_FALSE(rc::cameraFromMsg(d, false, &cam, &why));
  EXPECT_NE(why.find("plumb_bob with 3 coefficients"), std::string::npos) << why;
}

TEST(SensorConversions, RectifiedImagesTakeP) {
  core::CameraIntrinsics cam;
  auto d = cameraInfo();
  d.D = {-0.25, 0.08, 0.001, -0.002, 0.01};
  ASSERT_TRUE(rc::cameraFromMsg(d, true, &cam));
  EXPECT_EQ(cam, (core::CameraIntrinsics{320, 240, 280, 290, 150.5, 110.5})) << "P, and no distortion";
  std::string why;
  d.P = {};
  EXPECT_FALSE(rc::cameraFromMsg(d, true, &cam, &why));
  EXPECT_NE(why.find("P is zero"), std::string::npos) << why;
}

TEST(SensorConversions, BinningAndRoiAreApplied) {
  core::CameraIntrinsics cam;
  auto b = cameraInfo();
  b.D = {-0.25, 0.08, 0.001, -0.002, 0.01};
  b.binning_x = 2;
  b.binning_y = 2;
  ASSERT_TRUE(rc::cameraFromMsg(b, false, &cam));
  EXPECT_EQ(cam.width, 160);
  EXPECT_EQ(cam.height, 120);
  EXPECT_DOUBLE_EQ(cam.fx, 150);
  EXPECT_DOUBLE_EQ(cam.fy, 155);
  EXPECT_DOUBLE_EQ(cam.cx, 159.5 / 2);
  EXPECT_EQ(cam.distortion, b.D) << "D is in normalised coordinates: unchanged by binning";
  ASSERT_TRUE(rc::cameraFromMsg(b, true, &cam));
  EXPECT_DOUBLE_EQ(cam.fx, 140);
  EXPECT_DOUBLE_EQ(cam.cy, 110.5 / 2);

  auto roi = cameraInfo();
  roi.roi.x_offset = 40;
  roi.roi.y_offset = 20;
  roi.roi.width = 200;
  roi.roi.height = 180;
  ASSERT_TRUE(rc::cameraFromMsg(roi, false, &cam));
  EXPECT_EQ(cam.width, 200);
  EXPECT_EQ(cam.height, 180);
  EXPECT_DOUBLE_EQ(cam.fx, 300);
  EXPECT_DOUBLE_EQ(cam.cx, 119.5);
  EXPECT_DOUBLE_EQ(cam.cy, 99.5);
}

TEST(SensorConversions, CameraInfoFromUrl) {
  const std::string dir = ::testing::TempDir() + "uwms_camera_info_url_" + std::to_string(::getpid());
  std::filesystem::create_directories(dir);
  core::CameraIntrinsics written{320, 240, 300.0, 305.0, 161.0, 118.0};
  written.distortion_model = core::DistortionModel::kPlumbBob;
  written.distortion = {-0.28, 0.09, 0.001, -0.0007, -0.01};
  const std::string path = dir + "/cam.yaml";
  std::ofstream(path) << core::rosCalibrationYaml(written, "down");
  for (const std::string& url : {"file://" + path, path}) {
    sensor_msgs::CameraInfo info;
    std::string why;
    ASSERT_TRUE(rc::cameraInfoFromUrl(url, &info, &why)) << why;
    core::CameraIntrinsics cam;
    ASSERT_TRUE(rc::cameraFromMsg(info, false, &cam, &why)) << why;
    EXPECT_EQ(cam, written) << url;
  }
  sensor_msgs::CameraInfo info;
  std::string why;
  EXPECT_FALSE(rc::cameraInfoFromUrl("file://" + dir + "/missing.yaml", &info, &why));
  EXPECT_NE(why.find("cannot read a calibration from " + dir + "/missing.yaml"), std::string::npos) << why;
  EXPECT_FALSE(rc::cameraInfoFromUrl("http://example.org/cam.yaml", &info, &why));
  EXPECT_NE(why.find("expected file:///absolute/path"), std::string::npos) << why;
  EXPECT_FALSE(rc::cameraInfoFromUrl("package://no_such_package_uwms/cam.yaml", &info, &why));
  EXPECT_NE(why.find("no such package"), std::string::npos) << why;
  std::filesystem::remove_all(dir);
}

TEST(SensorConversions, AltitudeFromRange) {
  sensor_msgs::Range r;
  r.min_range = 0.1;
  r.max_range = 100;
  r.range = 2.5;
  double a = 0;
  ASSERT_TRUE(rc::altitudeFromMsg(r, 200.0, &a));
  EXPECT_DOUBLE_EQ(a, 2.5);
  std::string why;
  for (float bad : {std::numeric_limits<float>::quiet_NaN(), std::numeric_limits<float>::infinity(), -1.0f, 0.0f,
                    0.05f, 150.0f}) {
    r.range = bad;
    a = 7;
    EXPECT_FALSE(rc::altitudeFromMsg(r, 200.0, &a, &why)) << bad;
    EXPECT_DOUBLE_EQ(a, 7) << "untouched on failure";
    EXPECT_FALSE(why.empty());
  }
  // Above slam/odometry/max_altitude_m: refused even where the message claims no range (0 = none)
  // or a range that holds it (an altimeter's "no bottom" 9999).
  for (float claimed_max : {0.0f, 10000.0f}) {
    r.max_range = claimed_max;
    r.range = 9999.0f;
    EXPECT_FALSE(rc::altitudeFromMsg(r, 200.0, &a, &why)) << claimed_max;
    EXPECT_NE(why.find("above slam/odometry/max_altitude_m (200)"), std::string::npos) << why;
    r.range = 150.0f;
    EXPECT_TRUE(rc::altitudeFromMsg(r, 200.0, &a, &why)) << claimed_max;
  }
}

TEST(SensorConversions, NavFromOdometryUndoesTheMountAndRefusesBadReadings) {
  // The camera 0.4 m ahead of base_link, turned 0.3 rad: two camera poses (image axes) published
  // as the vehicle's z-up odometry come back exactly, so the nav's motions are the camera's.
  core::CameraMount mount;
  mount.base_from_camera = core::Pose2(0.4, -0.1, 0.3);
  const std::vector<core::Pose2> cameras = {core::Pose2(1.0, 2.0, 0.2), core::Pose2(1.7, 2.4, -0.5)};
  for (const core::Pose2& c : cameras) {
    const core::Pose2 v = core::vehicleFromCamera(c, mount);
    nav_msgs::Odometry m;
    m.header.stamp = ros::Time(100.5);
    m.pose.pose.position.x = v.x();
    m.pose.pose.position.y = v.y();
    m.pose.pose.orientation.z = std::sin(v.yaw() / 2);
    m.pose.pose.orientation.w = std::cos(v.yaw() / 2);
    m.pose.covariance[0] = 0.04;
    m.pose.covariance[7] = 0.09;
    m.pose.covariance[35] = 0.0001;
    core::NavRecord r;
    std::string why;
    ASSERT_TRUE(rc::navFromMsg(m, mount, &r, &why)) << why;
    EXPECT_TRUE(core::approxEqual(r.pose, c, 1e-9, 1e-9)) << r.pose << " vs " << c;
    EXPECT_DOUBLE_EQ(r.stamp_s, 100.5);
    EXPECT_NEAR(r.sigma_xy_m, 0.3, 1e-12) << "the larger of x and y";
    EXPECT_NEAR(r.sigma_yaw_rad, 0.01, 1e-12);
    nav_msgs::Odometry bad = m;
    bad.pose.pose.position.x = std::nan("");
    EXPECT_FALSE(rc::navFromMsg(bad, mount, &r, &why));
    bad = m;
    bad.pose.covariance[35] = -1.0;
    EXPECT_FALSE(rc::navFromMsg(bad, mount, &r, &why));
    EXPECT_NE(why.find("covariance"), std::string::npos) << why;
    bad = m;
    bad.header.stamp = ros::Time();
    EXPECT_FALSE(rc::navFromMsg(bad, mount, &r, &why));
    EXPECT_NE(why.find("zero stamp"), std::string::npos) << why;
  }
}

}  // namespace
}  // namespace uw_multislam
