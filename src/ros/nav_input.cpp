#include "uw_multislam/ros/nav_input.h"

#include <tf2/LinearMath/Matrix3x3.h>
#include <tf2/LinearMath/Quaternion.h>
#include <tf2/LinearMath/Transform.h>
#include <tf2_geometry_msgs/tf2_geometry_msgs.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>

#include "uw_multislam/ros/conversions.h"
#include "uw_multislam/ros/sensor_conversions.h"

namespace uw_multislam {
namespace ros_inputs {

namespace rc = ros_conversions;

core::NavRecord TfNavDrift::add(double stamp_s, const core::Pose2& vehicle, const core::CameraMount& mount) {
  model_.advance(vehicle.translation());
  core::NavRecord r;
  r.stamp_s = stamp_s;
  r.pose = core::cameraFromVehicle(vehicle, mount);
  r.sigma_xy_m = model_.sigmaXy();
  r.sigma_yaw_rad = model_.sigmaYaw();
  return r;
}

bool navToEnu(const nav_msgs::Odometry& in, const std::string& odom_frame, const std::string& base_frame,
              nav_msgs::Odometry* out, std::string* why) {
  const std::string ned = odom_frame + "_ned", frd = base_frame + "_frd";
  const bool parent_ned = in.header.frame_id == ned, child_frd = in.child_frame_id == frd;
  if (in.header.frame_id != odom_frame && !parent_ned) {
    if (why)
      *why = "nav odometry: header.frame_id '" + in.header.frame_id + "', expected " + odom_frame + " (ENU) or " + ned +
             " (NED)";
    return false;
  }
  if (in.child_frame_id != base_frame && !child_frd) {
    if (why) *why = "nav odometry: child_frame_id '" + in.child_frame_id + "', expected " + base_frame + " or " + frd;
    return false;
  }
  *out = in;
  out->header.frame_id = odom_frame;
  out->child_frame_id = base_frame;
  if (!parent_ned && !child_frd) return true;
  // REP-103: ENU <- NED is a half turn about (1, 1, 0)/sqrt(2) (x <-> y, z flipped); the FRD body
  // is the FLU body turned by a half turn about x. odom <- base = (odom <- odom_ned) (in) (frd <- flu).
  const tf2::Quaternion enu_from_ned =
      parent_ned ? tf2::Quaternion(M_SQRT1_2, M_SQRT1_2, 0, 0) : tf2::Quaternion(0, 0, 0, 1);
  const tf2::Quaternion frd_from_flu = child_frd ? tf2::Quaternion(1, 0, 0, 0) : tf2::Quaternion(0, 0, 0, 1);
  tf2::Transform pose;
  tf2::fromMsg(in.pose.pose, pose);
  const tf2::Transform enu = tf2::Transform(enu_from_ned) * pose * tf2::Transform(frd_from_flu);
  tf2::toMsg(enu, out->pose.pose);
  // The covariance is in the parent frame (position, then rotation about its axes): R C R^T per block.
  const tf2::Matrix3x3 r(enu_from_ned);
  for (int a = 0; a < 2; ++a)
    for (int b = 0; b < 2; ++b)
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) {
          double v = 0.0;
          for (int k = 0; k < 3; ++k)
            for (int l = 0; l < 3; ++l) v += r[i][k] * in.pose.covariance[(3 * a + k) * 6 + 3 * b + l] * r[j][l];
          out->pose.covariance[(3 * a + i) * 6 + 3 * b + j] = v;
        }
  out->twist = geometry_msgs::TwistWithCovariance();  // not used
  return true;
}

NavInput::NavInput(ros::NodeHandle nh, const std::string& topic, const NavInputOptions& options)
    : options_(options),
      covariance_check_(options.tf_drift, options.tf_yaw_drift),
      drift_(options.tf_drift, options.tf_yaw_drift) {
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

std::optional<core::NavRecord> NavInput::at(const ros::Time& stamp, const core::CameraMount& mount,
                                            bool clock_jumped_back) {
  if (tf_buffer_) return fromTf(stamp, mount);
  if (clock_jumped_back) {
    std::size_t dropped = 0;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      dropped = track_.dropClockBefore(stamp.toSec(), std::max(options_.reorder_tolerance_s, 1e-6));
      if (dropped > 0) covariance_check_.reset();
    }
    if (dropped > 0)
      ROS_WARN(
          "odometry: the image stamps jumped back to %.3f: %zu nav readings of the clock before dropped (the new "
          "session uses only readings of its own clock)",
          stamp.toSec(), dropped);
  }
  std::optional<core::NavRecord> r = fromTopic(stamp.toSec());
  // The track holds a camera at base_link: back to base_link, then to the mounted camera.
  if (r) r->pose = core::cameraFromVehicle(core::vehicleFromCamera(r->pose, core::CameraMount()), mount);
  return r;
}

void NavInput::onNav(const nav_msgs::OdometryConstPtr& msg) {
  ++received_;
  core::NavRecord r;
  std::string why;
  nav_msgs::Odometry enu;
  bool ok = navToEnu(*msg, options_.odom_frame, options_.base_frame, &enu, &why) &&
            rc::navFromMsg(enu, core::CameraMount(), &r, &why);
  if (ok) {
    std::lock_guard<std::mutex> lock(mutex_);
    // Further back than a late reading may be: a new clock (a bag played again), the track restarts.
    const double restart_after_s = std::max(options_.reorder_tolerance_s, 1e-6);
    const core::NavCovarianceCheck before = covariance_check_;
    if (!track_.empty() && r.stamp_s < track_.rows().back().stamp_s - restart_after_s) covariance_check_.reset();
    const core::NavCovarianceCheck::Result checked = covariance_check_.add(r);
    ok = track_.append(checked.row, &why, restart_after_s);
    if (!ok) covariance_check_ = before;  // a refused reading is not part of the track
    if (ok && !why.empty()) ROS_WARN("odometry: nav reading at %.3f: %s", r.stamp_s, why.c_str());
    if (ok && checked.decided)
      ROS_WARN(
          "odometry: the nav covariance on %s has not grown over %.1f m travelled (x-y %s at %.4f m, yaw %s at "
          "%.5f rad): a dead reckoning's grows, so it is not used; sigma = ~nav_tf_drift %.3f x distance and "
          "~nav_tf_yaw_drift %.4f rad/m x distance instead (nav_covariance_replaced counts the readings)",
          sub_.getTopic().c_str(), covariance_check_.distance(), core::verdictName(checked.xy).c_str(), r.sigma_xy_m,
          core::verdictName(checked.yaw).c_str(), r.sigma_yaw_rad, options_.tf_drift, options_.tf_yaw_drift);
    covariance_replaced_ += ok && checked.replaced;
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
