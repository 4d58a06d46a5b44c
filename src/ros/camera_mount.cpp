#include "uw_multislam/ros/camera_mount.h"

#include <tf2/LinearMath/Matrix3x3.h>
#include <tf2/LinearMath/Quaternion.h>
#include <tf2/LinearMath/Transform.h>
#include <tf2_geometry_msgs/tf2_geometry_msgs.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_listener.h>

#include <cmath>
#include <sstream>
#include <stdexcept>

#include "uw_multislam/ros/slam_params.h"

namespace uw_multislam {
namespace ros_frames {

namespace {
tf2::Transform toTf(const geometry_msgs::Transform& m) {
  tf2::Transform t;
  tf2::fromMsg(m, t);
  return t;
}

bool finiteMsg(const geometry_msgs::Transform& m) {
  const auto& q = m.rotation;
  const double n = std::sqrt(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w);
  return std::isfinite(m.translation.x) && std::isfinite(m.translation.y) && std::isfinite(m.translation.z) &&
         std::isfinite(n) && n > 1e-9;
}
}  // namespace

MountOptions mountOptions(const ros::NodeHandle& nh) {
  using ros_params::param;
  auto nonempty = [](const std::string& s) { return !s.empty(); };
  MountOptions o;
  o.base_frame = param(nh, "frames/base_frame", o.base_frame, nonempty, "a frame id");
  o.wait_s = param(
      nh, "frames/mount_wait_s", 2.0, [](double v) { return v >= 0 && v <= 60; }, "in [0, 60] s");
  o.max_tilt_deg = param(
      nh, "frames/max_camera_tilt_deg", 5.0, [](double v) { return v >= 0 && v <= 45; }, "in [0, 45] degrees");
  std::string former;
  for (const char* key :
       {"camera_position", "camera_yaw", "altimeter_position", "publish_mount_tf", "camera_frame", "altimeter_frame"})
    if (nh.hasParam(std::string("frames/") + key)) former += std::string(former.empty() ? "" : ", ") + key;
  if (!former.empty())
    ROS_WARN_ONCE(
        "%s: %s not read any more: the sensors' mount comes from tf, base_link -> the frame_id of the images and "
        "of the altitude readings (the vehicle's URDF, or the launch files' camera_mount / altimeter_mount arguments)",
        nh.resolveName("frames").c_str(), former.c_str());
  return o;
}

bool mountFromTransforms(const geometry_msgs::Transform& base_from_camera_optical,
                         const geometry_msgs::Transform& base_from_altimeter, double max_tilt_rad,
                         core::CameraMount* out, std::string* why) {
  if (!finiteMsg(base_from_camera_optical) || !finiteMsg(base_from_altimeter)) {
    *why = "a mount transform is not finite (or has a zero quaternion)";
    return false;
  }
  tf2::Transform cam = toTf(base_from_camera_optical);
  cam.setRotation(cam.getRotation().normalized());
  const tf2::Matrix3x3 level = cam.getBasis() * tf2::Matrix3x3(tf2::Quaternion(tf2::Vector3(1, 0, 0), M_PI));
  const tf2::Vector3 up = level.getColumn(2);  // the level frame's z in base_link
  const double tilt = std::acos(std::max(-1.0, std::min(1.0, up.z())));
  if (tilt > max_tilt_rad) {
    std::ostringstream os;
    os << "the camera's optical axis is " << tilt * 180.0 / M_PI << " deg from straight down (at most "
       << max_tilt_rad * 180.0 / M_PI << " deg: the 2-D model needs a bottom-looking camera)";
    *why = os.str();
    return false;
  }
  const tf2::Vector3 x = level.getColumn(0);
  out->base_from_camera = core::Pose2(cam.getOrigin().x(), cam.getOrigin().y(), std::atan2(x.y(), x.x()));
  out->camera_above_altimeter_m = cam.getOrigin().z() - base_from_altimeter.translation.z;
  return true;
}

SensorMount::SensorMount(ros::NodeHandle nh, const std::string& base_frame, double wait_s, double max_tilt_rad)
    : base_frame_(base_frame),
      wait_s_(wait_s),
      max_tilt_rad_(max_tilt_rad),
      buffer_(std::make_unique<tf2_ros::Buffer>()),
      listener_(std::make_unique<tf2_ros::TransformListener>(*buffer_, nh, true)) {}

SensorMount::Lookup SensorMount::get(const std::string& camera_frame, const std::string& altimeter_frame) {
  const auto frames = std::make_pair(camera_frame, altimeter_frame);
  const double now = ros::WallTime::now().toSec();
  if (resolved_for_ && *resolved_for_ == frames) {
    Lookup l;
    l.state = State::kResolved;
    l.mount = resolved_;
    if (now < next_check_s_) return l;
    next_check_s_ = now + 1.0;
    const Lookup again = lookup(camera_frame, altimeter_frame);
    constexpr double kSame = 1e-6;  // m and rad: the same transform published again
    const core::Pose2 moved = core::between(resolved_.base_from_camera, again.mount.base_from_camera);
    if (again.state != State::kResolved ||
        (moved.translation().norm() <= kSame && std::abs(moved.yaw()) <= kSame &&
         std::abs(again.mount.camera_above_altimeter_m - resolved_.camera_above_altimeter_m) <= kSame))
      return l;
    l.changed = true;
    l.message = "moved in tf: " + core::describe(resolved_) + " before, " + again.message + " now";
    l.mount = resolved_ = again.mount;
    return l;
  }
  if (camera_frame.empty()) {
    Lookup l;
    l.message = "the image has no header.frame_id: the camera cannot be placed on " + base_frame_ +
                " (set the camera driver's frame_id)";
    return l;
  }
  auto have = [&](const std::string& f) { return f.empty() || buffer_->canTransform(base_frame_, f, ros::Time(0)); };
  // A poll of an awaited condition, bounded by wall time (simulated time may not run yet).
  if (!deadline_s_) deadline_s_ = now + wait_s_;
  while (!(have(camera_frame) && have(altimeter_frame)) && ros::WallTime::now().toSec() < *deadline_s_ && ros::ok())
    ros::WallDuration(0.01).sleep();
  Lookup l = lookup(camera_frame, altimeter_frame);
  if (l.state == State::kMissing)
    l.message = "no transform " + l.message + " in tf after " + std::to_string(wait_s_).substr(0, 4) +
                " s: publish the sensors' mount (the vehicle's URDF with robot_state_publisher, or the launch "
                "files' camera_mount / altimeter_mount arguments)";
  if (l.state != State::kResolved) return l;
  l.fresh = true;
  l.message = "from tf, " + l.message;
  resolved_for_ = frames;
  resolved_ = l.mount;
  next_check_s_ = now + 1.0;
  return l;
}

SensorMount::Lookup SensorMount::lookup(const std::string& camera_frame, const std::string& altimeter_frame) {
  Lookup l;
  const bool altimeter = !altimeter_frame.empty();
  std::string missing;
  for (const std::string& f : {camera_frame, altimeter_frame}) {
    if (f.empty()) continue;
    std::string error;
    if (!buffer_->canTransform(base_frame_, f, ros::Time(0), &error))
      missing += (missing.empty() ? "" : "; ") + base_frame_ + " -> " + f + " (" + error + ")";
  }
  if (!missing.empty()) {
    l.message = missing;
    return l;
  }
  geometry_msgs::TransformStamped cam, alt;
  try {
    cam = buffer_->lookupTransform(base_frame_, camera_frame, ros::Time(0));
    if (altimeter) alt = buffer_->lookupTransform(base_frame_, altimeter_frame, ros::Time(0));
  } catch (const tf2::TransformException& e) {
    l.message = e.what();
    return l;
  }
  if (!altimeter) {
    alt.transform.translation = cam.transform.translation;  // the altitude is the camera's
    alt.transform.rotation.w = 1.0;
  }
  std::string why;
  if (!mountFromTransforms(cam.transform, alt.transform, max_tilt_rad_, &l.mount, &why)) {
    l.state = State::kRefused;
    l.message = base_frame_ + " -> " + camera_frame + ": " + why;
    return l;
  }
  l.state = State::kResolved;
  l.message = base_frame_ + " -> " + camera_frame +
              (altimeter ? " and " + base_frame_ + " -> " + altimeter_frame : std::string(" (no altimeter)")) + ": " +
              core::describe(l.mount);
  return l;
}

}  // namespace ros_frames
}  // namespace uw_multislam
