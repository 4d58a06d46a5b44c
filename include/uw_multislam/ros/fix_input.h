// The back-end's sensor_msgs/NavSatFix input (doc/ros_api.md, backend_node "fix"; doc/frames.md):
// fixes from a GPS at the surface or a USBL, each matched to the keyframe nearest in stamp and
// given to the session manager as an absolute position prior with its covariance
// (core/export/geo_fix.h does the work; this is the glue). A fix is the position of its frame_id
// (the antenna, the transponder), whose lever arm from base_link tf's static transforms give (an
// empty frame_id or base_link: none; a frame without a static transform, or more than 20 m from
// base_link: refused, counted fixes_refused_no_lever_arm, WARNed).
// Refusals are counted by reason (/diagnostics, fixes_refused_*) and WARNed, throttled.
// Threading: the subscription and a steady timer run on the node's callback thread; the matcher
// has its own mutex, taken after the worker's lock when both are held.
#pragma once

#include <ros/ros.h>
#include <sensor_msgs/NavSatFix.h>

#include <memory>
#include <mutex>
#include <optional>
#include <string>

#include "uw_multislam/core/export/geo_fix.h"
#include "uw_multislam/core/session/session_worker.h"
#include "uw_multislam/ros/backend_counters.h"
#include "uw_multislam/ros/frame_publisher.h"
#include "uw_multislam/ros/slam_params.h"

namespace uw_multislam {
namespace ros_geo {

/// The message as the core takes it.
core::NavFix fromMsg(const sensor_msgs::NavSatFix& msg);

class FixInput {
 public:
  /// Subscribes to `topic` on `nh` (relative names: the back-end's namespace). Throws
  /// std::invalid_argument on bad options (read and checked by ros_params::backendNodeletOptions).
  FixInput(ros::NodeHandle nh, const std::string& topic, const core::FixOptions& options, const std::string& base_frame,
           core::SessionWorker* worker, ros_frames::FramePublisher* frames);
  /// The back-end's: on ~fix/topic with ~fix/*, or null when ~fix/topic is empty (off).
  static std::unique_ptr<FixInput> make(ros::NodeHandle nh, const ros_params::BackendNodeletOptions& options,
                                        core::SessionWorker* worker, ros_frames::FramePublisher* frames);
  FixInput(const FixInput&) = delete;
  FixInput& operator=(const FixInput&) = delete;
  /// Its counters into `c` (fixes_*); callable under the worker's lock.
  void counters(ros_diagnostics::BackendCounters* c) const;

 private:
  void onFix(const sensor_msgs::NavSatFixConstPtr& msg);
  /// The waiting fixes against the keyframes the manager holds now; the priors given; the maps
  /// they made due solved by the worker.
  void matchWaiting();
  void warnIfRefused(long before);
  long refusals() const;  // the matcher's mutex held

  std::string base_frame_;
  core::SessionWorker* worker_;
  ros_frames::FramePublisher* frames_;
  mutable std::mutex mutex_;  // guards matcher_ and said_frame_
  core::FixMatcher matcher_;
  std::string said_frame_;  // the frame whose lever arm was said last, and that arm
  Eigen::Vector2d said_arm_ = Eigen::Vector2d::Zero();
  ros::Subscriber sub_;
  ros::SteadyTimer timer_;  // fixes waiting for a keyframe are tried again
};

}  // namespace ros_geo
}  // namespace uw_multislam
