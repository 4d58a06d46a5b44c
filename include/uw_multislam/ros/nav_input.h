// The odometry's nav input: the vehicle's dead reckoning at each frame's stamp, as a nav row of the
// core (core/frontend/nav_prior.h), from one of two sources (~nav_source):
//   topic  nav_msgs/Odometry on nav/odom, kept for ~nav_buffer_s and interpolated at the stamp (no
//          extrapolation: a frame after the last reading goes without). Its frames are checked
//          (navToEnu): header.frame_id the odom frame (ENU) or its REP-103 "_ned" twin,
//          child_frame_id the base frame or its "_frd" twin; a NED reading is turned into ENU by
//          REP-103's fixed rotation. Its covariance is used once it grows along the trajectory;
//          until then, and for good when it has not grown over 2 m (constant or zero), the sigmas
//          are the tf source's drift model (core::NavCovarianceCheck; counted and WARNed). Bad
//          readings (other frames, not finite, a negative variance, a zero stamp, not after the last
//          one) are skipped and counted. A frame newer than the newest reading waits
//          up to ~nav_wait_s for the next one while readings keep coming (the nav and the image
//          travel on separate connections); after 1 s without readings (an outage) it does not wait.
//   tf     odom_frame -> base_frame at the stamp (waiting up to ~nav_tf_wait_s); a frame without the
//          transform goes without nav (counted). tf has no covariance: sigma grows with the distance
//          travelled (TfNavDrift).
// The two differ in their sigmas on purpose: a topic reading carries the nav's own covariance.
// Threading: the topic callback (any thread) appends under a mutex of its own; at() is called by
// the odometry's worker only.
#pragma once

#include <nav_msgs/Odometry.h>
#include <ros/ros.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_listener.h>

#include <atomic>
#include <condition_variable>
#include <memory>
#include <mutex>
#include <optional>
#include <string>

#include "uw_multislam/core/frontend/nav_drift.h"
#include "uw_multislam/core/frontend/nav_prior.h"
#include "uw_multislam/core/geometry/vehicle_frame.h"

namespace uw_multislam {
namespace ros_inputs {

struct NavInputOptions {
  std::string source = "topic";      // topic, tf or none
  double wait_s = 0.05;              // topic: how long a frame newer than the newest reading waits
  double buffer_s = 60.0;            // topic: readings kept this long behind the newest
  double reorder_tolerance_s = 1.0;  // topic: a reading further back is a new clock (the track restarts)
  double tf_wait_s = 0.05;           // tf: how long a frame waits for its transform
  double tf_drift = 0.01;            // tf: sigma_xy = this x the distance travelled
  double tf_yaw_drift = 0.001;       // tf: sigma_yaw = this (rad/m) x the distance travelled
  std::string odom_frame = "odom", base_frame = "base_link";
};

/// The tf source's sigmas: the distance travelled along the poses given, times the drift rates
/// (core::NavDriftModel).
class TfNavDrift {
 public:
  TfNavDrift(double xy_per_m, double yaw_per_m) : model_(xy_per_m, yaw_per_m) {}
  /// The nav row of the vehicle's pose `vehicle` (in odom) at `stamp_s`: the camera's pose by
  /// `mount`, sigmas from the distance travelled up to it.
  core::NavRecord add(double stamp_s, const core::Pose2& vehicle, const core::CameraMount& mount);
  double distance() const { return model_.distance(); }

 private:
  core::NavDriftModel model_;
};

/// `in` as the ENU reading the core takes: header.frame_id `odom_frame` (ENU, REP-103) or
/// `odom_frame`_ned (NED), child_frame_id `base_frame` (x forward, y left, z up) or
/// `base_frame`_frd (forward, right, down); a NED parent or an FRD child is turned by REP-103's
/// fixed rotations (pose and covariance). False, with `why` naming the expected frames, for
/// other (or empty) frame ids. Tested in test/ros/test_nav_input.cpp.
bool navToEnu(const nav_msgs::Odometry& in, const std::string& odom_frame, const std::string& base_frame,
              nav_msgs::Odometry* out, std::string* why);

class NavInput {
 public:
  /// Subscribes to `topic` (source topic) or listens to tf (source tf); nothing with none.
  NavInput(ros::NodeHandle nh, const std::string& topic, const NavInputOptions& options);
  /// The nav at a frame's stamp, if there is one: the camera's pose by `mount` (the worker's thread).
  /// `clock_jumped_back`: the images' stamps just jumped back to `stamp`; topic readings of the clock
  /// before are dropped first (NavTrack::dropClockBefore; counted, warned), so a new session never
  /// uses a reading of the pass before (tf's listener clears its own buffer when time jumps back).
  std::optional<core::NavRecord> at(const ros::Time& stamp, const core::CameraMount& mount,
                                    bool clock_jumped_back = false);
  void shutdown() { sub_.shutdown(); }
  long received() const { return received_; }
  long refused() const { return refused_; }
  /// Topic readings whose covariance did not grow (constant or zero): the drift model's sigmas used.
  long covarianceReplaced() const { return covariance_replaced_; }
  long tfMissing() const { return tf_missing_; }
  /// The start-up line: where the nav comes from (`used`: slam/odometry/nav/enabled).
  std::string description(bool used) const;

 private:
  void onNav(const nav_msgs::OdometryConstPtr& msg);
  std::optional<core::NavRecord> fromTopic(double stamp_s);
  std::optional<core::NavRecord> fromTf(const ros::Time& stamp, const core::CameraMount& mount);

  NavInputOptions options_;
  std::mutex mutex_;
  std::condition_variable appended_;
  // Guarded by mutex_: the readings as the camera's poses of a camera at base_link (the identity
  // mount): the mount comes from tf at the first frame, after readings may have arrived.
  core::NavTrack track_;
  ros::WallTime last_appended_;                // guarded by mutex_: when the last reading was appended (zero: none yet)
  core::NavCovarianceCheck covariance_check_;  // guarded by mutex_
  std::atomic<long> received_{0}, refused_{0}, tf_missing_{0}, covariance_replaced_{0};
  std::unique_ptr<tf2_ros::Buffer> tf_buffer_;
  std::unique_ptr<tf2_ros::TransformListener> tf_listener_;
  TfNavDrift drift_;  // the worker's
  ros::Subscriber sub_;
};

}  // namespace ros_inputs
}  // namespace uw_multislam
