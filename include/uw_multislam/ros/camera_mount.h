// Where the camera and the altimeter sit on the vehicle (doc/frames.md): tf's base_link -> the
// frame_id the sensors write into their headers (the vehicle's URDF through robot_state_publisher,
// a bag's /tf_static, or the launch files' camera_mount argument: scripts/mount_publisher.py).
// There is no default mount. Both nodelets use it: the odometry (SensorMount) adds the camera's
// height above the altimeter to each altitude and publishes the vehicle's pose, and refuses to
// track without it; the back-end (ros/frame_publisher.h) publishes every pose as the vehicle's
// (core/geometry/vehicle_frame.h). Tested in test/ros/test_conversions.cpp and rostest
// sensor_frames.
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
  std::string base_frame = "base_link";
  double wait_s = 2.0;        // the odometry's first frame waits this long for the mount in tf
  double max_tilt_deg = 5.0;  // optical axis from straight down
};

/// frames/{base_frame, mount_wait_s, max_camera_tilt_deg} of `nh` (the pipeline's namespace);
/// std::invalid_argument naming the key for a bad value. The former mount parameters
/// (frames/camera_position, camera_yaw, altimeter_position, publish_mount_tf, camera_frame,
/// altimeter_frame) are not read any more: a WARN names those that are set.
MountOptions mountOptions(const ros::NodeHandle& nh);

/// The mount from tf's two transforms. False, with `why`, for a non-finite transform or a camera
/// whose optical axis is more than max_tilt_rad from base_link's -z (the 2-D model needs a
/// bottom-looking camera on a level vehicle).
bool mountFromTransforms(const geometry_msgs::Transform& base_from_camera_optical,
                         const geometry_msgs::Transform& base_from_altimeter, double max_tilt_rad,
                         core::CameraMount* out, std::string* why);

/// The mount of the sensors that named their frames: base_frame -> the camera's frame (an image's
/// header.frame_id) and base_frame -> the altimeter's (a Range's header.frame_id), looked up in
/// tf (the vehicle's URDF through robot_state_publisher, or scripts/mount_publisher.py) and kept
/// once found (they are static). No default: without them the caller refuses the frame. The
/// first lookup waits up to wait_s (wall time: simulated time may not run yet) for them; later
/// ones do not wait, so a refused frame costs nothing. Once found, tf is read again at most once a
/// second (no wait): a mount that moved (a second static publisher, a changed URDF) is taken and
/// reported (Lookup::changed); one that vanished keeps the last found. Not thread-safe (the
/// odometry's worker).
class SensorMount {
 public:
  SensorMount(ros::NodeHandle nh, const std::string& base_frame, double wait_s, double max_tilt_rad);

  enum class State { kResolved, kMissing, kRefused };
  struct Lookup {
    State state = State::kMissing;
    core::CameraMount mount;  // when kResolved
    std::string message;      // kMissing / kRefused: what is missing or wrong; kResolved: where it came from
    bool fresh = false;       // kResolved for these frames for the first time (log it)
    bool changed = false;     // kResolved, and the mount moved since it was found (message: from what to what)
  };
  /// The mount for these frames (`altimeter_frame` empty: no altimeter, the altitude is the camera's).
  Lookup get(const std::string& camera_frame, const std::string& altimeter_frame);

 private:
  // The mount of `frames` in tf now (no wait): kResolved, or why not.
  Lookup lookup(const std::string& camera_frame, const std::string& altimeter_frame);

  std::string base_frame_;
  double wait_s_, max_tilt_rad_;
  double next_check_s_ = 0.0;         // wall time: the resolved mount is looked up again from then
  std::optional<double> deadline_s_;  // wall time: the first lookup's wait ends then
  std::unique_ptr<tf2_ros::Buffer> buffer_;
  std::unique_ptr<tf2_ros::TransformListener> listener_;
  std::optional<std::pair<std::string, std::string>> resolved_for_;
  core::CameraMount resolved_;
};

}  // namespace ros_frames
}  // namespace uw_multislam
