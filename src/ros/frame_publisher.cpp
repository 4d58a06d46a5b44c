#include "uw_multislam/ros/frame_publisher.h"

#include <cmath>
#include <cstdio>
#include <vector>

#include <sensor_msgs/NavSatFix.h>

#include "uw_multislam/Keyframe.h"
#include "uw_multislam/core/export/geo_datum.h"

#include "uw_multislam/ros/conversions.h"

namespace uw_multislam {
namespace ros_frames {

namespace rc = ros_conversions;

namespace {
bool same(const core::Pose2& a, const core::Pose2& b) { return a.x() == b.x() && a.y() == b.y() && a.yaw() == b.yaw(); }
}  // namespace

FramePublisher::FramePublisher(ros::NodeHandle nh, const FrameOptions& options) : options_(options), nh_(nh) {
  mount_buffer_ = std::make_unique<tf2_ros::Buffer>();
  mount_listener_ = std::make_unique<tf2_ros::TransformListener>(*mount_buffer_, nh, true);
  // The camera's frame is the one the images name (the keyframes carry their header); one
  // subscription of the process per topic, so no second copy of the keyframes is received.
  camera_frame_sub_ = nh.subscribe<uw_multislam::Keyframe>(
      topics::kKeyframes, 10, [this](const uw_multislam::KeyframeConstPtr& k) { onCameraFrame(k->header.frame_id); });
  if (options_.publish_tf && !options_.publish_odom_tf) {
    buffer_ = std::make_unique<tf2_ros::Buffer>();
    listener_ = std::make_unique<tf2_ros::TransformListener>(*buffer_, nh);
  }
  window_start_ = ros::SteadyTime::now();
  if (options_.publish_odom_tf) odom_pub_ = nh.advertise<nav_msgs::Odometry>(topics::kOdometry, 10);
  if (!options_.publish_tf) return;
  timer_ = nh.createSteadyTimer(ros::WallDuration(1.0 / options_.tf_rate_hz),
                                [this](const ros::SteadyTimerEvent&) { tick(); });
}

FramePublisher::~FramePublisher() {
  timer_.stop();
  camera_frame_sub_.shutdown();
}

void FramePublisher::onCameraFrame(const std::string& frame) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (frame.empty() || frame == mount_for_) return;
    camera_frame_ = frame;
  }
  geometry_msgs::TransformStamped t;
  std::string why;
  core::CameraMount m;
  try {
    t = mount_buffer_->lookupTransform(options_.mount.base_frame, frame, ros::Time(0));
  } catch (const tf2::TransformException& e) {
    ROS_WARN_THROTTLE(10, "frames: no %s -> %s in tf (%s): poses drawn as the camera's until it comes",
                      options_.mount.base_frame.c_str(), frame.c_str(), e.what());
    return;
  }
  // The altimeter does not matter here: only the camera's place in base_link's plane.
  geometry_msgs::Transform level_altimeter = t.transform;
  level_altimeter.rotation = geometry_msgs::Quaternion();
  level_altimeter.rotation.w = 1.0;
  if (!mountFromTransforms(t.transform, level_altimeter, options_.mount.max_tilt_deg * M_PI / 180.0, &m, &why)) {
    ROS_WARN_THROTTLE(10, "frames: %s -> %s: %s", options_.mount.base_frame.c_str(), frame.c_str(), why.c_str());
    return;
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    mount_ = m;
    mount_for_ = frame;
  }
  ROS_INFO("frames: camera mount from tf, %s -> %s: %s", options_.mount.base_frame.c_str(), frame.c_str(),
           core::describe(m).c_str());
}

std::optional<Eigen::Vector2d> FramePublisher::inBasePlane(const std::string& frame, std::string* why) const {
  // A sensor on the vehicle is a static transform (a URDF's fixed joint, /tf_static). Looked up at
  // an old time, a chain through a moving frame (map, odom, a session's) cannot be had, while a
  // static one can at any time: that is what tells them apart.
  geometry_msgs::Vector3 t;
  try {
    t = mount_buffer_->lookupTransform(options_.mount.base_frame, frame, ros::Time(1)).transform.translation;
  } catch (const tf2::TransformException& e) {
    *why = std::string("no static ") + options_.mount.base_frame + " -> " + frame + " in tf: " + e.what();
    return std::nullopt;
  }
  const Eigen::Vector2d arm(t.x, t.y);
  if (!(arm.norm() <= kMaxLeverArmM)) {
    *why = options_.mount.base_frame + " -> " + frame + " is " + std::to_string(arm.norm()) + " m: not on the vehicle";
    return std::nullopt;
  }
  return arm;
}

core::CameraMount FramePublisher::mount() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return mount_;
}

void FramePublisher::setActive(int session, const core::Pose2& map_from_session,
                               const core::Pose2& map_from_last_keyframe, const ros::Time& keyframe_stamp) {
  const core::Pose2 base = vehicle(map_from_last_keyframe);  // (takes the lock itself)
  {
    std::lock_guard<std::mutex> lock(mutex_);
    active_ = session;
    map_from_session_ = core::zUp(map_from_session);
    if (options_.publish_tf && !options_.publish_odom_tf) keyframe_ = std::make_pair(base, keyframe_stamp);
  }
  if (options_.publish_tf) tick();  // a new correction (a join, an optimisation) goes out now, not at the next tick
}

namespace {
geometry_msgs::TransformStamped toTransformMsg(const Eigen::Isometry3d& t, const std::string& parent,
                                               const std::string& child) {
  geometry_msgs::TransformStamped m;
  m.header.stamp = ros::Time::now();
  m.header.frame_id = parent;
  m.child_frame_id = child;
  const Eigen::Vector3d p = t.translation();
  const Eigen::Quaterniond q(t.linear());
  m.transform.translation.x = p.x();
  m.transform.translation.y = p.y();
  m.transform.translation.z = p.z();
  m.transform.rotation.x = q.x();
  m.transform.rotation.y = q.y();
  m.transform.rotation.z = q.z();
  m.transform.rotation.w = q.w();
  return m;
}
}  // namespace

std::vector<std::string> FramePublisher::noDatum() const {
  return {"datum: none (~datum/latitude_deg and longitude_deg unset, none in the store): no " + options_.earth_frame +
          " frame, no UTM frame, " + topics::kKeyframeFix + " not advertised until set_datum"};
}

std::optional<core::GeoOrigin> FramePublisher::datum() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return datum_;
}

core::MapFrame FramePublisher::mapFrame() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return map_frame_;
}

geometry_msgs::TransformStamped FramePublisher::sessionFrame(int id, const core::Pose2& map_from_session) const {
  return rc::toTransformStampedMsg(map_frame_.toPublished(core::zUp(map_from_session)), options_.map_frame,
                                   options_.session_frame_prefix + std::to_string(id), ros::Time::now());
}

std::vector<std::string> FramePublisher::setDatum(const core::GeoOrigin& d) {
  // The published map is ENU at the datum (core::MapFrame): earth -> map and map -> utm are those
  // of a datum whose x axis points east, whatever the first keyframe's heading.
  core::GeoOrigin enu = d;
  enu.heading_deg = core::kEnuHeadingDeg;
  // Everything that can throw first: a refused datum changes nothing.
  const std::optional<core::UtmDatum> utm =
      options_.utm_frame.empty() ? std::nullopt : std::optional<core::UtmDatum>(core::utmFromMap(enu));
  const core::MapFrame turned = core::MapFrame::enuAtHeading(d.heading_deg);
  std::vector<std::string> lines{"datum: " + core::describeDatum(d) + "; " + options_.map_frame +
                                 " is ENU there (x east, y north, z up); " + topics::kKeyframeFix + " published"};
  std::vector<geometry_msgs::TransformStamped> t;
  // Held to the end, before mutex_ (as setSessionFrames): a session frame built in the old axes
  // cannot go out after the new ones.
  std::lock_guard<std::mutex> statics(static_mutex_);
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (!fix_pub_) fix_pub_ = nh_.advertise<sensor_msgs::NavSatFix>(topics::kKeyframeFix, 10);
    datum_ = d;
    const bool moved = turned.theta() != map_frame_.theta();
    map_frame_ = turned;
    // map -> session_<id> as they are published now: re-expressed in the new axes.
    if (moved && options_.publish_tf && options_.publish_session_frames)
      for (const auto& [id, p] : session_frames_) t.push_back(sessionFrame(id, p));
  }
  if (options_.publish_tf) tick();  // map -> odom in the new axes now, not at the next tick
  if (!options_.publish_tf) {
    lines.push_back("datum: publish_tf is false, no " + options_.earth_frame + " -> " + options_.map_frame +
                    (utm ? " nor " + options_.map_frame + " -> " + options_.utm_frame : std::string()));
    return lines;
  }
  t.push_back(toTransformMsg(core::earthFromMap(enu), options_.earth_frame, options_.map_frame));
  lines.push_back("datum: static " + options_.earth_frame + " -> " + options_.map_frame + " (ECEF, " +
                  options_.map_frame + " ENU)");
  if (utm) {
    t.push_back(toTransformMsg(utm->utm_from_map.inverse(), options_.map_frame, options_.utm_frame));
    char line[240];
    std::snprintf(line, sizeof line,
                  "datum: static %s -> %s, UTM zone %s (WGS84), origin at easting %.3f m, northing %.3f m, grid "
                  "convergence %.4f deg, scale %.6f (left out)",
                  options_.map_frame.c_str(), options_.utm_frame.c_str(), utm->zoneName().c_str(),
                  utm->utm_from_map.translation().x(), utm->utm_from_map.translation().y(), utm->convergence_deg,
                  utm->scale);
    lines.push_back(line);
  }
  static_tf_.sendTransform(t);  // replaces the last ones (by child frame)
  return lines;
}

void FramePublisher::publishFix(const core::UncertainPose2& vehicle_in_core_map, const ros::Time& stamp) {
  std::optional<core::GeoOrigin> d;
  ros::Publisher pub;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    d = datum_;
    pub = fix_pub_;
  }
  if (!d) return;
  const core::GeoFix f = core::fixFromMap(*d, vehicle_in_core_map);  // the datum's heading: the core map's x axis
  sensor_msgs::NavSatFix m;
  m.header.stamp = stamp;
  m.header.frame_id = options_.base_frame;  // NavSatFix: where on the vehicle the position is (here base_link)
  // A SLAM estimate, no satellite service; STATUS_FIX: a position without augmentation.
  m.status.status = sensor_msgs::NavSatStatus::STATUS_FIX;
  m.status.service = 0;
  m.latitude = f.lat_deg;
  m.longitude = f.lon_deg;
  m.altitude = f.alt_m;
  for (std::size_t i = 0; i < m.position_covariance.size(); ++i) m.position_covariance[i] = f.enu_covariance[i];
  m.position_covariance_type = sensor_msgs::NavSatFix::COVARIANCE_TYPE_KNOWN;
  pub.publish(m);
}

void FramePublisher::setSessionFrames(const std::map<int, core::Pose2>& map_from_session) {
  if (!options_.publish_tf || !options_.publish_session_frames) return;
  std::vector<geometry_msgs::TransformStamped> changed;
  std::lock_guard<std::mutex> statics(static_mutex_);  // before mutex_: in order with setDatum's
  {
    std::lock_guard<std::mutex> lock(mutex_);
    for (const auto& [id, p] : map_from_session) {
      const auto it = session_frames_.find(id);
      if (it != session_frames_.end() && same(it->second, p)) continue;
      session_frames_[id] = p;
      changed.push_back(sessionFrame(id, p));
    }
  }
  if (changed.empty()) return;
  static_tf_.sendTransform(changed);  // the broadcaster replaces them by child frame
}

std::optional<core::Pose2> FramePublisher::onOdometry(int session, const core::UncertainPose2& pose,
                                                      const ros::Time& stamp) {
  std::optional<core::Pose2> in_map;
  core::Pose2 in_odom;
  nav_msgs::Odometry odom;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (session < 0) session = active_;  // a pose in a frame not named after a session
    in_odom = chain_.toOdom(session, pose.mean);
    if (map_from_session_ && session == active_) {
      in_map = core::compose(*map_from_session_, pose.mean);
    } else if (options_.publish_odom_tf && map_from_odom_) {
      in_map = core::compose(*map_from_odom_, in_odom);  // a session the back-end has not seen yet
    }
    if (in_map) in_map = map_frame_.toPublished(*in_map);
    if (options_.publish_odom_tf) {
      // odom <- base = (odom <- session, exact) (+) (session <- base): the covariance turns with the placement.
      const core::UncertainPose2 u = core::compose(core::UncertainPose2::exact(*chain_.offset(session)), pose);
      const bool later = last_odom_ && stamp > last_odom_->second;
      odom =
          rc::toOdometryMsg(u, later ? &last_odom_->first : nullptr, later ? (stamp - last_odom_->second).toSec() : 0.0,
                            options_.odom_frame, options_.base_frame, stamp);
      last_odom_ = std::make_pair(in_odom, stamp);
    }
  }
  if (options_.publish_tf && options_.publish_odom_tf)
    tf_.sendTransform(rc::toTransformStampedMsg(in_odom, options_.odom_frame, options_.base_frame, stamp));
  if (options_.publish_odom_tf) odom_pub_.publish(odom);
  return in_map;
}

void FramePublisher::tick() {
  std::lock_guard<std::mutex> in_order(tick_order_);  // stamps go out in the order they are taken
  geometry_msgs::TransformStamped t;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const ros::SteadyTime wall = ros::SteadyTime::now();
    if ((wall - window_start_).toSec() >= 1.0) {
      stats_.map_to_odom_rate_hz =
          (stats_.map_to_odom_published - published_at_window_) / (wall - window_start_).toSec();
      published_at_window_ = stats_.map_to_odom_published;
      window_start_ = wall;
    }
    const ros::Time now = ros::Time::now();
    if (now.isZero()) return;  // simulated time not started yet
    if (options_.publish_odom_tf) {
      const std::optional<core::Pose2> offset = chain_.offset(active_);
      if (map_from_session_ && offset) map_from_odom_ = core::mapFromOdom(*map_from_session_, *offset);
    } else if (keyframe_) {
      const auto& [map_from_base, at] = *keyframe_;
      core::Pose2 odom_from_base;
      if (buffer_->canTransform(options_.odom_frame, options_.base_frame, at) &&
          rc::fromMsg(buffer_->lookupTransform(options_.odom_frame, options_.base_frame, at).transform,
                      &odom_from_base)) {
        map_from_odom_ = core::mapFromOdom(map_from_base, odom_from_base);
        keyframe_.reset();
      } else if (now - at > ros::Duration(5.0)) {  // tf will not have it any more: keep the last correction
        ++stats_.odom_lookup_failures;
        ROS_WARN_THROTTLE(5, "frames: no %s -> %s at the keyframe stamp %.3f: map -> %s not updated",
                          options_.odom_frame.c_str(), options_.base_frame.c_str(), at.toSec(),
                          options_.odom_frame.c_str());
        keyframe_.reset();
      }
    }
    if (!map_from_odom_) return;
    const core::Pose2 published = map_frame_.toPublished(*map_from_odom_);
    ros::Time stamp = now + ros::Duration(options_.tf_future_s);
    if (stamp <= last_stamp_) {
      // The clock stands still (a paused or finished bag): tf2 would drop a repeated stamp, so
      // nothing is sent, unless the correction changed (a join): then 1 us after the last one, so
      // that listeners asking for the latest transform see it.
      if (sent_ && same(*sent_, published)) return;
      stamp = last_stamp_ + ros::Duration(0, 1000);
    }
    last_stamp_ = stamp;
    sent_ = published;
    t = rc::toTransformStampedMsg(published, options_.map_frame, options_.odom_frame, stamp);
    ++stats_.map_to_odom_published;
  }
  tf_.sendTransform(t);
}

FrameStats FramePublisher::stats() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return stats_;
}

}  // namespace ros_frames
}  // namespace uw_multislam
