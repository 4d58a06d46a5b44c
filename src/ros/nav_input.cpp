#include "uw_multislam/ros/nav_input.h"

#include <algorithm>
#include <chrono>
#include <cstdio>

#include "uw_multislam/ros/conversions.h"
#include "uw_multislam/ros/sensor_conversions.h"

namespace uw_multislam {
namespace ros_inputs {

namespace rc = ros_conversions;

core::NavRecord TfNavDrift::add(double stamp_s, const core::Pose2& vehicle, const core::CameraMount& mount) {
  if (last_) distance_m_ += (vehicle.translation() - last_->translation()).norm();
  last_ = vehicle;
  core::NavRecord r;
  r.stamp_s = stamp_s;
  r.pose = core::cameraFromVehicle(vehicle, mount);
  r.sigma_xy_m = xy_per_m_ * distance_m_;
  r.sigma_yaw_rad = yaw_per_m_ * distance_m_;
  return r;
}

NavInput::NavInput(ros::NodeHandle nh, const std::string& topic, const NavInputOptions& options)
    : options_(options), drift_(options.tf_drift, options.tf_yaw_drift) {
  if (options_.source == "tf") {
    tf_buffer_ = std::make_unique<tf2_ros::Buffer>(ros::Duration(std::max(10.0, options_.buffer_s)));
    tf_listener_ = std::make_unique<tf2_ros::TransformListener>(*tf_buffer_, nh);
  } else if (options_.source == "topic") {
    sub_ = nh.subscribe(topic, 100, &NavInput::onNav, this);
  }
}

std::string NavInput::description(bool used) const {
  char line[512];
  if (tf_buffer_)
    std::snprintf(
        line, sizeof(line),
        "nav prior from tf %s -> %s at each image stamp (waiting up to %.2f s), sigma %.3f x and %.4f rad/m x "
        "the distance travelled",
        options_.odom_frame.c_str(), options_.base_frame.c_str(), options_.tf_wait_s, options_.tf_drift,
        options_.tf_yaw_drift);
  else
    std::snprintf(line, sizeof(line),
                  "nav prior from %s (nav_msgs/Odometry, %s), readings kept %.0f s; frames without one go as without "
                  "nav",
                  sub_.getTopic().c_str(), used ? "used" : "slam/odometry/nav/enabled false: ignored",
                  options_.buffer_s);
  return line;
}

std::optional<core::NavRecord> NavInput::at(const ros::Time& stamp, const core::CameraMount& mount) {
  if (tf_buffer_) return fromTf(stamp, mount);
  std::optional<core::NavRecord> r = fromTopic(stamp.toSec());
  // The track holds a camera at base_link: back to base_link, then to the mounted camera.
  if (r) r->pose = core::cameraFromVehicle(core::vehicleFromCamera(r->pose, core::CameraMount()), mount);
  return r;
}

void NavInput::onNav(const nav_msgs::OdometryConstPtr& msg) {
  ++received_;
  core::NavRecord r;
  std::string why;
  bool ok = rc::navFromMsg(*msg, core::CameraMount(), &r, &why);
  if (ok) {
    std::lock_guard<std::mutex> lock(mutex_);
    // Further back than a late reading may be: a new clock (a bag played again), the track restarts.
    ok = track_.append(r, &why, std::max(options_.reorder_tolerance_s, 1e-6));
    if (ok && !why.empty()) ROS_WARN("odometry: nav reading at %.3f: %s", r.stamp_s, why.c_str());
    if (ok && track_.rows().size() > 64) track_.dropBefore(r.stamp_s - options_.buffer_s);
    if (ok) last_appended_ = ros::WallTime::now();
  }
  if (ok) appended_.notify_all();
  if (!ok) {
    ++refused_;
    ROS_WARN_THROTTLE(5, "odometry: nav reading skipped: %s (%ld so far)", why.c_str(), refused_.load());
  }
}

std::optional<core::NavRecord> NavInput::fromTopic(double stamp_s) {
  std::unique_lock<std::mutex> lock(mutex_);
  core::NavRecord r;
  // The frame is newer than the newest reading while readings keep coming: its own is on the way
  // (another connection than the image's), wait for it up to wait_s.
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(options_.wait_s);
  auto waiting = [&] {
    return !track_.empty() && track_.rows().back().stamp_s < stamp_s && !last_appended_.isZero() &&
           (ros::WallTime::now() - last_appended_).toSec() < 1.0;
  };
  while (waiting() && appended_.wait_until(lock, deadline) != std::cv_status::timeout) {
  }
  if (!track_.at(stamp_s, &r)) return std::nullopt;
  return r;
}

std::optional<core::NavRecord> NavInput::fromTf(const ros::Time& stamp, const core::CameraMount& mount) {
  geometry_msgs::TransformStamped t;
  try {
    t = tf_buffer_->lookupTransform(options_.odom_frame, options_.base_frame, stamp, ros::Duration(options_.tf_wait_s));
  } catch (const tf2::TransformException& e) {
    ++tf_missing_;
    ROS_WARN_THROTTLE(5, "odometry: no nav for the frame at %.3f: %s (%ld frames so far)", stamp.toSec(), e.what(),
                      tf_missing_.load());
    return std::nullopt;
  }
  core::Pose2 vehicle;
  if (!rc::fromMsg(t.transform, &vehicle)) {  // not finite, or a zero quaternion
    ++tf_missing_;
    return std::nullopt;
  }
  return drift_.add(stamp.toSec(), vehicle, mount);
}

}  // namespace ros_inputs
}  // namespace uw_multislam
