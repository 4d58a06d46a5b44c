// Where the camera and the altimeter sit on the vehicle (README "Frames"): the frames/ block's
// camera_* / altimeter_* parameters, published by backend_node as static tf (the default: a
// camera at base_link looking straight down), or, with frames/publish_mount_tf false, the
// vehicle's own tf (URDF, robot_state_publisher) read once at start-up. Both nodelets use the
// mount: the odometry adds the camera's height above the altimeter to each altitude and
// publishes the vehicle's pose, the back-end publishes every pose as the vehicle's
// (core/geometry/vehicle_frame.h). Tested in test/ros/test_conversions.cpp.
#pragma once

#include <geometry_msgs/Transform.h>
#include <geometry_msgs/TransformStamped.h>
#include <ros/node_handle.h>

#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_listener.h>

#include <array>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "uw_multislam/core/geometry/vehicle_frame.h"

namespace uw_multislam {
namespace ros_frames {

struct MountOptions {
  std::string base_frame = "base_link", camera_frame = "camera_optical", altimeter_frame = "altimeter";
  bool publish_tf = true;                      // from the values below; false: read from the vehicle's tf
  std::array<double, 3> camera_position{};     // optical centre in base_link, m
  double camera_yaw = 0.0;                     // image columns from base_link's x, rad (looking straight down)
  std::array<double, 3> altimeter_position{};  // in base_link, m
  double wait_s = 2.0;                         // for the vehicle's tf at start-up
  double max_tilt_deg = 5.0;                   // optical axis from straight down
};

/// frames/{base_frame, camera_frame, altimeter_frame, publish_mount_tf, camera_position,
/// camera_yaw, altimeter_position, mount_wait_s, max_camera_tilt_deg} of `nh` (the pipeline's
/// namespace); std::invalid_argument naming the key for a bad value.
MountOptions mountOptions(const ros::NodeHandle& nh);

/// base_link -> camera optical frame (z down, x along the image columns) and base_link ->
/// altimeter, as the options place them.
std::vector<geometry_msgs::TransformStamped> mountTransforms(const MountOptions& o, const ros::Time& stamp);

/// The mount from tf's two transforms. False, with `why`, for a non-finite transform or a camera
/// whose optical axis is more than max_tilt_rad from base_link's -z (the 2-D model needs a
/// bottom-looking camera on a level vehicle).
bool mountFromTransforms(const geometry_msgs::Transform& base_from_camera_optical,
                         const geometry_msgs::Transform& base_from_altimeter, double max_tilt_rad,
                         core::CameraMount* out, std::string* why);

/// The mount the options give: their values, or with publish_tf false tf's (waiting up to
/// wait_s for the static transforms). False when tf had none in time: then `out` is the default
/// mount (the caller WARNs). `note` says where the mount came from. std::invalid_argument for a
/// tilted camera.
bool resolveCameraMount(const ros::NodeHandle& nh, const MountOptions& o, core::CameraMount* out, std::string* note);

/// The mount of the sensors that named their frames: base_frame -> the camera's frame (an image's
/// header.frame_id) and base_frame -> the altimeter's (a Range's header.frame_id), looked up in
/// tf (the vehicle's URDF through robot_state_publisher, or scripts/mount_publisher.py) and kept
/// once found (they are static). No default: without them the caller refuses the frame. The
/// first lookup waits up to wait_s (wall time: simulated time may not run yet) for them; later
/// ones do not wait, so a refused frame costs nothing. Not thread-safe (the odometry's worker).
class SensorMount {
 public:
  SensorMount(ros::NodeHandle nh, const std::string& base_frame, double wait_s, double max_tilt_rad);

  enum class State { kResolved, kMissing, kRefused };
  struct Lookup {
    State state = State::kMissing;
    core::CameraMount mount;  // when kResolved
    std::string message;      // kMissing / kRefused: what is missing or wrong; kResolved: where it came from
    bool fresh = false;       // kResolved for these frames for the first time (log it)
  };
  /// The mount for these frames (`altimeter_frame` empty: no altimeter, the altitude is the camera's).
  Lookup get(const std::string& camera_frame, const std::string& altimeter_frame);

 private:
  std::string base_frame_;
  double wait_s_, max_tilt_rad_;
  std::optional<double> deadline_s_;  // wall time: the first lookup's wait ends then
  std::unique_ptr<tf2_ros::Buffer> buffer_;
  std::unique_ptr<tf2_ros::TransformListener> listener_;
  std::optional<std::pair<std::string, std::string>> resolved_for_;
  core::CameraMount resolved_;
};

}  // namespace ros_frames
}  // namespace uw_multislam
