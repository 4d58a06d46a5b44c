// What the back-end publishes of its sessions, from the session manager's state: each session's
// trajectory in its own frame (session_trajectory, for the loop detectors' local candidates), its
// path in the map frame (paths/session_<id>, latched, advertised with its first keyframe), the
// loop and trajectory markers, the active session's keyframe pose (and, while it is relocalised
// in another map, relocalised_pose: core::RelocalisationTracker), the corrections the frame
// publisher sends as tf, and active_session (what the odometry is asked to record next). Every
// pose in the map frame goes out in the published `map` (ENU at a datum: FramePublisher::mapFrame()).
//
// Not thread-safe: the back-end calls it under the session worker's lock (the manager's state
// must not change during a publication), except onOdometry, which never takes that lock: the
// per-frame pose goes out through the frame publisher's own copy of the active correction.
#pragma once

#include <geometry_msgs/PoseWithCovarianceStamped.h>
#include <ros/node_handle.h>
#include <ros/publisher.h>
#include <ros/time.h>

#include <cstdint>
#include <functional>
#include <map>
#include <string>

#include "uw_multislam/SessionState.h"
#include "uw_multislam/core/session/session_manager.h"
#include "uw_multislam/core/session/session_worker.h"
#include "uw_multislam/ros/frame_publisher.h"

namespace uw_multislam {
namespace ros_sessions {

class SessionPublisher {
 public:
  /// `frames` (thread-safe) must outlive this; `say` gets the relocalisation's changes.
  SessionPublisher(ros::NodeHandle& nh, ros_frames::FramePublisher* frames, const ros_frames::FrameOptions& options,
                   std::function<void(const std::string&)> say);

  /// The active session (all_sessions false: its trajectory, path, pose and tf; the markers at
  /// most at 1 Hz) or every session (after an event: joins, splits, optimisations, requests).
  void publishAll(const core::SessionQueries& m, bool all_sessions);
  /// On active_session: the recording session, else the id the next one gets, in `state` (ACTIVE,
  /// or FINISHED after finish_session: the odometry then drops frames until start_session).
  void announceNextSession(const core::SessionQueries& m, std::uint8_t state = uw_multislam::SessionState::ACTIVE);
  /// On active_session, next_session_only: another vehicle's session took an id, so our
  /// odometry's own next session takes a later one; the last request repeated, not renewed.
  void announceNextId(const core::SessionQueries& m);
  /// odometry/pose (the odometry's pose in its session's frame): the vehicle's pose in the map
  /// frame on `pose`, and odom -> base_link (frame publisher). Never waits for the worker.
  void onOdometry(const geometry_msgs::PoseWithCovarianceStampedConstPtr& msg);
  /// A deleted session's latched path: an empty one, or rviz would go on drawing it.
  void clearPath(int session);
  /// No active session (finish_session): nothing relocalised.
  void resetRelocalisation() { reloc_.reset(); }
  const core::RelocalisationTracker::State& relocalisation() const { return reloc_.state(); }

 private:
  /// Its poses in the map frame `out` gives; returns the core's map <- session (FramePublisher turns it).
  core::Pose2 publishSession(const core::SessionQueries& m, int id, const core::MapFrame& out);
  uw_multislam::SessionState sessionRequest(const core::SessionQueries& m, std::uint8_t state) const;

  ros::NodeHandle nh_;
  ros_frames::FramePublisher* frames_;
  const ros_frames::FrameOptions options_;
  const std::function<void(const std::string&)> say_;
  core::RelocalisationTracker reloc_;
  std::map<int, double> offsets_;         // where each map is drawn in rviz
  uw_multislam::SessionState announced_;  // the last active_session request
  ros::WallTime markers_sent_;            // the last trajectory_markers
  std::map<int, ros::Publisher> path_pubs_;
  ros::Publisher trajectory_pub_, markers_pub_, trajectory_markers_pub_, keyframe_pose_pub_, active_pub_,
      relocalised_pub_, pose_pub_;
};

}  // namespace ros_sessions
}  // namespace uw_multislam
