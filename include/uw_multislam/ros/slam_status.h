// The SLAM at a glance: uw_multislam/SlamStatus on `status` (latched) and its rviz text marker.
//
// Who publishes what. The odometry alone knows whether it tracks, is lost or paused, what its
// last frame cost and how many frames it skipped; the back-end alone knows the sessions, maps,
// loops and its mode. So the odometry publishes its part on `odometry/status` (SlamStatus with the
// back-end's fields -1: one message type, and a head without a back-end still has a status), and
// the back-end adds its part and publishes the whole on `status`. The other way round (the
// back-end reading the odometry's /diagnostics) would have told a tracking loss a second late and
// parsed text; the odometry asking the back-end would have made the odometry, whose latency
// matters, wait for the back-end's lock.
//
// When. The odometry: after a frame that made a keyframe or changed its state, and once a second
// on a wall timer (so NO_INPUT shows when frames stop). The back-end: when the odometry's part
// arrives, after a worker item that changed its part (a keyframe, a loop), and once a second.
#pragma once

#include <ros/node_handle.h>
#include <ros/publisher.h>
#include <ros/subscriber.h>
#include <ros/wall_timer.h>

#include <chrono>
#include <cstdint>
#include <map>
#include <mutex>
#include <string>
#include <utility>

#include "uw_multislam/SlamStatus.h"
#include "uw_multislam/core/session/session_worker.h"
#include "uw_multislam/ros/odometry_counters.h"

namespace uw_multislam {
namespace ros_status {

/// The state's name as SlamStatus documents it (no_input, tracking, lost, paused, localisation).
const char* stateName(std::uint8_t state);

/// Frames received and not taken into the odometry: every skip and drop counter of the odometry.
long framesSkipped(const ros_diagnostics::OdometryCounters& c);

/// The odometry's state from its counters, followed from one frame to the next: lost from a
/// tracking loss (tracking_losses grew) until a session starts again (sessions grew).
class OdometryStateTracker {
 public:
  /// The odometry's part of a status after a frame (frame_age_s 0) or on the timer (the wall
  /// seconds since the last frame; -1: none yet). NO_INPUT when no session has started (no frame
  /// yet, or none accepted: no mount) or no frame came for `timeout_s`.
  uw_multislam::SlamStatus update(const ros_diagnostics::OdometryCounters& c, double frame_age_s, double timeout_s);

 private:
  long losses_ = 0, sessions_ = 0;
  bool lost_ = false;
};

/// The back-end's part, as the worker's lock shows it.
struct BackendPart {
  std::map<int, std::pair<int, int>> sessions;  // id -> (map, keyframes)
  int maps = 0, keyframes = 0, loops = 0;
  int active = -1;              // the back-end's active session
  double last_loop_stamp = -1;  // the newest accepted loop's new keyframe's stamp (s): which loop; -1: none this run
  bool localisation = false;
  bool operator==(const BackendPart& o) const;
};
BackendPart backendPart(const core::SessionQueries& m);

/// `odometry` (its part) completed with the back-end's at ROS time `now_s`, the newest loop having
/// been seen at `loop_seen_s` (-1: none); the text filled.
uw_multislam::SlamStatus combine(uw_multislam::SlamStatus odometry, const BackendPart& b, double now_s,
                                 double loop_seen_s);
/// The one line the marker shows (and SlamStatus.text).
std::string statusText(const uw_multislam::SlamStatus& s);

/// The odometry's part on odometry/status.
class OdometryStatusPublisher {
 public:
  OdometryStatusPublisher(ros::NodeHandle& nh, double input_timeout_s);
  /// After each frame the worker finished, with the counters then.
  void frame(const ros_diagnostics::OdometryCounters& c);

 private:
  void publish(const ros_diagnostics::OdometryCounters& c, double frame_age_s, bool always);

  const double timeout_s_;
  ros::Publisher pub_;
  ros::WallTimer timer_;
  std::mutex mutex_;  // the worker's frames and the timer
  OdometryStateTracker tracker_;
  ros_diagnostics::OdometryCounters last_;
  std::chrono::steady_clock::time_point last_frame_;
  bool any_frame_ = false;
  long keyframes_ = 0;
  std::uint8_t state_ = uw_multislam::SlamStatus::NO_INPUT;
};

/// The whole status on `status` and its marker on `status_marker`, in the back-end.
class BackendStatusPublisher {
 public:
  /// `worker` must outlive this; the marker is drawn in `base_frame` (it follows the vehicle).
  BackendStatusPublisher(ros::NodeHandle& nh, core::SessionWorker* worker, std::string base_frame);
  /// The worker's after-item hook (under its lock): published when the back-end's part changed.
  void afterItem(const core::SessionQueries& m);

 private:
  void onOdometry(const uw_multislam::SlamStatusConstPtr& msg);
  void take(BackendPart b);  // under mutex_: a newer loop is noted with the time it was seen
  void publish();            // under mutex_

  core::SessionWorker* worker_;
  const std::string base_frame_;
  ros::Publisher pub_, marker_pub_;
  ros::Subscriber sub_;
  ros::WallTimer timer_;
  std::mutex mutex_;  // taken after the worker's lock, never before it
  uw_multislam::SlamStatus odometry_;
  BackendPart backend_;
  double loop_seen_s_ = -1;  // ROS time the newest loop (backend_.last_loop_stamp) was seen
};

}  // namespace ros_status
}  // namespace uw_multislam
