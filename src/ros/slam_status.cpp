#include "uw_multislam/ros/slam_status.h"

#include <ros/time.h>
#include <visualization_msgs/Marker.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <set>
#include <vector>

#include "uw_multislam/ros/topics.h"

namespace uw_multislam {
namespace ros_status {

using uw_multislam::SlamStatus;

const char* stateName(std::uint8_t state) {
  switch (state) {
    case SlamStatus::TRACKING:
      return "tracking";
    case SlamStatus::LOST:
      return "lost";
    case SlamStatus::PAUSED:
      return "paused";
    case SlamStatus::LOCALISATION:
      return "localisation";
    default:
      return "no_input";
  }
}

long framesSkipped(const ros_diagnostics::OdometryCounters& c) {
  return c.skipped_no_camera_info + c.skipped_no_altitude + c.dropped_queue_full + c.skipped_for_newest +
         c.frames_dropped_paused + c.badImages() + c.skipped_camera_info + c.skipped_duplicate_stamp +
         c.skipped_out_of_order + c.skipped_no_mount + c.skipped_by_odometry;
}

SlamStatus OdometryStateTracker::update(const ros_diagnostics::OdometryCounters& c, double frame_age_s,
                                        double timeout_s) {
  if (c.tracking_losses > losses_) lost_ = true;  // a frame closes a session: the next one cannot start one
  if (c.sessions > sessions_) lost_ = false;
  losses_ = c.tracking_losses, sessions_ = c.sessions;
  SlamStatus s;
  if (c.paused)
    s.state = SlamStatus::PAUSED;
  else if (c.sessions == 0 || frame_age_s < 0 || frame_age_s > timeout_s)
    s.state = SlamStatus::NO_INPUT;
  else
    s.state = lost_ ? SlamStatus::LOST : SlamStatus::TRACKING;
  s.state_name = stateName(s.state);
  s.session = c.sessions > 0 ? static_cast<int>(c.session) : -1;
  s.frame_ms = c.ms_last_frame;
  s.frame_age_s = frame_age_s;
  s.frames_received = c.images_received;
  s.frames_skipped = framesSkipped(c);
  s.tracking_losses = static_cast<int>(c.tracking_losses);
  s.session_keyframes = s.map = s.sessions = s.maps = s.keyframes = s.loops = -1;
  s.last_loop_age_s = -1;
  s.text = statusText(s);
  return s;
}

bool BackendPart::operator==(const BackendPart& o) const {
  return sessions == o.sessions && maps == o.maps && keyframes == o.keyframes && loops == o.loops &&
         active == o.active && last_loop_stamp == o.last_loop_stamp && localisation == o.localisation;
}

BackendPart backendPart(const core::SessionQueries& m) {
  BackendPart b;
  std::set<int> maps;
  for (const core::SessionSummary& s : m.list()) {
    b.sessions[s.id] = {s.map, s.keyframes};
    b.keyframes += s.keyframes;
    maps.insert(s.map);
  }
  b.maps = static_cast<int>(maps.size());
  b.active = m.activeSession();
  b.localisation = m.localising();
  // This run's visual loops the back-end kept: a loop's new keyframe is of a session of this run.
  const std::vector<core::Loop>& loops = m.loops();
  for (std::size_t i = 0; i < loops.size(); ++i) {
    const core::Loop& l = loops[i];
    if (l.nav_placement || m.loopRefused(i) || !m.has(l.session_b) || m.restored(l.session_b)) continue;
    ++b.loops;
    const std::vector<double>& stamps = m.stamps(l.session_b);
    if (l.keyframe_b >= 0 && l.keyframe_b < static_cast<int>(stamps.size()))
      b.last_loop_stamp = std::max(b.last_loop_stamp, stamps[l.keyframe_b]);
  }
  return b;
}

SlamStatus combine(SlamStatus s, const BackendPart& b, double now_s, double loop_seen_s) {
  if (s.session < 0) s.session = b.active;  // no word from the odometry yet: the session keyframes go to
  const auto it = b.sessions.find(s.session);
  s.map = it != b.sessions.end() ? it->second.first : -1;
  s.session_keyframes = it != b.sessions.end() ? it->second.second : 0;
  s.sessions = static_cast<int>(b.sessions.size());
  s.maps = b.maps, s.keyframes = b.keyframes, s.loops = b.loops;
  s.last_loop_age_s = loop_seen_s >= 0 ? std::max(0.0, now_s - loop_seen_s) : -1.0;
  s.localisation = b.localisation;
  if (s.state == SlamStatus::TRACKING && b.localisation) s.state = SlamStatus::LOCALISATION;
  s.state_name = stateName(s.state);
  s.text = statusText(s);
  return s;
}

std::string statusText(const SlamStatus& s) {
  std::string upper = s.state_name;
  for (char& c : upper) c = static_cast<char>(c == '_' ? ' ' : std::toupper(static_cast<unsigned char>(c)));
  char line[320];
  int n = std::snprintf(line, sizeof line, "%s", upper.c_str());
  auto add = [&](const char* format, auto... values) {
    if (n >= 0 && n < static_cast<int>(sizeof line)) n += std::snprintf(line + n, sizeof line - n, format, values...);
  };
  if (s.session >= 0) add("  session %d", s.session);
  if (s.map >= 0) add(" (map %d)", s.map);
  if (s.session_keyframes >= 0) add(", %d keyframes", s.session_keyframes);
  if (s.sessions >= 0) add("  |  %d sessions, %d maps", s.sessions, s.maps);
  if (s.loops >= 0 && s.last_loop_age_s >= 0)
    add("  |  %d loops, last %.0f s ago", s.loops, s.last_loop_age_s);
  else if (s.loops >= 0)
    add("  |  %s", "no loop yet");
  add("  |  %.0f ms/frame, %ld skipped", s.frame_ms, static_cast<long>(s.frames_skipped));
  if (s.frame_age_s >= 0 && s.state == SlamStatus::NO_INPUT) add(", no frame for %.0f s", s.frame_age_s);
  return line;
}

// --- The odometry's part ---------------------------------------------------------------------------

OdometryStatusPublisher::OdometryStatusPublisher(ros::NodeHandle& nh, double input_timeout_s)
    : timeout_s_(input_timeout_s) {
  pub_ = nh.advertise<SlamStatus>(topics::kOdometryStatus, 10, true);  // a state change is never dropped
  timer_ = nh.createWallTimer(ros::WallDuration(1.0), [this](const ros::WallTimerEvent&) {
    std::lock_guard<std::mutex> lock(mutex_);
    const double age =
        any_frame_ ? std::chrono::duration<double>(std::chrono::steady_clock::now() - last_frame_).count() : -1.0;
    publish(last_, age, true);
  });
  std::lock_guard<std::mutex> lock(mutex_);
  publish(last_, -1.0, true);  // NO_INPUT until the first frame
}

void OdometryStatusPublisher::frame(const ros_diagnostics::OdometryCounters& c) {
  std::lock_guard<std::mutex> lock(mutex_);
  last_ = c;
  last_frame_ = std::chrono::steady_clock::now();
  any_frame_ = true;
  publish(c, 0.0, c.keyframes != keyframes_);
  keyframes_ = c.keyframes;
}

void OdometryStatusPublisher::publish(const ros_diagnostics::OdometryCounters& c, double frame_age_s, bool always) {
  SlamStatus s = tracker_.update(c, frame_age_s, timeout_s_);
  if (!always && s.state == state_) return;
  state_ = s.state;
  s.header.stamp = ros::Time::now();
  pub_.publish(s);
}

// --- The whole, in the back-end ---------------------------------------------------------------------

namespace {

std_msgs::ColorRGBA stateColour(std::uint8_t state) {
  std_msgs::ColorRGBA c;
  c.a = 1.0f;
  switch (state) {
    case SlamStatus::TRACKING:
      c.g = 0.9f;
      break;
    case SlamStatus::LOCALISATION:
      c.g = 0.8f, c.b = 1.0f;
      break;
    case SlamStatus::LOST:
      c.r = 1.0f, c.g = 0.2f, c.b = 0.2f;
      break;
    case SlamStatus::PAUSED:
      c.r = 1.0f, c.g = 0.85f;
      break;
    default:
      c.r = c.g = c.b = 0.7f;
  }
  return c;
}

}  // namespace

BackendStatusPublisher::BackendStatusPublisher(ros::NodeHandle& nh, core::SessionWorker* worker, std::string base_frame)
    : worker_(worker), base_frame_(std::move(base_frame)) {
  odometry_.state = SlamStatus::NO_INPUT;
  odometry_.session = -1, odometry_.frame_age_s = -1;
  pub_ = nh.advertise<SlamStatus>(topics::kStatus, 10, true);
  marker_pub_ = nh.advertise<visualization_msgs::Marker>(topics::kStatusMarker, 1, true);
  sub_ = nh.subscribe(topics::kOdometryStatus, 10, &BackendStatusPublisher::onOdometry, this);
  timer_ = nh.createWallTimer(ros::WallDuration(1.0), [this](const ros::WallTimerEvent&) {
    BackendPart b = worker_->locked([](const core::SessionQueries& m) { return backendPart(m); });
    std::lock_guard<std::mutex> lock(mutex_);
    take(std::move(b));
    publish();
  });
}

void BackendStatusPublisher::afterItem(const core::SessionQueries& m) {
  BackendPart b = backendPart(m);
  std::lock_guard<std::mutex> lock(mutex_);
  if (b == backend_) return;
  take(std::move(b));
  publish();
}

void BackendStatusPublisher::take(BackendPart b) {
  // The age of the last loop is counted from when the back-end took it, not from its image's stamp:
  // a bag played without its clock has stamps of another time.
  if (b.last_loop_stamp > backend_.last_loop_stamp) loop_seen_s_ = ros::Time::now().toSec();
  if (b.last_loop_stamp < 0) loop_seen_s_ = -1;
  backend_ = std::move(b);
}

void BackendStatusPublisher::onOdometry(const uw_multislam::SlamStatusConstPtr& msg) {
  std::lock_guard<std::mutex> lock(mutex_);
  odometry_ = *msg;
  publish();
}

void BackendStatusPublisher::publish() {
  const ros::Time now = ros::Time::now();
  SlamStatus s = combine(odometry_, backend_, now.toSec(), loop_seen_s_);
  s.header.stamp = now;
  pub_.publish(s);
  if (marker_pub_.getNumSubscribers() == 0) return;
  visualization_msgs::Marker m;
  m.header.frame_id = base_frame_;  // stamp 0: rviz draws it at the vehicle's newest pose
  m.ns = "status";
  m.type = visualization_msgs::Marker::TEXT_VIEW_FACING;
  m.action = visualization_msgs::Marker::ADD;
  m.pose.position.y = -0.6;  // beside the vehicle, not over its trajectory
  m.pose.orientation.w = 1.0;
  m.scale.z = 0.25;  // text height, m
  m.color = stateColour(s.state);
  m.text = s.text;
  marker_pub_.publish(m);
}

}  // namespace ros_status
}  // namespace uw_multislam
