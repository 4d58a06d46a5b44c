#include "uw_multislam/ros/odometry_options.h"

#include <boost/make_shared.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iomanip>
#include <sstream>
#include <stdexcept>

#include "uw_multislam/core/common/work_queue.h"
#include "uw_multislam/core/frontend/enhancement.h"
#include "uw_multislam/core/session/session_manager.h"
#include "uw_multislam/ros/camera_mount.h"
#include "uw_multislam/ros/frame_publisher.h"
#include "uw_multislam/ros/sensor_conversions.h"
#include "uw_multislam/ros/slam_params.h"

namespace uw_multislam {
namespace ros_params {

namespace rc = ros_conversions;

std::size_t OdometryNodeletOptions::workerQueueSize() const {
  const auto depth = static_cast<std::size_t>(queue_size);
  return drop_policy == "newest" ? core::newestCapacity(depth) : depth;
}

int OdometryNodeletOptions::inputQueueSize() const {
  return std::max(sync_queue_size, static_cast<int>(core::newestCapacity(static_cast<std::size_t>(queue_size))));
}

core::InputPairingOptions OdometryNodeletOptions::pairing() const {
  core::InputPairingOptions p;
  p.sync_max_interval_s = sync_max_interval_s;
  p.altitude_max_age_s = altitude_max_age_s;
  p.reorder_tolerance_s = reorder_tolerance_s;
  p.max_waiting = 2 * static_cast<std::size_t>(inputQueueSize());
  p.altitude_topic = use_altitude_topic;
  p.fixed_altitude_m = altitude_m;
  p.input_timeout_s = input_timeout_s;
  p.fallback_altitude_m = fallback_altitude_m;
  return p;
}

ros_inputs::NavInputOptions OdometryNodeletOptions::nav() const {
  ros_inputs::NavInputOptions n;
  n.source = nav_source;
  n.wait_s = nav_wait_s;
  n.buffer_s = nav_buffer_s;
  n.reorder_tolerance_s = reorder_tolerance_s;
  n.tf_wait_s = nav_tf_wait_s;
  n.tf_drift = nav_tf_drift;
  n.tf_yaw_drift = nav_tf_yaw_drift;
  n.odom_frame = odom_frame;
  n.base_frame = base_frame;
  return n;
}

OdometryNodeletOptions odometryNodeletOptions(const ros::NodeHandle& nh, const ros::NodeHandle& pnh) {
  warnAboutFormerPrivateNamespace(pnh);
  return odometryNodeletOptions(Params(nh), Params(pnh));
}

OdometryNodeletOptions odometryNodeletOptions(const Params& nh, const Params& pnh) {
  OdometryNodeletOptions o;
  auto positive = [](double v) { return v > 0; };
  auto in_0_1 = [](double v) { return v >= 0 && v <= 1; };
  auto in_0_1_open = [](double v) { return v > 0 && v <= 1; };
  param(pnh, "image_transport", &o.image_transport);
  param(pnh, "use_altitude_topic", &o.use_altitude_topic);
  param(pnh, "altitude", &o.altitude_m);
  if (!o.use_altitude_topic && !(o.altitude_m > 0)) {
    throw std::invalid_argument(pnh.resolve("altitude") + " = " + shownMember(o.altitude_m) +
                                ": must be a positive altitude in metres when use_altitude_topic is false");
  }
  param(
      pnh, "queue_size", &o.queue_size, [](int v) { return v >= 1 && v <= 10000; }, "in [1, 10000]");
  param(
      pnh, "drop_policy", &o.drop_policy, [](const std::string& s) { return s == "newest" || s == "oldest"; },
      "newest (bounded latency: the newest frame that is safe to take, the ones before it skipped and counted) or "
      "oldest (every frame in order; the oldest dropped when the queue is full)");
  param(
      pnh, "prepare_threads", &o.prepare_threads, [](int v) { return v >= 0 && v <= 8; }, "in [0, 8]");
  param(pnh, "stale_fraction", &o.stale_fraction, in_0_1_open, "in (0, 1]");
  param(pnh, "keyframe_lookahead", &o.keyframe_lookahead);
  o.keyframe_lookahead = o.keyframe_lookahead && o.drop_policy == "newest";
  param(
      pnh, "sync_queue_size", &o.sync_queue_size, [](int v) { return v >= 1 && v <= 1000; }, "in [1, 1000]");
  param(pnh, "sync_max_interval_s", &o.sync_max_interval_s, positive, "positive");
  param(
      pnh, "altitude_max_age_s", &o.altitude_max_age_s, [](double v) { return v > 0 && v <= 60; },
      "in (0, 60] seconds");
  param(
      pnh, "session", &o.session, [](int v) { return v >= 0 && v <= core::kMaxSessionId; },
      "in [0, " + std::to_string(core::kMaxSessionId) + "]");
  param(
      pnh, "session_gap_s", &o.session_gap_s, [](double v) { return v >= 0; }, ">= 0 (0 = off)");
  param(
      pnh, "session_gap_periods", &o.session_gap_periods, [](double v) { return v >= 1; }, ">= 1");
  param(pnh, "stats_period_s", &o.stats_period_s, positive, "positive");
  param(
      pnh, "reorder_tolerance_s", &o.reorder_tolerance_s, [](double v) { return v >= 0; }, ">= 0");
  param(pnh, "input_timeout_s", &o.input_timeout_s, positive, "positive");
  param(
      pnh, "fallback_altitude", &o.fallback_altitude_m, [](double v) { return v >= 0; }, ">= 0 metres (0 = off)");
  param(pnh, "diagnostic_period", &o.diagnostic_period_s, positive, "positive");
  param(
      pnh, "max_image_pixels", &o.max_image_pixels,
      [](int v) { return v >= static_cast<int>(rc::kMinImageSide * rc::kMinImageSide) && v <= 1000000000; },
      "in [1024, 1000000000] pixels");
  param(pnh, "rectified_images", &o.rectified_images);
  param(
      pnh, "nav_source", &o.nav_source, [](const std::string& s) { return s == "topic" || s == "tf" || s == "none"; },
      "topic (nav/odom, nav_msgs/Odometry), tf (odom -> base_link) or none");
  param(pnh, "nav_tf_wait_s", &o.nav_tf_wait_s, in_0_1, "in [0, 1] s");
  param(pnh, "nav_wait_s", &o.nav_wait_s, in_0_1, "in [0, 1] s");
  param(pnh, "nav_tf_drift", &o.nav_tf_drift, in_0_1_open, "in (0, 1]");
  param(pnh, "nav_tf_yaw_drift", &o.nav_tf_yaw_drift, in_0_1_open, "in (0, 1] rad per metre");
  ros_frames::FrameOptions backend;  // the back-end's frames/ and ~publish_odom_tf, from the same defaults
  readFrames(nh, &backend);
  param(nh, "backend_node/publish_odom_tf", &backend.publish_odom_tf);
  if (o.nav_source == "tf" && backend.publish_odom_tf)
    throw std::invalid_argument(pnh.resolve("nav_source") +
                                ": tf needs the vehicle's own odom -> base_link, but the back-end publishes it from "
                                "the visual odometry (set backend_node/publish_odom_tf false)");
  o.odom_frame = backend.odom_frame;
  o.base_frame = backend.base_frame;
  o.session_frame_prefix = backend.session_frame_prefix;
  o.mount_wait_s = backend.mount.wait_s;
  o.max_camera_tilt_deg = backend.mount.max_tilt_deg;
  param(
      pnh, "nav_buffer_s", &o.nav_buffer_s, [](double v) { return v >= 1 && v <= 3600; }, "in [1, 3600] seconds");
  param(pnh, "nav_world_fixed", &o.nav_world_fixed);
  param(pnh, "camera_info_url", &o.camera_info_url);
  if (!o.camera_info_url.empty()) {
    auto info = boost::make_shared<sensor_msgs::CameraInfo>();
    core::CameraIntrinsics camera;
    std::string why;
    if (!rc::cameraInfoFromUrl(o.camera_info_url, info.get(), &why) ||
        !rc::cameraFromMsg(*info, o.rectified_images, &camera, &why)) {
      throw std::invalid_argument(pnh.resolve("camera_info_url") + ": " + why);
    }
    o.fallback_camera_info = info;
  }
  o.config = slamConfigFromParams(nh);
  const std::string bad = o.config.validate();
  if (!bad.empty()) throw std::invalid_argument(nh.resolve("slam") + ": " + bad);
  // The fixed altitudes are bounded like the readings (every frame would be skipped at one above).
  const double max_alt = o.config.odometry.max_altitude_m;
  if (!o.use_altitude_topic && o.altitude_m > max_alt)
    throw std::invalid_argument(pnh.resolve("altitude") + " = " + shownMember(o.altitude_m) +
                                ": above slam/odometry/max_altitude_m (" + shownMember(max_alt) + ")");
  if (o.fallback_altitude_m > max_alt)
    throw std::invalid_argument(pnh.resolve("fallback_altitude") + " = " + shownMember(o.fallback_altitude_m) +
                                ": above slam/odometry/max_altitude_m (" + shownMember(max_alt) + ")");
  return o;
}

std::vector<std::string> describe(const OdometryNodeletOptions& o) {
  const core::SlamConfig& c = o.config;
  char line[1024];
  std::snprintf(
      line, sizeof(line),
      "altitude from %s (interpolated at the image stamp, altitude_max_age_s %.2f), queue_size %d, drop_policy %s "
      "(%s), prepare_threads %d (%s), stale_fraction %.2f, keyframe_lookahead %s, max_image_pixels %d, sync_queue_size "
      "%d, sync_max_interval_s %.3f, first "
      "session %d, session_gap_s %.1f (and %.3g frame periods), reorder_tolerance_s %.2f, input_timeout_s %.1f, "
      "fallback_altitude %s, stats "
      "every %.0f s, diagnostics every %.1f s; n = %d features, enhancement %s, keyframes at overlap < %.2f",
      o.use_altitude_topic ? "the altitude topic"
                           : ("the fixed altitude " + std::to_string(o.altitude_m) + " m").c_str(),
      o.altitude_max_age_s, o.queue_size, o.drop_policy.c_str(),
      o.drop_policy == "newest" ? "when behind, the newest frame that is safe to take; 20 x queue_size may wait, "
                                  "the oldest dropped beyond"
                                : "every frame in order; the oldest dropped when full",
      o.prepare_threads,
      o.prepare_threads == 0      ? "each frame prepared by the worker"
      : o.drop_policy == "newest" ? "the newest frame prepared as it arrives"
                                  : "the frames waiting prepared in order",
      o.stale_fraction, o.keyframe_lookahead ? "on" : "off", o.max_image_pixels, o.sync_queue_size,
      o.sync_max_interval_s, o.session, o.session_gap_s, o.session_gap_periods, o.reorder_tolerance_s,
      o.input_timeout_s, o.fallback_altitude_m > 0 ? (std::to_string(o.fallback_altitude_m) + " m").c_str() : "off",
      o.stats_period_s, o.diagnostic_period_s, c.odometry.features.num_features,
      core::enhancementName(c.odometry.enhancement.mode).c_str(), c.odometry.keyframes.min_overlap);
  std::ostringstream os;
  os << "sensor mount from tf: " << o.base_frame << " -> each image's header.frame_id and each altitude reading's "
     << "(waiting up to frames/mount_wait_s " << o.mount_wait_s << " s at the first frame; none: frames are refused); ";
  os << "camera from camera_info, " << (o.rectified_images ? "rectified images (P)" : "raw images (K, D)")
     << (o.camera_info_url.empty() ? "" : "; while none arrives, from ~camera_info_url ") << o.camera_info_url;
  if (o.nav_world_fixed && o.nav_source != "none" && c.odometry.nav.enabled)
    os << "; the nav's frame is world-fixed (~nav_world_fixed): each new session is placed by the nav against the "
       << "last keyframe with a nav reading before it";
  return {line, os.str()};
}

std::string silenceMessage(const core::InputSilence& q, const OdometryNodeletOptions& o, const InputTopics& topics) {
  using K = core::InputSilence::Kind;
  if (q.kind == K::kNone) return "";
  std::ostringstream os;
  os << std::fixed << std::setprecision(0);
  if (q.kind == K::kNoImage) {
    os << "no image on " << topics.image << " (transport '" << topics.transport << "') "
       << (q.image_ever ? "for " : "in the ") << q.for_s << (q.image_ever ? " s" : " s since start") << ", while "
       << (q.camera_info_arrives ? "camera_info arrives" : "no camera_info arrives either") << " and "
       << (q.altitude_arrives ? "altitude arrives" : "no altitude arrives either")
       << ": check the topic name (rostopic list; launch argument image:=) and the transport";
    return os.str();
  }
  os << "images arrive on " << topics.image << " but none was paired for " << q.for_s << " s: ";
  if (q.kind == K::kNoCameraInfo) {
    os << "no camera_info on " << topics.camera_info;
  } else if (q.kind == K::kNoAltitude) {
    os << "no altitude on " << topics.altitude
       << " (set ~fallback_altitude to fly on a fixed altitude, or ~use_altitude_topic false)";
  } else {
    os << "their stamps are further apart than ~sync_max_interval_s " << o.sync_max_interval_s
       << " s (camera_info) or ~altitude_max_age_s " << o.altitude_max_age_s << " s (altitude)";
  }
  return os.str();
}

}  // namespace ros_params
}  // namespace uw_multislam
