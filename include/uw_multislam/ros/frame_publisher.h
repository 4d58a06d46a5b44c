// The back-end's tf: map -> odom -> base_link (REP-105), and the per-session frames
// map -> session_<id> (doc/frames.md). Thread-safe: the worker reports corrections, the
// odometry/pose callback reports poses, a steady timer publishes map -> odom; none of them waits
// for the others longer than a copy under this class's own mutex.
//
//  - odom -> base_link: with publish_odom_tf (visual odometry, the default) from every
//    odometry/pose, stamped with it, through core::OdomChain (one continuous odom frame over the
//    sessions). Without it the vehicle's nav stack publishes odom -> base_link, and this class
//    reads it from tf.
//  - map -> odom: published at tf_rate_hz, stamped now + tf_future_s (fresh stamps, each later
//    than the last: tf2 drops a repeated stamp, and listeners can look base_link up in map at any
//    time up to now), and at once when the worker reports a new correction (a join reaches
//    listeners without waiting for the next tick). Visual odometry: from the active session's correction and its place
//    in odom. Vehicle odometry: from the active session's last keyframe, map <- base at its stamp t, and the vehicle's
//    odom <- base at t looked up in tf (retried on each tick until tf has it; failures counted).
//  - map -> session_<id>: static transforms (latched; they change only when a map is optimised,
//    joined or split), sent again when a correction changes.
//  - the camera's mount is not published here: tf gives base_link -> the camera's frame (the
//    vehicle's URDF, or the launch files' scripts/mount_publisher.py). This class looks it up for
//    the frame the keyframes name in their header (the image's frame_id), when the first keyframe
//    comes (the odometry sends none before it has found the same transform); until then poses are
//    drawn with the camera at base_link, with a WARN.
// The class takes the core's poses (the camera's, image axes) where it says so and publishes
// REP-103 ones (z-up, base_link: core/geometry/vehicle_frame.h); odometry/pose comes in as the
// vehicle's already (the odometry nodelet converts it). It keeps every map pose in the core's map
// (z-up) and turns it into the published `map` when it sends it (mapFrame(): ENU at the datum,
// core/geometry/map_frame.h), so a new datum re-expresses what goes out next.
#pragma once

#include <ros/ros.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/static_transform_broadcaster.h>
#include <tf2_ros/transform_broadcaster.h>
#include <tf2_ros/transform_listener.h>

#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "uw_multislam/core/export/survey_export.h"
#include "uw_multislam/core/geometry/map_frame.h"
#include "uw_multislam/core/session/odom_chain.h"
#include "uw_multislam/ros/camera_mount.h"
#include "uw_multislam/ros/topics.h"

namespace uw_multislam {
namespace ros_frames {

struct FrameOptions {
  std::string map_frame = frames::kDefaultMapFrame, odom_frame = frames::kDefaultOdomFrame,
              base_frame = frames::kDefaultBaseFrame;
  std::string session_frame_prefix = topics::kDefaultSessionFramePrefix;
  bool publish_tf = true;              // false: no tf at all (the pose is still computed)
  bool publish_odom_tf = true;         // false: the vehicle publishes odom -> base_link
  bool publish_session_frames = true;  // map -> session_<id>
  double tf_rate_hz = 20.0;            // map -> odom
  double tf_future_s = 0.0;            // its stamp: now + this
  MountOptions mount;                  // frames/ camera and altimeter on the vehicle
  /// ~datum/*: map's origin on WGS84 and the heading of its x axis; set: a static earth_frame ->
  /// map_frame, map_frame -> utm_frame when that is not empty (setDatum), and keyframe_fix. The
  /// datum in use is setDatum's (ros/datum_service.h decides it: the store's wins over this).
  std::optional<core::GeoOrigin> datum;
  std::string earth_frame = frames::kDefaultEarthFrame;
  std::string utm_frame;  // empty: no UTM frame
};

struct FrameStats {
  long map_to_odom_published = 0;
  long odom_lookup_failures = 0;     // the vehicle's odom -> base_link missing at a keyframe's stamp
  double map_to_odom_rate_hz = 0.0;  // measured over the last second or so
};

class FramePublisher {
 public:
  /// Listens to the keyframes' camera frame and tf for the mount, and starts the timer on `nh`
  /// (steady: it runs while a bag is paused, and publishes nothing new then). Rates and frames are
  /// checked by ros_params::backendNodeletOptions.
  FramePublisher(ros::NodeHandle nh, const FrameOptions& options);
  ~FramePublisher();  // stops the timer before anything it reads goes
  FramePublisher(const FramePublisher&) = delete;
  FramePublisher& operator=(const FramePublisher&) = delete;

  /// From the worker after each publication of the active session: its correction map <- session,
  /// and its last keyframe's pose in the map with its stamp (the core's).
  void setActive(int session, const core::Pose2& map_from_session, const core::Pose2& map_from_last_keyframe,
                 const ros::Time& keyframe_stamp);
  /// The datum in use from now on: `map` becomes ENU at it (mapFrame()), the static earth_frame ->
  /// map_frame (REP-105's earth: ECEF; core::earthFromMap of the datum with its x axis east, so no
  /// heading turn) and, with a utm_frame, map_frame -> utm_frame (core::utmFromMap inverted, the
  /// grid convergence its only turn: utm is map's child, as navsat_transform sends it by default,
  /// because map's one parent in tf is earth), sent again in place of the last ones, with map ->
  /// session_<id> and map -> odom in the new axes; keyframe_fix advertised at the first datum.
  /// Thread-safe. Returns the lines that say what was published, for the node's log. Throws
  /// std::invalid_argument for a utm_frame with a polar datum, with nothing changed.
  std::vector<std::string> setDatum(const core::GeoOrigin& datum);
  /// The datum in use (nullopt: none yet).
  std::optional<core::GeoOrigin> datum() const;
  /// The published `map` from the core's z-up map: ENU at the datum in use, identity without one.
  /// Every pose published in map_frame goes through it (here and in SessionPublisher).
  core::MapFrame mapFrame() const;
  /// What is published without a datum, for the node's log.
  std::vector<std::string> noDatum() const;
  /// With a datum: keyframe_fix, the geographic position of keyframe_pose at its stamp, from the
  /// vehicle's pose in the core's z-up map (before mapFrame(): core::fixFromMap with the datum's
  /// heading). Without one: nothing (not advertised).
  void publishFix(const core::UncertainPose2& vehicle_in_core_map, const ros::Time& stamp);
  /// map -> session_<id> for these sessions (the core's corrections); those that changed are sent, in one message.
  void setSessionFrames(const std::map<int, core::Pose2>& map_from_session);
  /// An odometry pose (the vehicle's, in the session's z-up frame, with its covariance): with
  /// publish_odom_tf, odom -> base_link and the odom topic (nav_msgs/Odometry: the pose in odom,
  /// its covariance carried through the session's placement; the twist from the last pose).
  /// Returns the vehicle's pose in the published map (the active session's correction applied,
  /// then mapFrame()) or nullopt before any correction.
  std::optional<core::Pose2> onOdometry(int session, const core::UncertainPose2& pose, const ros::Time& stamp);
  /// The vehicle's pose (z-up, base_link) from a core pose of the camera.
  core::Pose2 vehicle(const core::Pose2& camera) const { return core::vehicleFromCamera(camera, mount()); }
  core::UncertainPose2 vehicle(const core::UncertainPose2& camera) const {
    return core::vehicleFromCamera(camera, mount());
  }
  /// base_link -> the keyframes' camera frame from tf; the camera at base_link until it is known.
  core::CameraMount mount() const;
  /// Where `frame`'s origin is in base_link's plane (x forward, y left: tf's static base_frame ->
  /// frame), e.g. a GPS antenna's or a USBL transponder's lever arm; nullopt, with `why`, when tf
  /// has no static transform there or it is farther than kMaxLeverArmM. Thread-safe.
  std::optional<Eigen::Vector2d> inBasePlane(const std::string& frame, std::string* why) const;
  static constexpr double kMaxLeverArmM = 20.0;  // beyond any AUV's length: not a sensor on it
  FrameStats stats() const;

 private:
  void tick();
  /// map -> session_<id> as published (mutex_ held).
  geometry_msgs::TransformStamped sessionFrame(int id, const core::Pose2& map_from_session) const;
  void onCameraFrame(const std::string& frame);  // a keyframe's header.frame_id

  FrameOptions options_;
  ros::NodeHandle nh_;                             // keyframe_fix is advertised on it at the first datum
  std::unique_ptr<tf2_ros::Buffer> mount_buffer_;  // thread-safe
  std::unique_ptr<tf2_ros::TransformListener> mount_listener_;
  ros::Subscriber camera_frame_sub_;
  ros::SteadyTimer timer_;
  tf2_ros::TransformBroadcaster tf_;
  std::mutex static_mutex_;  // the static broadcaster is not thread-safe: setDatum and setSessionFrames share it
  tf2_ros::StaticTransformBroadcaster static_tf_;
  ros::Publisher odom_pub_;                  // topics::kOdometry, with publish_odom_tf
  std::unique_ptr<tf2_ros::Buffer> buffer_;  // vehicle odometry only
  std::unique_ptr<tf2_ros::TransformListener> listener_;

  // tick() runs on the timer and on setActive's caller: its stamp is taken under mutex_ and the
  // transform sent after it, so two ticks could send their stamps out of order (rostest frames
  // saw one map -> odom stamp older than the one before). tick_order_ holds across both.
  std::mutex tick_order_;
  mutable std::mutex mutex_;  // guards everything below
  core::OdomChain chain_;
  int active_ = -1;
  core::CameraMount mount_;                                    // from tf, once found
  std::string camera_frame_, mount_for_;                       // the keyframes' camera frame; mount_'s
  std::optional<core::Pose2> map_from_session_;                // of the active session
  std::optional<std::pair<core::Pose2, ros::Time>> keyframe_;  // vehicle odometry: waiting for its lookup
  // Map poses here are the core map's (z-up), turned by map_frame_ when sent.
  std::optional<core::Pose2> map_from_odom_;
  std::optional<core::Pose2> sent_;                             // map_from_odom_ as last published (turned)
  std::optional<std::pair<core::Pose2, ros::Time>> last_odom_;  // for the twist
  ros::Time last_stamp_;
  std::map<int, core::Pose2> session_frames_;
  std::optional<core::GeoOrigin> datum_;  // in use
  core::MapFrame map_frame_;              // published map <- core map (z-up), from datum_
  ros::Publisher fix_pub_;                // topics::kKeyframeFix, from the first datum on
  FrameStats stats_;
  long published_at_window_ = 0;  // the rate's window: publications and start
  ros::SteadyTime window_start_;
};

}  // namespace ros_frames
}  // namespace uw_multislam
