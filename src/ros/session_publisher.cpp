#include "uw_multislam/ros/session_publisher.h"

#include <geometry_msgs/PoseStamped.h>
#include <geometry_msgs/PoseWithCovarianceStamped.h>
#include <nav_msgs/Path.h>
#include <visualization_msgs/MarkerArray.h>

#include <algorithm>
#include <utility>
#include <vector>

#include "uw_multislam/SessionTrajectory.h"
#include "uw_multislam/ros/backend_conversions.h"
#include "uw_multislam/ros/conversions.h"
#include "uw_multislam/ros/topics.h"

namespace uw_multislam {
namespace ros_sessions {

namespace rc = ros_conversions;

SessionPublisher::SessionPublisher(ros::NodeHandle& nh, ros_frames::FramePublisher* frames,
                                   const ros_frames::FrameOptions& options, std::function<void(const std::string&)> say)
    : nh_(nh), frames_(frames), options_(options), say_(std::move(say)) {
  trajectory_pub_ = nh.advertise<uw_multislam::SessionTrajectory>(topics::kSessionTrajectory, 10);
  markers_pub_ = nh.advertise<visualization_msgs::MarkerArray>(topics::kLoopMarkers, 1, true);
  trajectory_markers_pub_ = nh.advertise<visualization_msgs::MarkerArray>(topics::kTrajectoryMarkers, 1, true);
  keyframe_pose_pub_ = nh.advertise<geometry_msgs::PoseWithCovarianceStamped>(topics::kKeyframePoseWithCovariance, 10);
  active_pub_ = nh.advertise<uw_multislam::SessionState>(topics::kActiveSession, 1, true);
  relocalised_pub_ = nh.advertise<geometry_msgs::PoseWithCovarianceStamped>(topics::kRelocalisedPose, 10);
  pose_pub_ = nh.advertise<geometry_msgs::PoseStamped>(topics::kCurrentPose, 10);
}

void SessionPublisher::onOdometry(const geometry_msgs::PoseWithCovarianceStampedConstPtr& msg) {
  core::UncertainPose2 odo;
  if (!rc::fromMsg(msg->pose, &odo)) return;
  const int session = rc::sessionOfFrame(msg->header.frame_id, options_.session_frame_prefix);
  const std::optional<core::Pose2> in_map = frames_->onOdometry(session, odo, msg->header.stamp);  // never waits
  if (!in_map) return;
  geometry_msgs::PoseStamped p;
  p.header.stamp = msg->header.stamp;
  p.header.frame_id = options_.map_frame;
  p.pose = rc::toPoseMsg(*in_map);
  pose_pub_.publish(p);
}

core::Pose2 SessionPublisher::publishSession(const core::SessionQueries& m, int id, const core::MapFrame& out) {
  const std::vector<core::Pose2> poses = m.poses(id);
  const core::Pose2 correction = m.correction(id);
  std::vector<ros::Time> stamps;
  for (double s : m.stamps(id)) stamps.emplace_back(std::max(0.0, s));
  const ros::Time now = stamps.empty() ? ros::Time::now() : stamps.back();
  trajectory_pub_.publish(rc::toSessionTrajectoryMsg(id, m.mapOf(id), m.posesInSessionFrame(id), now,
                                                     options_.session_frame_prefix + std::to_string(id)));
  ros::Publisher& path = path_pubs_[id];  // latched, advertised with the session's first keyframe
  if (!path && m.hasKeyframe(id))
    path = nh_.advertise<nav_msgs::Path>(topics::kSessionPathPrefix + std::to_string(id), 1, true);
  const std::string& map = options_.map_frame;
  if (path)
    path.publish(rc::toPathMsg(rc::toPublished(out, rc::vehiclePoses(m, id, frames_->mount())), stamps, map, now));
  if (id != m.activeSession()) return correction;
  std::string said;
  const std::optional<core::SessionQueries::Relocalisation> reloc = reloc_.update(m, id, &said);
  if (!said.empty() && say_) say_(said);
  if (!reloc) {
    frames_->setActive(id, correction, poses.back(), now);
    const core::UncertainPose2 vehicle = frames_->vehicle(m.lastKeyframeInMap(id));
    keyframe_pose_pub_.publish(rc::toPoseWithCovarianceStampedMsg(out.toPublished(vehicle), map, now));
    frames_->publishFix(vehicle, now);  // keyframe_fix: the same pose on WGS84, with a datum
    return correction;
  }
  // Relocalised in another map: tf and the poses go out in that map's frame (where it is drawn).
  frames_->setActive(id, reloc->correction, reloc->pose.mean, now);
  const core::UncertainPose2 vehicle = frames_->vehicle(reloc->pose);
  const auto msg = rc::toPoseWithCovarianceStampedMsg(out.toPublished(vehicle), map, now);
  keyframe_pose_pub_.publish(msg);
  frames_->publishFix(vehicle, now);
  relocalised_pub_.publish(msg);
  reloc_.published();
  return reloc->correction;  // map -> session_<id> as map -> odom: the stored map's
}

void SessionPublisher::publishAll(const core::SessionQueries& m, bool all_sessions) {
  if (all_sessions) offsets_ = rc::mapOffsets(m, frames_->mount());  // maps change only with events
  std::map<int, core::Pose2> corrections;                            // map -> session_<id>: sent together
  const core::MapFrame out = frames_->mapFrame();                    // one datum for the whole publication
  for (int id : all_sessions ? m.sessionIds() : std::vector<int>{m.activeSession()})
    if (id >= 0) corrections[id] = publishSession(m, id, out);
  frames_->setSessionFrames(corrections);
  const ros::WallTime now = ros::WallTime::now();  // every session's markers: on events, else at most 1 Hz
  if (trajectory_markers_pub_.getNumSubscribers() > 0 && (all_sessions || (now - markers_sent_).toSec() >= 1.0)) {
    markers_sent_ = now;
    trajectory_markers_pub_.publish(rc::toPublished(
        out, rc::toTrajectoryMarkersMsg(m, frames_->mount(), offsets_, options_.map_frame, ros::Time::now())));
  }
  if (!all_sessions && m.loops().empty()) return;
  markers_pub_.publish(rc::toPublished(out, rc::toMarkerArrayMsg(rc::loopSegments(m, frames_->mount(), offsets_),
                                                                 options_.map_frame, ros::Time::now())));
}

uw_multislam::SessionState SessionPublisher::sessionRequest(const core::SessionQueries& m, std::uint8_t state) const {
  uw_multislam::SessionState st;
  st.session = m.activeSession() >= 0 ? m.activeSession() : m.nextId();
  st.name = m.has(st.session) ? m.name(st.session) : core::defaultSessionName(st.session);
  st.state = state;
  st.map = st.session;
  st.relocalised_map = -1;
  st.next_session = m.nextId();
  return st;
}

void SessionPublisher::announceNextSession(const core::SessionQueries& m, std::uint8_t state) {
  announced_ = sessionRequest(m, state);
  active_pub_.publish(announced_);
}

void SessionPublisher::announceNextId(const core::SessionQueries& m) {
  // The last request, repeated for a late subscriber (none yet: what the odometry would be asked now).
  uw_multislam::SessionState st =
      announced_.name.empty() ? sessionRequest(m, uw_multislam::SessionState::ACTIVE) : announced_;
  st.next_session = m.nextId();
  st.next_session_only = true;
  active_pub_.publish(st);
}

void SessionPublisher::clearPath(int session) {
  const auto path = path_pubs_.find(session);
  if (path == path_pubs_.end() || !path->second) return;
  nav_msgs::Path empty;
  empty.header.stamp = ros::Time::now();
  empty.header.frame_id = options_.map_frame;
  path->second.publish(empty);
}

}  // namespace ros_sessions
}  // namespace uw_multislam
