#include "uw_multislam/ros/dataset_bag.h"

#include <cv_bridge/cv_bridge.h>
#include <nav_msgs/Odometry.h>
#include <ros/names.h>
#include <rosbag/bag.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/image_encodings.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <iomanip>
#include <map>
#include <memory>
#include <opencv2/imgcodecs.hpp>
#include <set>
#include <sstream>

#include "uw_multislam/core/frontend/image_file.h"
#include "uw_multislam/core/geometry/vehicle_frame.h"
#include "uw_multislam/ros/conversions.h"
#include "uw_multislam/ros/sensor_conversions.h"

namespace uw_multislam {
namespace ros_bag {

namespace fs = std::filesystem;

namespace {

const std::vector<std::string> kEncodings = {"mono8", "mono16", "bgr8", "rgb8", "bgr16", "rgb16"};

[[noreturn]] void fail(const std::string& what) { throw DatasetBagError(what); }

std::string frameLabel(const std::string& csv, const core::FrameRecord& f) {
  return csv + ": frame " + std::to_string(f.index);
}

// ------------------------------------------------------------------------------------------------
// Options

std::string checkTopic(const std::string& name, const char* what) {
  std::string error;
  if (name.empty()) return std::string(what) + " topic is empty";
  if (name.front() == '~') return std::string(what) + " topic '" + name + "' is private ('~'): a bag has no node";
  if (!ros::names::validate(name, error)) return std::string(what) + " topic '" + name + "' is invalid: " + error;
  return "";
}

std::string checkFrame(const std::string& id, const char* what) {
  if (id.empty()) return std::string(what) + " frame id is empty";
  if (id.front() == '/') return std::string(what) + " frame id '" + id + "' starts with '/' (tf2 rejects it)";
  if (id.find_first_of(" \t\n") != std::string::npos) return std::string(what) + " frame id '" + id + "' has spaces";
  return "";
}

std::string checkTopics(const BagTopics& t) {
  const std::pair<const std::string*, const char*> all[] = {{&t.image, "image"},
                                                            {&t.camera_info, "camera info"},
                                                            {&t.altitude, "altitude"},
                                                            {&t.ground_truth, "ground truth"},
                                                            {&t.nav, "nav"}};
  std::set<std::string> seen;
  for (const auto& [name, what] : all) {
    const std::string bad = checkTopic(*name, what);
    if (!bad.empty()) return bad;
    // One topic, one message type: a bag mixing types on a topic cannot be played.
    if (!seen.insert(ros::names::clean(*name)).second)
      return std::string(what) + " topic '" + *name + "' is used twice";
  }
  return "";
}

std::string checkAltimeter(const AltimeterModel& a) {
  std::ostringstream os;
  if (a.radiation_type != sensor_msgs::Range::ULTRASOUND && a.radiation_type != sensor_msgs::Range::INFRARED) {
    os << "altimeter radiation_type " << int(a.radiation_type) << " is neither ULTRASOUND (0) nor INFRARED (1)";
  } else if (!(std::isfinite(a.field_of_view_rad) && a.field_of_view_rad > 0.0 && a.field_of_view_rad <= M_PI)) {
    os << "altimeter field_of_view_rad " << a.field_of_view_rad << " is not in (0, pi]";
  } else if (!(std::isfinite(a.min_range_m) && std::isfinite(a.max_range_m) && a.min_range_m >= 0.0 &&
               a.min_range_m < a.max_range_m)) {
    os << "altimeter range [" << a.min_range_m << ", " << a.max_range_m << "] m is not 0 <= min < max";
  }
  return os.str();
}

// ------------------------------------------------------------------------------------------------
// Per-frame inputs

// Header stamp of a frame; the frame's time must be representable as a ros::Time (0, 2^32) s.
ros::Time frameStamp(const ros::Time& start, const core::FrameRecord& f, const std::string& csv) {
  if (!std::isfinite(f.stamp_s)) fail(frameLabel(csv, f) + ": stamp_s is not finite");
  const double t = start.toSec() + f.stamp_s;
  if (!(t >= 1e-6 && t < 4294967295.0)) {
    std::ostringstream os;
    os << frameLabel(csv, f) << ": start time + stamp_s = " << std::fixed << std::setprecision(3) << t
       << " s is outside ROS time (0, 2^32) s; choose another start time";
    fail(os.str());
  }
  return start + ros::Duration(f.stamp_s);
}

// The gt.csv row of each frame index, checked against frames.csv.
std::map<int, const core::GroundTruthRecord*> groundTruthByIndex(const core::Dataset& d) {
  const std::string csv = (fs::path(d.directory) / "gt.csv").string();
  std::map<int, const core::FrameRecord*> frames;
  for (const auto& f : d.frames) frames[f.index] = &f;
  std::map<int, const core::GroundTruthRecord*> gt;
  for (const auto& g : d.ground_truth) {
    if (!gt.emplace(g.index, &g).second) fail(csv + ": duplicate index " + std::to_string(g.index));
    const auto it = frames.find(g.index);
    // A different image for the same index means the two files describe different frames.
    if (it != frames.end() && !g.image.empty() && g.image != it->second->image) {
      fail(csv + ": frame " + std::to_string(g.index) + " is '" + g.image + "' but '" + it->second->image +
           "' in frames.csv");
    }
    if (!std::isfinite(g.pose.x()) || !std::isfinite(g.pose.y()) || !std::isfinite(g.pose.yaw())) {
      fail(csv + ": frame " + std::to_string(g.index) + " has a non-finite pose");
    }
  }
  return gt;
}

// The image file as stored (grey stays grey, 16 bits 16 bits: core::decodeImageFile) and its
// encoding; throws naming the file when it is unreadable, of an unsupported type or of the wrong size.
cv::Mat readImage(const std::string& path, const core::CameraIntrinsics& camera, std::string* encoding) {
  std::string why;
  const cv::Mat image = core::decodeImageFile(path, &why);
  if (image.empty()) fail(why);
  switch (image.type()) {
    case CV_8UC1:
      *encoding = "mono8";
      break;
    case CV_8UC3:
      *encoding = "bgr8";
      break;
    case CV_16UC1:
      *encoding = "mono16";
      break;
    case CV_16UC3:
      *encoding = "bgr16";
      break;
    default:
      fail(path + ": unsupported image type (" + std::to_string(image.channels()) + " channels, OpenCV depth " +
           std::to_string(image.depth()) + ")");
  }
  if (image.cols != camera.width || image.rows != camera.height) {
    fail(path + ": image is " + std::to_string(image.cols) + "x" + std::to_string(image.rows) +
         " but camera.yaml says " + std::to_string(camera.width) + "x" + std::to_string(camera.height));
  }
  return image;
}

sensor_msgs::ImagePtr toImageMsg(const cv::Mat& image, const std::string& encoding, const std::string& wanted,
                                 const std_msgs::Header& header, const std::string& path) {
  const auto stored = boost::make_shared<cv_bridge::CvImage>(header, encoding, image);
  if (wanted.empty() || wanted == encoding) return stored->toImageMsg();
  try {
    return cv_bridge::cvtColor(stored, wanted)->toImageMsg();
  } catch (const cv_bridge::Exception& e) {
    fail(path + ": cannot convert " + encoding + " to " + wanted + " (" + e.what() + ")");
  }
}

// The image as compressed_image_transport would publish it: colour as BGR (8 bits for JPEG, the
// same depth for PNG) with the target in the format, grey as it is.
sensor_msgs::CompressedImage toCompressedMsg(const sensor_msgs::Image& image, const DatasetBagOptions& o,
                                             const std::string& path) {
  namespace enc = sensor_msgs::image_encodings;
  const bool jpeg = o.image_format == ImageFormat::kJpeg;
  const bool colour = enc::isColor(image.encoding);
  const int depth = enc::bitDepth(image.encoding);
  if (jpeg && !colour && depth != 8) {
    fail(path + ": a " + image.encoding + " image cannot be written as JPEG (8 bits): use png, or encoding mono8");
  }
  const std::string target = colour ? (jpeg || depth == 8 ? "bgr8" : "bgr16") : "";
  sensor_msgs::CompressedImage m;
  m.header = image.header;
  m.format = image.encoding + (jpeg ? "; jpeg compressed " : "; png compressed ") + target;
  const std::vector<int> params = jpeg ? std::vector<int>{cv::IMWRITE_JPEG_QUALITY, o.jpeg_quality}
                                       : std::vector<int>{cv::IMWRITE_PNG_COMPRESSION, 3};
  try {
    const cv::Mat pixels = cv_bridge::toCvCopy(image, target)->image;
    if (!cv::imencode(jpeg ? ".jpg" : ".png", pixels, m.data, params)) fail(path + ": cannot compress the image");
  } catch (const cv_bridge::Exception& e) {
    fail(path + ": cannot compress the image (" + e.what() + ")");
  } catch (const cv::Exception& e) {
    fail(path + ": cannot compress the image (" + e.err + ")");
  }
  return m;
}

sensor_msgs::Range toRangeMsg(const AltimeterModel& a, double altitude_m, const std_msgs::Header& header) {
  sensor_msgs::Range r;
  r.header = header;
  r.radiation_type = a.radiation_type;
  r.field_of_view = static_cast<float>(a.field_of_view_rad);
  r.min_range = static_cast<float>(a.min_range_m);
  r.max_range = static_cast<float>(a.max_range_m);
  r.range = static_cast<float>(altitude_m);
  return r;
}

bool altitudeInRange(const AltimeterModel& a, double altitude_m) {
  return std::isfinite(altitude_m) && altitude_m >= a.min_range_m && altitude_m <= a.max_range_m;
}

nav_msgs::Odometry toOdometryMsg(const core::Pose2& pose, const std_msgs::Header& header, const std::string& child) {
  nav_msgs::Odometry o;
  o.header = header;
  o.child_frame_id = child;
  o.pose.pose = ros_conversions::toPoseMsg(pose);
  // Ground truth: covariance zero, as the dataset gives none. The twist is not known: zero.
  o.pose.covariance.fill(0.0);
  o.twist.covariance.fill(0.0);
  return o;
}

}  // namespace

nav_msgs::Odometry toNavOdometryMsg(const core::NavRecord& nav, const ros::Time& stamp, const BagFrames& frames) {
  const double sxy = nav.sigma_xy_m * nav.sigma_xy_m, syaw = nav.sigma_yaw_rad * nav.sigma_yaw_rad;
  const core::UncertainPose2 camera(nav.pose, Eigen::Vector3d(sxy, sxy, syaw).asDiagonal());
  return ros_conversions::toOdometryMsg(core::vehicleFromCamera(camera, core::CameraMount()), nullptr, 0.0,
                                        frames.nav_odom, frames.nav_child, stamp);
}

bool fromNavOdometryMsg(const nav_msgs::Odometry& msg, core::NavRecord* nav) {
  // The default mount turns x, y and yaw by signs only: the diagonal is kept.
  return ros_conversions::navFromMsg(msg, core::CameraMount(), nav);
}

namespace {

// ------------------------------------------------------------------------------------------------
// The bag: written to "<path>.active", renamed to <path> by commit(), removed if never committed.

class PendingBag {
 public:
  PendingBag(const std::string& path, BagCompression compression) : path_(path), active_(path + ".active") {
    if (fs::is_directory(path_)) fail(path_ + ": cannot write bag (is a directory)");
    try {
      bag_.open(active_, rosbag::bagmode::Write);
    } catch (const rosbag::BagException& e) {
      fail(path_ + ": cannot write bag (" + e.what() + ")");
    }
    bag_.setCompression(compression == BagCompression::kBz2   ? rosbag::compression::BZ2
                        : compression == BagCompression::kLz4 ? rosbag::compression::LZ4
                                                              : rosbag::compression::Uncompressed);
  }
  PendingBag(const PendingBag&) = delete;
  PendingBag& operator=(const PendingBag&) = delete;
  ~PendingBag() {
    if (committed_) return;
    try {
      bag_.close();
    } catch (...) {  // already failing; the partial file goes anyway
    }
    std::error_code ec;
    fs::remove(active_, ec);
  }

  template <typename M>
  void write(const std::string& topic, const ros::Time& stamp, const M& msg) {
    try {
      bag_.write(topic, stamp, msg);
    } catch (const rosbag::BagException& e) {
      fail(path_ + ": writing " + topic + " failed (" + e.what() + ")");
    }
  }

  // Closes the bag and moves it into place; returns its size in bytes.
  std::uintmax_t commit() {
    try {
      bag_.close();
    } catch (const rosbag::BagException& e) {
      fail(path_ + ": closing the bag failed (" + e.what() + ")");
    }
    std::error_code ec;
    fs::rename(active_, path_, ec);
    if (ec) fail(path_ + ": cannot move " + active_ + " into place (" + ec.message() + ")");
    committed_ = true;
    return fs::file_size(path_, ec);
  }

 private:
  std::string path_;
  std::string active_;
  rosbag::Bag bag_;
  bool committed_ = false;
};

// ------------------------------------------------------------------------------------------------

struct FrameContext {
  const core::Dataset& dataset;
  const DatasetBagOptions& options;
  const std::map<int, const core::GroundTruthRecord*>& ground_truth;
  bool write_ground_truth;
};

void writeFrame(const FrameContext& c, const core::FrameRecord& f, const ros::Time& stamp, std::uint32_t seq,
                PendingBag* bag, DatasetBagStats* stats) {
  const DatasetBagOptions& o = c.options;
  std_msgs::Header header;
  header.seq = seq;
  header.stamp = stamp;

  const std::string path = c.dataset.imagePath(f);
  std::string encoding;
  const cv::Mat image = readImage(path, c.dataset.camera, &encoding);
  header.frame_id = o.frames.camera;
  const sensor_msgs::ImagePtr msg = toImageMsg(image, encoding, o.image_encoding, header, path);
  if (o.image_format == ImageFormat::kRaw) {
    bag->write(o.topics.image, stamp, *msg);
  } else {
    bag->write(o.imageTopic(), stamp, toCompressedMsg(*msg, o, path));
  }
  ++stats->images;

  sensor_msgs::CameraInfo info = toCameraInfoMsg(c.dataset.camera);
  info.header = header;
  bag->write(o.topics.camera_info, stamp, info);
  ++stats->camera_infos;

  if (altitudeInRange(o.altimeter, f.altitude_m)) {
    header.frame_id = o.frames.altimeter;
    bag->write(o.topics.altitude, stamp, toRangeMsg(o.altimeter, f.altitude_m, header));
    ++stats->altitudes;
  } else {
    stats->frames_without_altitude.push_back(f.index);
  }

  if (!c.write_ground_truth) return;
  const auto gt = c.ground_truth.find(f.index);
  if (gt == c.ground_truth.end()) {
    stats->frames_without_ground_truth.push_back(f.index);
    return;
  }
  header.frame_id = o.frames.ground_truth_origin;
  bag->write(o.topics.ground_truth, stamp, toOdometryMsg(gt->second->pose, header, o.frames.camera));
  ++stats->ground_truth_poses;
}

std::string listIndexes(const std::vector<int>& indexes) {
  constexpr std::size_t kShown = 10;
  std::ostringstream os;
  for (std::size_t i = 0; i < indexes.size() && i < kShown; ++i) os << (i ? ", " : "") << indexes[i];
  if (indexes.size() > kShown) os << ", ...";
  return os.str();
}

}  // namespace

std::string DatasetBagOptions::validate() const {
  std::string bad = checkTopics(topics);
  if (bad.empty()) bad = checkFrame(frames.camera, "camera");
  if (bad.empty()) bad = checkFrame(frames.altimeter, "altimeter");
  if (bad.empty()) bad = checkFrame(frames.ground_truth_origin, "ground-truth origin");
  if (bad.empty()) bad = checkFrame(frames.nav_odom, "nav odom");
  if (bad.empty()) bad = checkFrame(frames.nav_child, "nav child");
  if (bad.empty()) bad = checkAltimeter(altimeter);
  if (bad.empty() && !image_encoding.empty() &&
      std::find(kEncodings.begin(), kEncodings.end(), image_encoding) == kEncodings.end()) {
    bad = "image encoding '" + image_encoding + "' is not one of mono8, mono16, bgr8, rgb8, bgr16, rgb16";
  }
  if (bad.empty() && start_time.isZero()) bad = "start time is 0, which ROS treats as no time";
  if (bad.empty() && !(jpeg_quality >= 1 && jpeg_quality <= 100)) {
    bad = "JPEG quality " + std::to_string(jpeg_quality) + " is not in 1..100";
  }
  if (bad.empty() && image_format != ImageFormat::kRaw) {
    // The compressed topic must not be another of the bag's topics.
    for (const std::string* t : {&topics.camera_info, &topics.altitude, &topics.ground_truth, &topics.nav}) {
      if (ros::names::clean(*t) == ros::names::clean(imageTopic())) bad = "topic '" + *t + "' is used twice";
    }
  }
  return bad;
}

std::string DatasetBagOptions::imageTopic() const {
  return image_format == ImageFormat::kRaw ? topics.image : topics.image + "/compressed";
}

sensor_msgs::CameraInfo toCameraInfoMsg(const core::CameraIntrinsics& c) {
  sensor_msgs::CameraInfo m;
  m.width = static_cast<std::uint32_t>(c.width);
  m.height = static_cast<std::uint32_t>(c.height);
  m.distortion_model =
      c.distortion_model == core::DistortionModel::kRationalPolynomial ? "rational_polynomial" : "plumb_bob";
  m.D = c.distortion;
  m.D.resize(m.distortion_model == "plumb_bob" ? std::max<std::size_t>(m.D.size(), 5) : 8, 0.0);
  m.K = {c.fx, 0.0, c.cx, 0.0, c.fy, c.cy, 0.0, 0.0, 1.0};
  m.R = {1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0};
  m.P = {c.fx, 0.0, c.cx, 0.0, 0.0, c.fy, c.cy, 0.0, 0.0, 0.0, 1.0, 0.0};
  return m;
}

DatasetBagStats writeDatasetBag(const core::Dataset& dataset, const DatasetBagOptions& options,
                                const std::string& bag_path) {
  const std::string bad_option = options.validate();
  if (!bad_option.empty()) fail(bag_path + ": bad option: " + bad_option);
  const std::string frames_csv = (fs::path(dataset.directory) / "frames.csv").string();
  const std::string bad_camera = dataset.camera.validate();
  if (!bad_camera.empty()) fail((fs::path(dataset.directory) / "camera.yaml").string() + ": " + bad_camera);
  if (dataset.frames.empty()) fail(frames_csv + ": no frames");

  // Everything that can be checked without reading images is checked before the bag is opened.
  std::vector<ros::Time> stamps;
  stamps.reserve(dataset.frames.size());
  for (const auto& f : dataset.frames) stamps.push_back(frameStamp(options.start_time, f, frames_csv));
  const bool write_gt = options.include_ground_truth && !dataset.ground_truth.empty();
  const auto gt = write_gt ? groundTruthByIndex(dataset) : std::map<int, const core::GroundTruthRecord*>{};

  DatasetBagStats stats;
  stats.bag_path = bag_path;
  stats.first_stamp = *std::min_element(stamps.begin(), stamps.end());
  stats.last_stamp = *std::max_element(stamps.begin(), stamps.end());
  PendingBag bag(bag_path, options.compression);
  const FrameContext context{dataset, options, gt, write_gt};
  for (std::size_t i = 0; i < dataset.frames.size(); ++i) {
    if (i > 0 && stamps[i] <= stamps[i - 1]) stats.non_increasing_stamps.push_back(dataset.frames[i].index);
    writeFrame(context, dataset.frames[i], stamps[i], static_cast<std::uint32_t>(i), &bag, &stats);
    ++stats.frames;
  }
  if (options.include_nav) {
    for (const core::NavRecord& r : dataset.nav) {
      const ros::Time stamp = options.start_time + ros::Duration(r.stamp_s);
      bag.write(options.topics.nav, stamp, toNavOdometryMsg(r, stamp, options.frames));
      ++stats.nav_poses;
    }
  }
  stats.bag_bytes = bag.commit();
  return stats;
}

std::string summarize(const DatasetBagStats& s, const DatasetBagOptions& o) {
  std::ostringstream os;
  os << s.bag_path << ": " << s.frames << " frames; " << o.imageTopic() << " " << s.images << ", "
     << o.topics.camera_info << " " << s.camera_infos << ", " << o.topics.altitude << " " << s.altitudes;
  if (s.ground_truth_poses > 0) os << ", " << o.topics.ground_truth << " " << s.ground_truth_poses;
  if (s.nav_poses > 0) os << ", " << o.topics.nav << " " << s.nav_poses;
  os << std::fixed << std::setprecision(3) << "; stamps " << s.first_stamp.toSec() << " .. " << s.last_stamp.toSec()
     << " s; " << std::setprecision(1) << static_cast<double>(s.bag_bytes) / (1024.0 * 1024.0) << " MiB";
  return os.str();
}

std::vector<std::string> warnings(const DatasetBagStats& s) {
  std::vector<std::string> out;
  if (!s.frames_without_altitude.empty()) {
    out.push_back(std::to_string(s.frames_without_altitude.size()) +
                  " frame(s) with a non-finite or out-of-range altitude, Range not written (index " +
                  listIndexes(s.frames_without_altitude) + ")");
  }
  if (!s.frames_without_ground_truth.empty()) {
    out.push_back(std::to_string(s.frames_without_ground_truth.size()) +
                  " frame(s) without a gt.csv row, no ground truth written (index " +
                  listIndexes(s.frames_without_ground_truth) + ")");
  }
  if (!s.non_increasing_stamps.empty()) {
    out.push_back(std::to_string(s.non_increasing_stamps.size()) +
                  " frame(s) whose stamp is not after the previous frame's (index " +
                  listIndexes(s.non_increasing_stamps) + "); written as given, replayed in stamp order");
  }
  return out;
}

}  // namespace ros_bag
}  // namespace uw_multislam
