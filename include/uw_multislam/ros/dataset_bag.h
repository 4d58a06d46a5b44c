// Dataset folder -> ROS bag (rosbag C++ API). Used by the folder_to_bag tool and by the survey
// generator, so a dataset replays through the same nodelets as a recorded mission.
//
// Per frame of frames.csv, in file order, every message with the same header stamp
// start_time + stamp_s (the bag's receive time is that stamp too):
//
//   topic (default)        type                    content
//   /camera/image_raw      sensor_msgs/Image       the image file, lossless (bgr8 colour, mono8 grey)
//     or, with image_format jpeg / png, instead:
//   /camera/image_raw/compressed  sensor_msgs/CompressedImage  as compressed_image_transport
//                                 writes it (format "bgr8; jpeg compressed bgr8", "mono8; png compressed ")
//   /camera/camera_info    sensor_msgs/CameraInfo  plumb_bob, D = 0, K/P from camera.yaml
//   /altitude              sensor_msgs/Range       altitude_m, frame "altimeter"
//   /ground_truth/odom     nav_msgs/Odometry       gt.csv pose; only when gt.csv exists
//
// and, when the folder has nav.csv, one message per nav.csv row at start_time + its stamp_s:
//   /nav/odom              nav_msgs/Odometry       the dead-reckoned pose as the vehicle's navigation
//                                                  publishes it: base_link in "odom", z-up (REP-105),
//                                                  for the default mount (camera at base_link's origin,
//                                                  looking down, image columns along x); covariance
//                                                  diag(sigma_xy^2, sigma_xy^2, -, -, -, sigma_yaw^2)
//
// Errors are thrown as DatasetBagError with a one-line message that starts with the file at
// fault. On any error no bag is left at the output path: the bag is written to "<path>.active"
// and renamed when complete.
#pragma once

#include <nav_msgs/Odometry.h>
#include <ros/time.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Range.h>

#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/ros/topics.h"

namespace uw_multislam {
namespace ros_bag {

class DatasetBagError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// Default start time, seconds since the epoch (2023-11-14T22:13:20Z). Fixed, so that two
/// conversions of the same folder give identical bags, and far from 0, which ROS treats as
/// "no time".
constexpr std::uint32_t kDefaultStartTimeSec = 1700000000;

/// Topic names as stored in the bag (absolute; rosbag play publishes them as they are).
struct BagTopics {
  std::string image = topics::globalName(topics::kImage);                   // "/camera/image_raw"
  std::string camera_info = topics::globalName(topics::kCameraInfo);        // "/camera/camera_info"
  std::string altitude = topics::globalName(topics::kAltitude);             // "/altitude"
  std::string ground_truth = topics::globalName(topics::kGroundTruthOdom);  // "/ground_truth/odom"
  std::string nav = topics::globalName(topics::kNavOdom);                   // "/nav/odom"
};

/// Frame ids written into the headers (no leading '/', as tf2 requires).
struct BagFrames {
  std::string camera = frames::kCamera;                          // Image, CameraInfo; odometry child
  std::string altimeter = frames::kAltimeter;                    // Range
  std::string ground_truth_origin = frames::kGroundTruthOrigin;  // Odometry header
  std::string nav_odom = "odom";                                 // the nav's Odometry header...
  std::string nav_child = "base_link";                           // ...and child
};

/// What the Range messages say about the altimeter. Underwater altimeters (and DVLs) are
/// acoustic, hence ULTRASOUND; a single-beam altimeter has a beam of a few degrees.
struct AltimeterModel {
  std::uint8_t radiation_type = sensor_msgs::Range::ULTRASOUND;
  double field_of_view_rad = 10.0 * M_PI / 180.0;  // full cone angle
  double min_range_m = 0.1;                        // altitudes outside [min, max] are not written (DatasetBagStats)
  double max_range_m = 100.0;
};

enum class BagCompression { kNone, kBz2, kLz4 };

/// How images are written: sensor_msgs/Image (raw), or sensor_msgs/CompressedImage on
/// "<image topic>/compressed" (what compressed_image_transport publishes and records).
enum class ImageFormat { kRaw, kJpeg, kPng };

struct DatasetBagOptions {
  BagTopics topics;
  BagFrames frames;
  AltimeterModel altimeter;
  /// Stamp of a frame = start_time + its stamp_s.
  ros::Time start_time{kDefaultStartTimeSec, 0};
  /// Write /ground_truth/odom when the folder has gt.csv.
  bool include_ground_truth = true;
  /// Write /nav/odom when the folder has nav.csv.
  bool include_nav = true;
  /// Empty: as stored (8-bit colour -> bgr8, 8-bit grey -> mono8, 16-bit -> bgr16/mono16).
  /// Otherwise every image is converted to this encoding: mono8, mono16, bgr8, rgb8, bgr16, rgb16.
  std::string image_encoding;
  BagCompression compression = BagCompression::kNone;
  /// kJpeg, kPng: CompressedImage on "<topics.image>/compressed" instead of Image on topics.image,
  /// after the encoding conversion above. As compressed_image_transport does: colour compressed as
  /// BGR (JPEG: 8 bits), grey as it is (16-bit grey only as PNG: JPEG is 8 bits).
  ImageFormat image_format = ImageFormat::kRaw;
  /// JPEG quality, 1..100 (compressed_image_transport's default: 80).
  int jpeg_quality = 80;

  /// The topic the images go to: topics.image, or topics.image + "/compressed".
  std::string imageTopic() const;
  /// Empty when usable, else a sentence naming the bad option.
  std::string validate() const;
};

/// What was written. Frame lists hold frames.csv indexes.
struct DatasetBagStats {
  std::string bag_path;
  std::size_t frames = 0;  // every frame gives one Image and one CameraInfo
  std::size_t images = 0;
  std::size_t camera_infos = 0;
  std::size_t altitudes = 0;
  std::size_t ground_truth_poses = 0;
  std::size_t nav_poses = 0;
  /// Frames whose altitude is non-finite or outside the altimeter's [min, max] range: their Range
  /// is not written (a consumer must ignore such a reading anyway, sensor_msgs/Range); the image
  /// and camera info still are.
  std::vector<int> frames_without_altitude;
  /// Frames with no gt.csv row (only counted when ground truth is written).
  std::vector<int> frames_without_ground_truth;
  /// Frames whose stamp is not after the previous frame's. They are written as they are, in
  /// frames.csv order; rosbag play will then replay them sorted by stamp.
  std::vector<int> non_increasing_stamps;
  ros::Time first_stamp;  // earliest and latest stamp written
  ros::Time last_stamp;
  std::uintmax_t bag_bytes = 0;

  std::size_t messages() const { return images + camera_infos + altitudes + ground_truth_poses + nav_poses; }
};

/// Writes the dataset's frames to a new bag at bag_path (replacing any file there).
/// Throws DatasetBagError for bad options, an unreadable image or one whose size differs from
/// camera.yaml, a non-finite stamp, an inconsistent gt.csv, or a bag that cannot be written.
DatasetBagStats writeDatasetBag(const core::Dataset& dataset, const DatasetBagOptions& options,
                                const std::string& bag_path);

/// One line: frames, messages per topic, bag size, stamp range.
std::string summarize(const DatasetBagStats& stats, const DatasetBagOptions& options);
/// One sentence per anomaly counted in stats (skipped altitudes, non-increasing stamps, ...).
std::vector<std::string> warnings(const DatasetBagStats& stats);

/// CameraInfo of a dataset's camera: its distortion (plumb_bob with zeros for a pinhole), R = I,
/// P = [K | 0].
sensor_msgs::CameraInfo toCameraInfoMsg(const core::CameraIntrinsics& camera);

/// A nav.csv row as the vehicle's navigation publishes it (see /nav/odom above), and back
/// (false for a message that is not finite or whose covariance is not usable).
nav_msgs::Odometry toNavOdometryMsg(const core::NavRecord& nav, const ros::Time& stamp, const BagFrames& frames);
bool fromNavOdometryMsg(const nav_msgs::Odometry& msg, core::NavRecord* nav);

}  // namespace ros_bag
}  // namespace uw_multislam
