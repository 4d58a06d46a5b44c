// A recorded mission's bag read as one camera stream for the offline runner (offline_slam --bag), with
// the rosbag C++ API (no master, no playback, no clock): the inputs the live odometry subscribes to,
// taken from the bag and checked as the live checks them (ros/image_input.h, ros/nav_input.h,
// ros/camera_mount.h, ros/sensor_conversions.h):
//
//   images       sensor_msgs/Image on the image topic, or sensor_msgs/CompressedImage on
//                <image topic>/compressed when the bag has no raw images there (decoded as the
//                odometry's built-in decoder does); one frame per image, in the bag's order, its
//                index the image's position (0, 1, ...), its stamp the header's
//   camera_info  sensor_msgs/CameraInfo: the stream's camera (one per stream: a bag whose
//                calibration changes is refused); without any, a calibration file (camera_info_url)
//   altitude     sensor_msgs/Range: core::AltitudeBuffer at each image stamp (exact, interpolated,
//                or the nearest within altitude_max_age_s), plus the camera's height above the
//                altimeter; an image without a reading that close is skipped and counted, as live.
//                Or a DVL driver's own message (dvl_topic, any type): the number at dvl_field
//                (ros/message_field.h), <= 0 (no bottom lock) refused like a bad range, stamped
//                and placed by its header (or dvl_frame), as the launch files' dvl relay does
//   nav          nav_msgs/Odometry (optional): navToEnu's frame checks, navFromMsg, the covariance
//                check and the track's order checks, the rows then moved to the mounted camera
//   /tf_static   the sensor mounts: base_frame -> the images' frame_id and -> the Ranges' frame_id,
//                looked up in a tf2::BufferCore filled with the bag's static transforms, unless the
//                mount is given (camera_mount: "X Y Z YAW" as the launch files' camera_mount)
//
// Relative topic names resolve in `ns` ("/": the bag's root), so a bag recorded as
// /uw_multislam/camera/image_raw is read with ns /uw_multislam. Every problem is a BagInputError whose
// one line starts with the bag's path and names the missing topic or frame and the option that gives it.
#pragma once

#include <opencv2/core.hpp>

#include <array>
#include <cstddef>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>

#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/geometry/vehicle_frame.h"
#include "uw_multislam/ros/topics.h"

namespace uw_multislam {
namespace ros_bag {

class BagInputError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct BagInputOptions {
  std::string ns = "/";  // relative topic names resolve in it
  std::string image = topics::kImage;
  std::string camera_info = topics::kCameraInfo;
  std::string altitude = topics::kAltitude;
  std::string nav = topics::kNavOdom;
  std::string dvl_topic;               // set: the altitude from this topic's messages instead of `altitude`
  std::string dvl_field = "altitude";  // the field path in them (a leading "m." as the relay's is allowed)
  std::string dvl_frame = "header";    // their frame_id: "header" (the message's own) or a frame
  std::string tf_static = "/tf_static";
  std::string camera_info_url;  // used when the bag has no camera_info (file:///..., package://..., /abs/path)
  std::string base_frame = frames::kDefaultBaseFrame, odom_frame = frames::kDefaultOdomFrame;
  std::optional<std::array<double, 4>> camera_mount;     // X Y Z YAW in base_frame: instead of /tf_static
  std::optional<std::array<double, 3>> altimeter_mount;  // X Y Z (with camera_mount); unset: at the camera
  double max_tilt_deg = 5.0;                             // frames/max_camera_tilt_deg
  double max_altitude_m = 200.0;                         // slam/odometry/max_altitude_m
  double altitude_max_age_s = 1.0;                       // ~altitude_max_age_s
  double nav_drift = 0.01, nav_yaw_drift = 0.001;        // the drift model replacing a covariance that never grows
  bool read_nav = true;                                  // false: the nav topic is not read
};

/// What was read and what was skipped.
struct BagInputCounts {
  long images = 0, frames = 0;                // images in the bag, frames kept
  long skipped_no_altitude = 0;               // no Range within altitude_max_age_s of the image
  long altitudes = 0, altitudes_refused = 0;  // Ranges, those refused (NaN: not finite, out of range)
  long nav_readings = 0, nav_refused = 0, nav_covariance_replaced = 0;
  long camera_infos = 0;
};

class BagStream {
 public:
  /// Opens and indexes the bag (every message but the images' pixels is read here); `path` may name
  /// several bags of one dive separated by commas ("dive_0.bag,dive_1.bag", rosbag record --split):
  /// their messages are read as one recording, in time order. Throws BagInputError.
  BagStream(const std::string& path, const BagInputOptions& options);
  ~BagStream();
  BagStream(const BagStream&) = delete;
  BagStream& operator=(const BagStream&) = delete;

  /// The stream as a dataset: directory the bag's path, camera, frames (index, stamp, the camera's
  /// altitude; no image file), nav (the mounted camera's poses, core conventions).
  const core::Dataset& dataset() const;
  /// The image of frame `i` (its position in dataset().frames) as the odometry takes it; empty with
  /// `why` for one that cannot be used (a truncated message, a refused encoding). Thread-safe.
  cv::Mat image(std::size_t i, std::string* why = nullptr) const;
  /// Seconds of recording between the first and the last frame.
  double recordedS() const;
  const BagInputCounts& counts() const;
  /// One line: the topics read, counts, the camera, where the mount came from.
  std::string summary() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// "X Y Z YAW" (or "X Y Z" when n is 3) into `out`; false for another count or a non-finite or
/// |value| >= 1000 number (mount_publisher.py's bounds).
bool parseMount(const std::string& text, std::size_t n, double* out);

}  // namespace ros_bag
}  // namespace uw_multislam
