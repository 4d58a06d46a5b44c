// Dataset folder -> bag: topics, types, counts, stamps, pixel-exact images, intrinsics, altitude,
// ground truth, and clear errors. Builds its own small dataset in a temp dir; no ROS master.
#include <gtest/gtest.h>

#include <cv_bridge/cv_bridge.h>
#include <nav_msgs/Odometry.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/Range.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>

#include "../common/scoped_temp_dir.h"
#include "uw_multislam/ros/dataset_bag.h"
#include "uw_multislam/ros/sensor_conversions.h"

namespace uw_multislam {
namespace ros_bag {
namespace {

namespace fs = std::filesystem;
using core::CameraIntrinsics;
using core::FrameRecord;
using core::GroundTruthRecord;
using core::Pose2;

constexpr int kWidth = 64;
constexpr int kHeight = 48;
constexpr int kGreyFrame = 4;  // the one grey image; the others are colour

// Frames as written to frames.csv (stamps and altitudes with few decimals: they survive the CSV).
std::vector<FrameRecord> sourceFrames() {
  return {{0, "0000.png", 0.0, 2.0},
          {1, "0001.png", 0.25, 2.125},
          {2, "0002.png", 0.5, 2.5},
          {3, "0003.png", 1.0, 3.0},
          {4, "0004.png", 1.5, 2.75}};
}

std::vector<GroundTruthRecord> sourceGroundTruth() {
  return {{0, "0000.png", Pose2(0.0, 0.0, 0.0)},
          {1, "0001.png", Pose2(0.5, -0.25, 0.5)},
          {2, "0002.png", Pose2(1.0, 0.75, 3.1)},
          {3, "0003.png", Pose2(-0.5, 2.0, -2.5)},
          {4, "0004.png", Pose2(0.125, 1.5, -0.75)}};
}

const CameraIntrinsics kCamera{kWidth, kHeight, 50.0, 51.0, 31.5, 23.5};

struct TopicSummary {
  std::string datatype;
  std::size_t count = 0;
};

// Every topic of a bag with its type and message count.
std::map<std::string, TopicSummary> topicsOf(const std::string& path) {
  rosbag::Bag bag(path, rosbag::bagmode::Read);
  rosbag::View view(bag);
  std::map<std::string, TopicSummary> out;
  for (const rosbag::ConnectionInfo* c : view.getConnections()) out[c->topic].datatype = c->datatype;
  for (const rosbag::MessageInstance& m : view) ++out[m.getTopic()].count;
  return out;
}

// The messages of one topic in bag order, with their bag (receive) times.
template <typename M>
std::vector<typename M::ConstPtr> read(const std::string& path, const std::string& topic,
                                       std::vector<ros::Time>* bag_times = nullptr) {
  rosbag::Bag bag(path, rosbag::bagmode::Read);
  std::vector<typename M::ConstPtr> out;
  for (const rosbag::MessageInstance& m : rosbag::View(bag, rosbag::TopicQuery(topic))) {
    auto msg = m.instantiate<M>();
    EXPECT_TRUE(msg != nullptr) << topic << " holds a " << m.getDataType();
    if (!msg) continue;
    out.push_back(msg);
    if (bag_times) bag_times->push_back(m.getTime());
  }
  return out;
}

double yawOf(const geometry_msgs::Quaternion& q) {
  return std::atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z));
}

class DatasetBagTest : public ::testing::Test {
 protected:
  void SetUp() override {
    data_ = root_ / "data";
    fs::create_directories(data_);
    bag_ = (root_ / "out.bag").string();
    frames_ = sourceFrames();
  }

  // Textured images (seeded noise), lossless PNG: four colour and one grey.
  void writeImages() {
    cv::RNG rng(12345);
    images_.clear();
    for (const auto& f : frames_) {
      cv::Mat image(kHeight, kWidth, f.index == kGreyFrame ? CV_8UC1 : CV_8UC3);
      rng.fill(image, cv::RNG::UNIFORM, 0, 256);
      ASSERT_TRUE(cv::imwrite((data_ / f.image).string(), image));
      images_.push_back(image);
    }
  }
  void writeDataset(bool with_ground_truth = true) {
    writeImages();
    core::writeCameraYaml((data_ / "camera.yaml").string(), kCamera);
    core::writeFramesCsv((data_ / "frames.csv").string(), frames_);
    if (with_ground_truth) core::writeGroundTruthCsv((data_ / "gt.csv").string(), sourceGroundTruth());
  }
  core::Dataset load() const { return core::loadDataset(data_.string()); }
  DatasetBagStats convert(const DatasetBagOptions& options = DatasetBagOptions()) {
    return writeDatasetBag(load(), options, bag_);
  }
  // Expects the conversion to throw a DatasetBagError whose message contains every needle.
  void expectError(const DatasetBagOptions& options, const std::vector<std::string>& needles) {
    try {
      writeDatasetBag(load(), options, bag_);
      ADD_FAILURE() << "no error";
    } catch (const DatasetBagError& e) {
      for (const auto& n : needles) EXPECT_NE(std::string(e.what()).find(n), std::string::npos) << e.what();
      EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos) << "not one line: " << e.what();
    }
  }

  testing_util::ScopedTempDir tmp_{"uwms_bag"};
  const fs::path root_ = tmp_.path();
  fs::path data_;
  std::string bag_;
  std::vector<FrameRecord> frames_;
  std::vector<cv::Mat> images_;
};

TEST_F(DatasetBagTest, WritesEveryTopicWithItsTypeAndCount) {
  writeDataset();
  const DatasetBagStats s = convert();
  EXPECT_EQ(s.frames, 5u);
  EXPECT_EQ(s.images, 5u);
  EXPECT_EQ(s.camera_infos, 5u);
  EXPECT_EQ(s.altitudes, 5u);
  EXPECT_EQ(s.ground_truth_poses, 5u);
  EXPECT_EQ(s.messages(), 20u);
  EXPECT_TRUE(warnings(s).empty());
  ASSERT_TRUE(fs::exists(bag_));
  EXPECT_EQ(s.bag_bytes, fs::file_size(bag_));
  EXPECT_FALSE(fs::exists(bag_ + ".active"));

  const auto topics = topicsOf(bag_);
  ASSERT_EQ(topics.size(), 4u);
  const std::map<std::string, std::string> expected = {{"/camera/image_raw", "sensor_msgs/Image"},
                                                       {"/camera/camera_info", "sensor_msgs/CameraInfo"},
                                                       {"/altitude", "sensor_msgs/Range"},
                                                       {"/ground_truth/odom", "nav_msgs/Odometry"}};
  for (const auto& [topic, type] : expected) {
    ASSERT_EQ(topics.count(topic), 1u) << topic;
    EXPECT_EQ(topics.at(topic).datatype, type) << topic;
    EXPECT_EQ(topics.at(topic).count, 5u) << topic;
  }
  const std::string line = summarize(s, DatasetBagOptions());
  EXPECT_NE(line.find("5 frames"), std::string::npos) << line;
  EXPECT_NE(line.find("/ground_truth/odom 5"), std::string::npos) << line;
}

TEST_F(DatasetBagTest, StampsAreStartPlusFrameStampAndIncrease) {
  writeDataset();
  DatasetBagOptions o;
  o.start_time = ros::Time(1234, 500000000);
  const DatasetBagStats s = convert(o);
  const std::int64_t start_ns = 1234500000000LL;
  auto expectStamps = [&](const std::string& topic, const std::vector<ros::Time>& header_stamps,
                          const std::vector<ros::Time>& bag_times) {
    ASSERT_EQ(header_stamps.size(), frames_.size()) << topic;
    for (std::size_t i = 0; i < frames_.size(); ++i) {
      const auto expected_ns = start_ns + std::llround(frames_[i].stamp_s * 1e9);
      EXPECT_EQ(static_cast<std::int64_t>(header_stamps[i].toNSec()), expected_ns) << topic << " frame " << i;
      EXPECT_EQ(bag_times[i], header_stamps[i]) << topic << " frame " << i;
      if (i > 0) {
        EXPECT_GT(header_stamps[i], header_stamps[i - 1]) << topic << " frame " << i;
      }
    }
  };
  std::vector<ros::Time> times, stamps;
  for (const auto& m : read<sensor_msgs::Image>(bag_, "/camera/image_raw", &times)) stamps.push_back(m->header.stamp);
  expectStamps("image", stamps, times);
  times.clear(), stamps.clear();
  for (const auto& m : read<sensor_msgs::CameraInfo>(bag_, "/camera/camera_info", &times)) {
    stamps.push_back(m->header.stamp);
  }
  expectStamps("camera_info", stamps, times);
  times.clear(), stamps.clear();
  for (const auto& m : read<sensor_msgs::Range>(bag_, "/altitude", &times)) stamps.push_back(m->header.stamp);
  expectStamps("altitude", stamps, times);
  times.clear(), stamps.clear();
  for (const auto& m : read<nav_msgs::Odometry>(bag_, "/ground_truth/odom", &times)) stamps.push_back(m->header.stamp);
  expectStamps("odom", stamps, times);
  EXPECT_EQ(s.first_stamp, ros::Time(1234, 500000000));
  EXPECT_EQ(s.last_stamp, ros::Time(1236, 0));
  EXPECT_TRUE(s.non_increasing_stamps.empty());
}

TEST_F(DatasetBagTest, DefaultStartTimeIsTheFixedEpochAndBagsAreReproducible) {
  writeDataset();
  convert();
  const auto images = read<sensor_msgs::Image>(bag_, "/camera/image_raw");
  ASSERT_EQ(images.size(), 5u);
  EXPECT_EQ(images[0]->header.stamp, ros::Time(kDefaultStartTimeSec, 0));
  EXPECT_EQ(images[3]->header.stamp, ros::Time(kDefaultStartTimeSec + 1, 0));

  auto bytes = [](const std::string& p) {
    std::ifstream in(p, std::ios::binary);
    std::ostringstream os;
    os << in.rdbuf();
    return os.str();
  };
  const std::string first = bytes(bag_);
  convert();
  EXPECT_EQ(bytes(bag_), first) << "converting the same folder twice gave different bags";
}

TEST_F(DatasetBagTest, ImagesArePixelExactWithTheirEncodings) {
  writeDataset();
  convert();
  const auto images = read<sensor_msgs::Image>(bag_, "/camera/image_raw");
  ASSERT_EQ(images.size(), images_.size());
  for (std::size_t i = 0; i < images.size(); ++i) {
    const bool grey = frames_[i].index == kGreyFrame;
    EXPECT_EQ(images[i]->encoding, grey ? "mono8" : "bgr8") << "frame " << i;
    EXPECT_EQ(images[i]->width, static_cast<unsigned>(kWidth));
    EXPECT_EQ(images[i]->height, static_cast<unsigned>(kHeight));
    EXPECT_EQ(images[i]->header.frame_id, "camera");
    const cv::Mat back = cv_bridge::toCvCopy(images[i])->image;
    ASSERT_EQ(back.type(), images_[i].type()) << "frame " << i;
    EXPECT_EQ(cv::norm(back, images_[i], cv::NORM_INF), 0.0) << "frame " << i << " pixels differ";
  }
}

TEST_F(DatasetBagTest, ForcedMono8EncodingConvertsColourImages) {
  writeDataset();
  DatasetBagOptions o;
  o.image_encoding = "mono8";
  convert(o);
  const auto images = read<sensor_msgs::Image>(bag_, "/camera/image_raw");
  ASSERT_EQ(images.size(), images_.size());
  for (std::size_t i = 0; i < images.size(); ++i) {
    EXPECT_EQ(images[i]->encoding, "mono8");
    cv::Mat expected = images_[i];
    if (expected.channels() == 3) cv::cvtColor(images_[i], expected, cv::COLOR_BGR2GRAY);
    const cv::Mat back = cv_bridge::toCvCopy(images[i])->image;
    ASSERT_EQ(back.type(), CV_8UC1);
    EXPECT_EQ(cv::norm(back, expected, cv::NORM_INF), 0.0) << "frame " << i;
  }
}

TEST_F(DatasetBagTest, CompressedImagesGoToTheCompressedTopicInThePluginsFormat) {
  writeDataset();
  for (const ImageFormat format : {ImageFormat::kPng, ImageFormat::kJpeg}) {
    const bool jpeg = format == ImageFormat::kJpeg;
    DatasetBagOptions o;
    o.image_format = format;
    o.jpeg_quality = 90;
    const DatasetBagStats s = convert(o);
    EXPECT_EQ(s.images, 5u);
    const auto topics = topicsOf(bag_);
    EXPECT_EQ(topics.count("/camera/image_raw"), 0u) << "the raw topic is not written as well";
    ASSERT_EQ(topics.count("/camera/image_raw/compressed"), 1u);
    EXPECT_EQ(topics.at("/camera/image_raw/compressed").datatype, "sensor_msgs/CompressedImage");
    EXPECT_EQ(topics.at("/camera/camera_info").count, 5u);
    EXPECT_NE(summarize(s, o).find("/camera/image_raw/compressed 5"), std::string::npos) << summarize(s, o);

    std::vector<ros::Time> times;
    const auto images = read<sensor_msgs::CompressedImage>(bag_, "/camera/image_raw/compressed", &times);
    ASSERT_EQ(images.size(), images_.size());
    for (std::size_t i = 0; i < images.size(); ++i) {
      const bool grey = frames_[i].index == kGreyFrame;
      const std::string codec = jpeg ? "jpeg" : "png";
      // compressed_image_transport's format: the encoding; the codec; colour's target.
      EXPECT_EQ(images[i]->format, grey ? "mono8; " + codec + " compressed " : "bgr8; " + codec + " compressed bgr8");
      EXPECT_EQ(images[i]->header.stamp, times[i]);
      EXPECT_EQ(images[i]->header.stamp, ros::Time(kDefaultStartTimeSec, 0) + ros::Duration(frames_[i].stamp_s));
      EXPECT_EQ(images[i]->header.frame_id, "camera");
      sensor_msgs::ImagePtr decoded;
      std::string why;
      ASSERT_TRUE(ros_conversions::imageFromCompressedMsg(*images[i], &decoded, &why)) << why;
      const cv::Mat back = cv_bridge::toCvShare(decoded)->image;
      ASSERT_EQ(back.type(), images_[i].type());
      if (jpeg) {
        // At the quality asked for: the pixels OpenCV's own JPEG round trip at 90 gives.
        std::vector<uchar> bytes;
        cv::imencode(".jpg", images_[i], bytes, {cv::IMWRITE_JPEG_QUALITY, 90});
        EXPECT_EQ(cv::norm(back, cv::imdecode(bytes, cv::IMREAD_UNCHANGED), cv::NORM_INF), 0.0) << "frame " << i;
      } else {
        EXPECT_EQ(cv::norm(back, images_[i], cv::NORM_INF), 0.0) << "frame " << i << ": PNG is lossless";
      }
    }
  }
  // The quality is applied: lower quality, smaller images.
  auto bytesAt = [&](int quality) {
    DatasetBagOptions o;
    o.image_format = ImageFormat::kJpeg;
    o.jpeg_quality = quality;
    convert(o);
    std::size_t n = 0;
    for (const auto& m : read<sensor_msgs::CompressedImage>(bag_, "/camera/image_raw/compressed")) n += m->data.size();
    return n;
  };
  EXPECT_LT(bytesAt(30), bytesAt(95));
}

TEST_F(DatasetBagTest, SixteenBitGreyIsNotWrittenAsJpeg) {
  writeDataset();
  DatasetBagOptions o;
  o.image_encoding = "mono16";
  o.image_format = ImageFormat::kJpeg;
  expectError(o, {"mono16", "JPEG", "png"});
  EXPECT_FALSE(fs::exists(bag_));
  o.image_format = ImageFormat::kPng;  // lossless 16 bits
  convert(o);
  const auto images = read<sensor_msgs::CompressedImage>(bag_, "/camera/image_raw/compressed");
  ASSERT_EQ(images.size(), 5u);
  EXPECT_EQ(images[0]->format, "mono16; png compressed ");
  EXPECT_EQ(cv::imdecode(images[0]->data, cv::IMREAD_UNCHANGED).type(), CV_16UC1);
}

TEST_F(DatasetBagTest, CameraInfoCarriesCameraYaml) {
  writeDataset();
  convert();
  const auto infos = read<sensor_msgs::CameraInfo>(bag_, "/camera/camera_info");
  ASSERT_EQ(infos.size(), 5u);
  for (const auto& m : infos) {
    EXPECT_EQ(m->header.frame_id, "camera");
    EXPECT_EQ(m->width, static_cast<unsigned>(kWidth));
    EXPECT_EQ(m->height, static_cast<unsigned>(kHeight));
    EXPECT_EQ(m->distortion_model, "plumb_bob");
    ASSERT_EQ(m->D.size(), 5u);
    for (double d : m->D) EXPECT_EQ(d, 0.0);
    const double K[9] = {50.0, 0.0, 31.5, 0.0, 51.0, 23.5, 0.0, 0.0, 1.0};
    for (int i = 0; i < 9; ++i) EXPECT_DOUBLE_EQ(m->K[i], K[i]) << "K[" << i << "]";
    const double P[12] = {50.0, 0.0, 31.5, 0.0, 0.0, 51.0, 23.5, 0.0, 0.0, 0.0, 1.0, 0.0};
    for (int i = 0; i < 12; ++i) EXPECT_DOUBLE_EQ(m->P[i], P[i]) << "P[" << i << "]";
    for (int i = 0; i < 9; ++i) EXPECT_DOUBLE_EQ(m->R[i], i % 4 == 0 ? 1.0 : 0.0) << "R[" << i << "]";
  }
}

TEST_F(DatasetBagTest, RangeIsTheAltitude) {
  writeDataset();
  convert();
  const auto ranges = read<sensor_msgs::Range>(bag_, "/altitude");
  ASSERT_EQ(ranges.size(), frames_.size());
  const AltimeterModel a;
  for (std::size_t i = 0; i < ranges.size(); ++i) {
    EXPECT_FLOAT_EQ(ranges[i]->range, static_cast<float>(frames_[i].altitude_m)) << "frame " << i;
    EXPECT_EQ(ranges[i]->radiation_type, sensor_msgs::Range::ULTRASOUND);
    EXPECT_FLOAT_EQ(ranges[i]->field_of_view, static_cast<float>(a.field_of_view_rad));
    EXPECT_FLOAT_EQ(ranges[i]->min_range, static_cast<float>(a.min_range_m));
    EXPECT_FLOAT_EQ(ranges[i]->max_range, static_cast<float>(a.max_range_m));
    EXPECT_EQ(ranges[i]->header.frame_id, "altimeter");
  }
}

TEST_F(DatasetBagTest, OdometryIsTheGroundTruthPose) {
  writeDataset();
  convert();
  const auto odom = read<nav_msgs::Odometry>(bag_, "/ground_truth/odom");
  const auto gt = sourceGroundTruth();
  ASSERT_EQ(odom.size(), gt.size());
  for (std::size_t i = 0; i < odom.size(); ++i) {
    const auto& p = odom[i]->pose.pose;
    EXPECT_EQ(odom[i]->header.frame_id, "gt_origin");
    EXPECT_EQ(odom[i]->child_frame_id, "camera");
    EXPECT_NEAR(p.position.x, gt[i].pose.x(), 1e-6) << "frame " << i;
    EXPECT_NEAR(p.position.y, gt[i].pose.y(), 1e-6) << "frame " << i;
    EXPECT_DOUBLE_EQ(p.position.z, 0.0);
    EXPECT_NEAR(core::normalizeAngle(yawOf(p.orientation) - gt[i].pose.yaw()), 0.0, 1e-6) << "frame " << i;
    for (double c : odom[i]->pose.covariance) EXPECT_EQ(c, 0.0);
  }
}

TEST_F(DatasetBagTest, NavCsvBecomesTheVehiclesNavOdometry) {
  writeDataset();
  // Two nav rows per frame (denser than the images), a yaw across +-pi.
  std::vector<core::NavRecord> nav;
  for (int i = 0; i < 10; ++i)
    nav.push_back({0.25 * i, core::Pose2(0.1 * i, -0.05 * i, 3.0 + 0.05 * i), 0.001 * i, 0.002});
  core::writeNavCsv((data_ / "nav.csv").string(), nav);
  nav = load().nav;  // as nav.csv holds them (7 decimals)
  ASSERT_EQ(nav.size(), 10u);
  const DatasetBagStats s = convert();
  EXPECT_EQ(s.nav_poses, nav.size());
  EXPECT_NE(summarize(s, DatasetBagOptions()).find("/nav/odom 10"), std::string::npos);
  const auto odom = read<nav_msgs::Odometry>(bag_, "/nav/odom");
  ASSERT_EQ(odom.size(), nav.size());
  for (std::size_t i = 0; i < odom.size(); ++i) {
    const auto& m = *odom[i];
    EXPECT_EQ(m.header.frame_id, "odom");
    EXPECT_EQ(m.child_frame_id, "base_link");
    EXPECT_EQ(m.header.stamp, ros::Time(kDefaultStartTimeSec, 0) + ros::Duration(nav[i].stamp_s));
    // z-up (REP-103): (x, y, yaw) of the image axes -> (x, -y, -yaw) for the default mount.
    EXPECT_NEAR(m.pose.pose.position.x, nav[i].pose.x(), 1e-6);
    EXPECT_NEAR(m.pose.pose.position.y, -nav[i].pose.y(), 1e-6);
    EXPECT_NEAR(core::normalizeAngle(yawOf(m.pose.pose.orientation) + nav[i].pose.yaw()), 0.0, 1e-6);
    EXPECT_NEAR(m.pose.covariance[0], nav[i].sigma_xy_m * nav[i].sigma_xy_m, 1e-12);
    EXPECT_NEAR(m.pose.covariance[35], 0.002 * 0.002, 1e-12);
    core::NavRecord back;
    ASSERT_TRUE(fromNavOdometryMsg(m, &back));
    EXPECT_TRUE(core::approxEqual(back.pose, nav[i].pose, 1e-9, 1e-9)) << back.pose << " vs " << nav[i].pose;
    EXPECT_NEAR(back.sigma_xy_m, nav[i].sigma_xy_m, 1e-9);
    EXPECT_NEAR(back.sigma_yaw_rad, 0.002, 1e-9);
  }
  DatasetBagOptions without;
  without.include_nav = false;
  EXPECT_EQ(convert(without).nav_poses, 0u);
  nav_msgs::Odometry bad = *odom[0];
  bad.pose.pose.position.x = std::nan("");
  core::NavRecord r;
  EXPECT_FALSE(fromNavOdometryMsg(bad, &r));
}

TEST_F(DatasetBagTest, NoGroundTruthTopicWithoutGtCsv) {
  writeDataset(/*with_ground_truth=*/false);
  const DatasetBagStats s = convert();
  EXPECT_EQ(s.ground_truth_poses, 0u);
  EXPECT_TRUE(s.frames_without_ground_truth.empty());  // nothing to miss without gt.csv
  const auto topics = topicsOf(bag_);
  EXPECT_EQ(topics.size(), 3u);
  EXPECT_EQ(topics.count("/ground_truth/odom"), 0u);
  EXPECT_EQ(topics.count("/camera/image_raw"), 1u);
}

TEST_F(DatasetBagTest, NoGroundTruthTopicWhenDisabled) {
  writeDataset();
  DatasetBagOptions o;
  o.include_ground_truth = false;
  const DatasetBagStats s = convert(o);
  EXPECT_EQ(s.ground_truth_poses, 0u);
  const auto topics = topicsOf(bag_);
  EXPECT_EQ(topics.size(), 3u);
  EXPECT_EQ(topics.count("/ground_truth/odom"), 0u);
}

TEST_F(DatasetBagTest, FramesMissingFromGtCsvAreCounted) {
  writeDataset(false);
  auto gt = sourceGroundTruth();
  gt.erase(gt.begin() + 4);
  gt.erase(gt.begin() + 2);
  core::writeGroundTruthCsv((data_ / "gt.csv").string(), gt);
  const DatasetBagStats s = convert();
  EXPECT_EQ(s.ground_truth_poses, 3u);
  EXPECT_EQ(s.frames_without_ground_truth, (std::vector<int>{2, 4}));
  EXPECT_EQ(read<nav_msgs::Odometry>(bag_, "/ground_truth/odom").size(), 3u);
  ASSERT_EQ(warnings(s).size(), 1u);
  EXPECT_NE(warnings(s)[0].find("gt.csv"), std::string::npos) << warnings(s)[0];
}

TEST_F(DatasetBagTest, GtCsvNamingAnotherImageIsAnError) {
  writeDataset(false);
  auto gt = sourceGroundTruth();
  gt[1].image = "0003.png";
  core::writeGroundTruthCsv((data_ / "gt.csv").string(), gt);
  expectError(DatasetBagOptions(), {"gt.csv", "frame 1", "0003.png"});
  EXPECT_FALSE(fs::exists(bag_));
}

TEST_F(DatasetBagTest, BrokenImageThrowsNamingTheFileAndKeepsTheOldBag) {
  writeDataset();
  std::ofstream(data_ / "0002.png") << "this is not a PNG";
  std::ofstream(bag_) << "previous bag";
  expectError(DatasetBagOptions(), {"0002.png", "cannot decode image"});
  std::ifstream in(bag_);
  std::string content;
  std::getline(in, content);
  EXPECT_EQ(content, "previous bag") << "a failed conversion must not replace the output";
  EXPECT_FALSE(fs::exists(bag_ + ".active"));
}

TEST_F(DatasetBagTest, TruncatedJpegThrowsNamingTheFile) {
  frames_[1].image = "0001.jpg";
  writeDataset(/*with_ground_truth=*/false);
  const std::string jpeg = (data_ / "0001.jpg").string();
  fs::resize_file(jpeg, fs::file_size(jpeg) / 2);  // as an interrupted copy leaves it
  expectError(DatasetBagOptions(), {"0001.jpg", "truncated JPEG"});
  EXPECT_FALSE(fs::exists(bag_));
}

TEST_F(DatasetBagTest, MissingImageThrowsNamingTheFile) {
  writeDataset();
  core::Dataset d = load();
  fs::remove(data_ / "0003.png");  // after loading, which checks that images exist
  try {
    writeDatasetBag(d, DatasetBagOptions(), bag_);
    ADD_FAILURE() << "no error";
  } catch (const DatasetBagError& e) {
    EXPECT_NE(std::string(e.what()).find("0003.png: cannot open"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(fs::exists(bag_));
}

TEST_F(DatasetBagTest, ImageSizeNotMatchingCameraYamlThrows) {
  writeDataset();
  ASSERT_TRUE(cv::imwrite((data_ / "0001.png").string(), cv::Mat(kHeight / 2, kWidth / 2, CV_8UC3, cv::Scalar(9))));
  expectError(DatasetBagOptions(), {"0001.png", "32x24", "camera.yaml", "64x48"});
  EXPECT_FALSE(fs::exists(bag_));
}

TEST_F(DatasetBagTest, InvalidAltitudeSkipsTheRangeAndIsCounted) {
  frames_[2].altitude_m = std::numeric_limits<double>::quiet_NaN();
  frames_[3].altitude_m = -1.0;  // below the altimeter's minimum range
  writeDataset();
  const DatasetBagStats s = convert();
  EXPECT_EQ(s.images, 5u);
  EXPECT_EQ(s.camera_infos, 5u);
  EXPECT_EQ(s.altitudes, 3u);
  EXPECT_EQ(s.frames_without_altitude, (std::vector<int>{2, 3}));
  const auto ranges = read<sensor_msgs::Range>(bag_, "/altitude");
  ASSERT_EQ(ranges.size(), 3u);
  for (const auto& r : ranges) EXPECT_TRUE(std::isfinite(r->range));
  EXPECT_FLOAT_EQ(ranges[2]->range, 2.75f);  // frame 4
  EXPECT_EQ(read<sensor_msgs::Image>(bag_, "/camera/image_raw").size(), 5u);
  ASSERT_EQ(warnings(s).size(), 1u);
  EXPECT_NE(warnings(s)[0].find("altitude"), std::string::npos) << warnings(s)[0];
}

TEST_F(DatasetBagTest, NonIncreasingStampsAreWrittenAndCounted) {
  frames_[2].stamp_s = 0.25;   // equal to frame 1
  frames_[3].stamp_s = 0.125;  // before frame 2
  writeDataset();
  const DatasetBagStats s = convert();
  EXPECT_EQ(s.images, 5u);
  EXPECT_EQ(s.non_increasing_stamps, (std::vector<int>{2, 3}));
  EXPECT_EQ(s.first_stamp, ros::Time(kDefaultStartTimeSec, 0));
  EXPECT_EQ(s.last_stamp, ros::Time(kDefaultStartTimeSec + 1, 500000000));
  EXPECT_EQ(read<sensor_msgs::Image>(bag_, "/camera/image_raw").size(), 5u);
  ASSERT_EQ(warnings(s).size(), 1u);
  EXPECT_NE(warnings(s)[0].find("stamp"), std::string::npos) << warnings(s)[0];
}

TEST_F(DatasetBagTest, NonFiniteStampIsAnErrorNamingFramesCsv) {
  frames_[1].stamp_s = std::numeric_limits<double>::infinity();
  writeDataset();
  expectError(DatasetBagOptions(), {"frames.csv", "frame 1", "stamp_s"});
  EXPECT_FALSE(fs::exists(bag_));
}

TEST_F(DatasetBagTest, UnwritableBagPathThrowsNamingIt) {
  writeDataset();
  bag_ = (root_ / "no_such_dir" / "out.bag").string();
  expectError(DatasetBagOptions(), {bag_, "cannot write bag"});
  bag_ = root_.string();  // a directory
  expectError(DatasetBagOptions(), {bag_, "is a directory"});
}

TEST_F(DatasetBagTest, CustomTopicsAndFramesAreUsed) {
  writeDataset();
  DatasetBagOptions o;
  o.topics.image = "/auv/down/image";
  o.topics.camera_info = "/auv/down/info";
  o.topics.altitude = "/auv/dvl/altitude";
  o.topics.ground_truth = "/auv/nav/truth";
  o.frames.camera = "down_cam";
  o.frames.altimeter = "dvl";
  o.frames.ground_truth_origin = "world_gt";
  convert(o);
  const auto topics = topicsOf(bag_);
  EXPECT_EQ(topics.size(), 4u);
  EXPECT_EQ(topics.count("/camera/image_raw"), 0u);
  const auto images = read<sensor_msgs::Image>(bag_, "/auv/down/image");
  ASSERT_EQ(images.size(), 5u);
  EXPECT_EQ(images[0]->header.frame_id, "down_cam");
  const auto infos = read<sensor_msgs::CameraInfo>(bag_, "/auv/down/info");
  ASSERT_EQ(infos.size(), 5u);
  EXPECT_EQ(infos[0]->header.frame_id, "down_cam");
  const auto ranges = read<sensor_msgs::Range>(bag_, "/auv/dvl/altitude");
  ASSERT_EQ(ranges.size(), 5u);
  EXPECT_EQ(ranges[0]->header.frame_id, "dvl");
  const auto odom = read<nav_msgs::Odometry>(bag_, "/auv/nav/truth");
  ASSERT_EQ(odom.size(), 5u);
  EXPECT_EQ(odom[0]->header.frame_id, "world_gt");
  EXPECT_EQ(odom[0]->child_frame_id, "down_cam");
}

TEST_F(DatasetBagTest, BadOptionsAreRejectedBeforeWriting) {
  writeDataset();
  DatasetBagOptions o;
  o.topics.altitude = o.topics.image;
  expectError(o, {"bad option", "used twice"});
  EXPECT_FALSE(fs::exists(bag_));
}

TEST(DatasetBagOptions, ValidateNamesTheBadOption) {
  EXPECT_EQ(DatasetBagOptions().validate(), "");
  auto bad = [](auto change) {
    DatasetBagOptions o;
    change(o);
    return o.validate();
  };
  EXPECT_NE(bad([](DatasetBagOptions& o) { o.frames.camera = ""; }).find("camera frame id"), std::string::npos);
  EXPECT_NE(bad([](DatasetBagOptions& o) { o.frames.altimeter = "/alt"; }).find("'/alt'"), std::string::npos);
  EXPECT_NE(bad([](DatasetBagOptions& o) { o.topics.image = "1bad"; }).find("image topic"), std::string::npos);
  EXPECT_NE(bad([](DatasetBagOptions& o) { o.topics.altitude = "~alt"; }).find("private"), std::string::npos);
  EXPECT_NE(bad([](DatasetBagOptions& o) { o.topics.ground_truth = "/camera/camera_info"; }).find("twice"),
            std::string::npos);
  EXPECT_NE(bad([](DatasetBagOptions& o) { o.image_encoding = "jpeg"; }).find("'jpeg'"), std::string::npos);
  EXPECT_NE(bad([](DatasetBagOptions& o) { o.start_time = ros::Time(); }).find("start time"), std::string::npos);
  EXPECT_NE(bad([](DatasetBagOptions& o) { o.jpeg_quality = 0; }).find("JPEG quality 0"), std::string::npos);
  EXPECT_NE(bad([](DatasetBagOptions& o) { o.jpeg_quality = 101; }).find("JPEG quality 101"), std::string::npos);
  EXPECT_NE(bad([](DatasetBagOptions& o) {
              o.image_format = ImageFormat::kPng;
              o.topics.altitude = "/camera/image_raw/compressed";
            }).find("twice"),
            std::string::npos);
  EXPECT_NE(bad([](DatasetBagOptions& o) { o.altimeter.field_of_view_rad = 0.0; }).find("field_of_view"),
            std::string::npos);
  EXPECT_NE(bad([](DatasetBagOptions& o) { o.altimeter.max_range_m = 0.05; }).find("range"), std::string::npos);
}

TEST(DatasetBagCameraInfo, IsPlumbBobWithKFromIntrinsics) {
  const auto m = toCameraInfoMsg(CameraIntrinsics{680, 512, 1000.0, 990.0, 340.0, 256.0});
  EXPECT_EQ(m.width, 680u);
  EXPECT_EQ(m.height, 512u);
  EXPECT_EQ(m.distortion_model, "plumb_bob");
  EXPECT_DOUBLE_EQ(m.K[0], 1000.0);
  EXPECT_DOUBLE_EQ(m.K[2], 340.0);
  EXPECT_DOUBLE_EQ(m.K[4], 990.0);
  EXPECT_DOUBLE_EQ(m.K[5], 256.0);
  EXPECT_DOUBLE_EQ(m.P[6], 256.0);
  EXPECT_DOUBLE_EQ(m.P[3], 0.0);
}

}  // namespace
}  // namespace ros_bag
}  // namespace uw_multislam
