// uw_multislam/Odometry: the nodelet's definitions; topics, sessions, bad input and threading
// are documented with the class in include/uw_multislam/ros/nodelets/odometry_nodelet.h.
#include "uw_multislam/ros/nodelets/odometry_nodelet.h"

#include <cv_bridge/cv_bridge.h>
#include <geometry_msgs/PoseWithCovarianceStamped.h>
#include <boost/asio/post.hpp>
#include <boost/asio/thread_pool.hpp>
#include <boost/bind/bind.hpp>

#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>
#include <pluginlib/class_list_macros.hpp>

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <limits>
#include <sstream>
#include <string>
#include <vector>

#include "uw_multislam/Keyframe.h"
#include "uw_multislam/core/session/keyframe_image.h"
#include "uw_multislam/core/session/session_manager.h"
#include "uw_multislam/ros/camera_mount.h"
#include "uw_multislam/ros/conversions.h"
#include "uw_multislam/ros/pipeline_conversions.h"
#include "uw_multislam/ros/sensor_conversions.h"
#include "uw_multislam/ros/slam_params.h"
#include "uw_multislam/ros/topics.h"

namespace uw_multislam {
namespace nodelets {

namespace rc = ros_conversions;

OdometryNodelet::~OdometryNodelet() {
  watchdog_.stop();
  pairing_timer_.stop();
  image_sub_.shutdown();
  compressed_sub_.shutdown();
  info_sub_.shutdown();
  range_sub_.shutdown();
  if (queue_) queue_->close();  // later frames are refused; the queued ones are still processed
  if (worker_.joinable()) worker_.join();
  if (prepare_pool_) prepare_pool_->join();  // idle: the worker waited for every frame it took
  if (odometry_) logStats("at shutdown");
}

void OdometryNodelet::readParameters() {
  ros::NodeHandle& pnh = getPrivateNodeHandle();
  ros_params::warnAboutFormerPrivateNamespace(pnh);
  using ros_params::param;
  options_.use_altitude_topic = param(
      pnh, "use_altitude_topic", true, [](bool) { return true; }, "a bool");
  options_.altitude_m = param(
      pnh, "altitude", 0.0, [](double) { return true; }, "");
  if (!options_.use_altitude_topic && !(std::isfinite(options_.altitude_m) && options_.altitude_m > 0)) {
    throw std::invalid_argument(pnh.resolveName("altitude") + " = " + std::to_string(options_.altitude_m) +
                                ": must be a positive altitude in metres when use_altitude_topic is false");
  }
  options_.queue_size = param(
      pnh, "queue_size", 5, [](int v) { return v >= 1 && v <= 10000; }, "in [1, 10000]");
  options_.prepare_threads = param(
      pnh, "prepare_threads", 0, [](int v) { return v >= 0 && v <= 8; }, "in [0, 8]");
  options_.sync_queue_size = param(
      pnh, "sync_queue_size", 10, [](int v) { return v >= 1 && v <= 1000; }, "in [1, 1000]");
  options_.sync_max_interval_s = param(
      pnh, "sync_max_interval_s", 0.1, [](double v) { return v > 0; }, "positive");
  options_.altitude_max_age_s = param(
      pnh, "altitude_max_age_s", 1.0, [](double v) { return std::isfinite(v) && v > 0 && v <= 60; },
      "in (0, 60] seconds");
  options_.session = param(
      pnh, "session", 0, [](int v) { return v >= 0 && v <= core::kMaxSessionId; },
      "in [0, " + std::to_string(core::kMaxSessionId) + "]");
  options_.session_gap_s = param(
      pnh, "session_gap_s", 10.0, [](double v) { return v >= 0; }, ">= 0 (0 = off)");
  options_.stats_period_s = param(
      pnh, "stats_period_s", 30.0, [](double v) { return v > 0; }, "positive");
  options_.reorder_tolerance_s = param(
      pnh, "reorder_tolerance_s", 1.0, [](double v) { return std::isfinite(v) && v >= 0; }, ">= 0");
  options_.input_timeout_s = param(
      pnh, "input_timeout_s", 5.0, [](double v) { return v > 0; }, "positive");
  options_.fallback_altitude_m = param(
      pnh, "fallback_altitude", 0.0, [](double v) { return std::isfinite(v) && v >= 0; }, ">= 0 metres (0 = off)");
  options_.diagnostic_period_s = param(
      pnh, "diagnostic_period", 1.0, [](double v) { return v > 0; }, "positive");
  options_.max_image_pixels = param(
      pnh, "max_image_pixels", static_cast<int>(rc::kDefaultMaxImagePixels),
      [](int v) { return v >= static_cast<int>(rc::kMinImageSide * rc::kMinImageSide) && v <= 1000000000; },
      "in [1024, 1000000000] pixels");
  options_.rectified_images = param(
      pnh, "rectified_images", false, [](bool) { return true; }, "a bool");
  options_.nav_source = param(
      pnh, "nav_source", std::string("topic"),
      [](const std::string& s) { return s == "topic" || s == "tf" || s == "none"; },
      "topic (nav/odom, nav_msgs/Odometry), tf (odom -> base_link) or none");
  options_.nav_tf_wait_s = param(
      pnh, "nav_tf_wait_s", 0.05, [](double v) { return std::isfinite(v) && v >= 0 && v <= 1; }, "in [0, 1] s");
  options_.nav_wait_s = param(
      pnh, "nav_wait_s", 0.05, [](double v) { return std::isfinite(v) && v >= 0 && v <= 1; }, "in [0, 1] s");
  options_.nav_tf_drift = param(
      pnh, "nav_tf_drift", 0.01, [](double v) { return std::isfinite(v) && v > 0 && v <= 1; }, "in (0, 1]");
  options_.nav_tf_yaw_drift = param(
      pnh, "nav_tf_yaw_drift", 0.001, [](double v) { return std::isfinite(v) && v > 0 && v <= 1; },
      "in (0, 1] rad per metre");
  if (options_.nav_source == "tf" && getNodeHandle().param("backend_node/publish_odom_tf", true))
    throw std::invalid_argument(pnh.resolveName("nav_source") +
                                ": tf needs the vehicle's own odom -> base_link, but the back-end publishes it from "
                                "the visual odometry (set backend_node/publish_odom_tf false)");
  odom_frame_ = getNodeHandle().param("frames/odom_frame", std::string("odom"));
  base_frame_ = getNodeHandle().param("frames/base_frame", std::string("base_link"));
  options_.nav_buffer_s = param(
      pnh, "nav_buffer_s", 60.0, [](double v) { return std::isfinite(v) && v >= 1 && v <= 3600; },
      "in [1, 3600] seconds");
  options_.camera_info_url = param(
      pnh, "camera_info_url", std::string(), [](const std::string&) { return true; }, "");
  if (!options_.camera_info_url.empty()) {
    auto info = boost::make_shared<sensor_msgs::CameraInfo>();
    core::CameraIntrinsics camera;
    std::string why;
    if (!rc::cameraInfoFromUrl(options_.camera_info_url, info.get(), &why) ||
        !rc::cameraFromMsg(*info, options_.rectified_images, &camera, &why)) {
      throw std::invalid_argument(pnh.resolveName("camera_info_url") + ": " + why);
    }
    fallback_info_ = info;
  }
  options_.session_frame_prefix = ros_params::sessionFramePrefix(getNodeHandle());
  config_ = ros_params::slamConfigFromParams(getNodeHandle());
  const std::string bad = config_.validate();
  if (!bad.empty()) throw std::invalid_argument(getNodeHandle().resolveName("slam") + ": " + bad);
  // The fixed altitudes are bounded like the readings (every frame would be skipped at one above).
  const double max_alt = config_.odometry.max_altitude_m;
  if (!options_.use_altitude_topic && options_.altitude_m > max_alt)
    throw std::invalid_argument(pnh.resolveName("altitude") + " = " + std::to_string(options_.altitude_m) +
                                ": above slam/odometry/max_altitude_m (" + std::to_string(max_alt) + ")");
  if (options_.fallback_altitude_m > max_alt)
    throw std::invalid_argument(pnh.resolveName("fallback_altitude") + " = " +
                                std::to_string(options_.fallback_altitude_m) +
                                ": above slam/odometry/max_altitude_m (" + std::to_string(max_alt) + ")");
  std::string note;  // where the camera sits on the vehicle (frames/ parameters or tf)
  if (ros_frames::resolveCameraMount(getNodeHandle(), ros_frames::mountOptions(getNodeHandle()), &mount_, &note))
    NODELET_INFO("odometry: camera mount %s", note.c_str());
  else
    NODELET_WARN("odometry: %s", note.c_str());
}

void OdometryNodelet::onInit() {
  try {
    readParameters();
  } catch (const std::exception& e) {
    NODELET_FATAL("odometry: invalid parameters, not starting: %s", e.what());
    throw;
  }
  const auto& o = options_;
  NODELET_INFO(
      "odometry: altitude from %s (interpolated at the image stamp, altitude_max_age_s %.2f), queue_size %d "
      "(oldest dropped when full), prepare_threads %d, max_image_pixels %d, sync_queue_size %d, sync_max_interval_s %.3f, first session %d, session_gap_s %.1f, "
      "reorder_tolerance_s %.2f, "
      "input_timeout_s %.1f, fallback_altitude %s, stats every %.0f s, diagnostics every %.1f s; n = %d features, "
      "enhancement %s, keyframes at overlap < %.2f",
      o.use_altitude_topic ? "the altitude topic"
                           : ("the fixed altitude " + std::to_string(o.altitude_m) + " m").c_str(),
      o.altitude_max_age_s, o.queue_size, o.prepare_threads, o.max_image_pixels, o.sync_queue_size, o.sync_max_interval_s, o.session, o.session_gap_s,
      o.reorder_tolerance_s, o.input_timeout_s,
      o.fallback_altitude_m > 0 ? (std::to_string(o.fallback_altitude_m) + " m").c_str() : "off", o.stats_period_s,
      o.diagnostic_period_s, config_.odometry.features.num_features,
      core::enhancementName(config_.odometry.enhancement.mode).c_str(), config_.odometry.keyframes.min_overlap);
  NODELET_INFO("odometry: camera from camera_info, %s%s%s",
               o.rectified_images ? "rectified images (P)" : "raw images (K, D)",
               o.camera_info_url.empty() ? "" : "; while none arrives, from ~camera_info_url ",
               o.camera_info_url.c_str());
  NODELET_DEBUG_STREAM("odometry: effective SLAM configuration:\n" << core::slamConfigToYaml(config_));
  session_ = o.session;
  const auto& g = config_.loops.global;
  hasher_ = std::make_unique<core::ImageHasher>(g.hash_mode, config_.odometry.features.num_features, g.projection_seed);
  // A dropped frame's stamp travels on with the frame after it, which the worker passes over
  // first: the queue's own drops never look like a gap in the images (a new session).
  queue_ = std::make_unique<ros_work::BoundedWorkQueue<Frame>>(
      static_cast<std::size_t>(o.queue_size), [](Frame& dropped, Frame& next) {
        dropped.passed_over.push_back(dropped.header().stamp.toSec());
        next.passed_over.insert(next.passed_over.begin(), dropped.passed_over.begin(), dropped.passed_over.end());
      });
  stamps_ = std::make_unique<core::StampGuard>(core::StampGuardOptions{o.reorder_tolerance_s, o.session_gap_s});

  ros::NodeHandle& nh = getNodeHandle();
  keyframe_pub_ = nh.advertise<uw_multislam::Keyframe>(topics::kKeyframes, 50);
  pose_pub_ = nh.advertise<geometry_msgs::PoseWithCovarianceStamped>(topics::kOdometryPose, 10);
  it_ = std::make_unique<image_transport::ImageTransport>(nh);
  keyframe_image_pub_ = it_->advertise(topics::kKeyframeImage, 1);
  chooseImageTransport();

  updater_ = std::make_unique<diagnostic_updater::Updater>(nh, getPrivateNodeHandle(), getName());
  updater_->setHardwareID("none");
  updater_->add("odometry", this, &OdometryNodelet::fillDiagnostics);
  watchdog_ = nh.createWallTimer(ros::WallDuration(o.diagnostic_period_s), &OdometryNodelet::onWatchdog, this);

  if (o.prepare_threads > 0) prepare_pool_ = std::make_unique<boost::asio::thread_pool>(o.prepare_threads);
  worker_ = std::thread([this] { work(); });

  if (o.use_altitude_topic) {
    core::AltitudeBufferOptions ao;
    ao.max_age_s = o.altitude_max_age_s;
    ao.reorder_tolerance_s = o.reorder_tolerance_s;
    altitudes_ = std::make_unique<core::AltitudeBuffer>(ao);
  }
  // Images waiting past their bound are decided by this timer when no message comes.
  pairing_timer_ = nh.createWallTimer(ros::WallDuration(std::min(0.1, o.altitude_max_age_s / 4)),
                                      &OdometryNodelet::onPairingTimer, this);

  session_sub_ = nh.subscribe(topics::kActiveSession, 1, &OdometryNodelet::onActiveSession, this);
  pause_srv_ = nh.advertiseService(topics::kPauseService, &OdometryNodelet::onPause, this);
  resume_srv_ = nh.advertiseService(topics::kResumeService, &OdometryNodelet::onResume, this);
  if (builtin_decoder_) {
    compressed_sub_ = nh.subscribe(image_topic_, o.sync_queue_size, &OdometryNodelet::onCompressedImage, this);
  } else {
    const image_transport::TransportHints hints("raw", ros::TransportHints(), getPrivateNodeHandle());
    image_sub_ = it_->subscribe(topics::kImage, o.sync_queue_size, &OdometryNodelet::onImage, this, hints);
  }
  info_sub_ = nh.subscribe(topics::kCameraInfo, o.sync_queue_size, &OdometryNodelet::onCameraInfo, this);
  if (o.use_altitude_topic) {
    range_sub_ = nh.subscribe(topics::kAltitude, o.sync_queue_size, &OdometryNodelet::onRange, this);
  }
  if (o.nav_source == "tf") {
    tf_buffer_ = std::make_unique<tf2_ros::Buffer>(ros::Duration(std::max(10.0, o.nav_buffer_s)));
    tf_listener_ = std::make_unique<tf2_ros::TransformListener>(*tf_buffer_, nh);
    NODELET_INFO("odometry: nav prior from tf %s -> %s at each image stamp (waiting up to %.2f s), sigma %.3f x and "
                 "%.4f rad/m x the distance travelled",
                 odom_frame_.c_str(), base_frame_.c_str(), o.nav_tf_wait_s, o.nav_tf_drift, o.nav_tf_yaw_drift);
  }
  if (o.nav_source == "topic") {
    nav_sub_ = nh.subscribe(topics::kNavOdometry, 100, &OdometryNodelet::onNav, this);
    NODELET_INFO("odometry: nav prior from %s (nav_msgs/Odometry, %s), readings kept %.0f s; frames without one "
                 "go as without nav",
                 nav_sub_.getTopic().c_str(), config_.odometry.nav.enabled ? "used" : "slam/odometry/nav/enabled false: ignored",
                 o.nav_buffer_s);
  }
}

void OdometryNodelet::onNav(const nav_msgs::OdometryConstPtr& msg) {
  ++nav_in_;
  core::NavRecord r;
  std::string why;
  bool ok = rc::navFromMsg(*msg, mount_, &r, &why);
  if (ok) {
    std::lock_guard<std::mutex> lock(nav_mutex_);
    // Further back than a late reading may be: a new clock (a bag played again), the track restarts.
    ok = nav_.append(r, &why, std::max(options_.reorder_tolerance_s, 1e-6));
    if (ok && !why.empty()) NODELET_WARN("odometry: nav reading at %.3f: %s", r.stamp_s, why.c_str());
    if (ok && nav_.rows().size() > 64) nav_.dropBefore(r.stamp_s - options_.nav_buffer_s);
    if (ok) last_nav_wall_ = ros::WallTime::now();
  }
  if (ok) nav_cv_.notify_all();
  if (!ok) {
    ++nav_refused_;
    NODELET_WARN_THROTTLE(5, "odometry: nav reading skipped: %s (%ld so far)", why.c_str(), nav_refused_.load());
  }
}

std::optional<core::NavRecord> OdometryNodelet::navFromTf(const ros::Time& stamp) {
  geometry_msgs::TransformStamped t;
  try {
    t = tf_buffer_->lookupTransform(odom_frame_, base_frame_, stamp, ros::Duration(options_.nav_tf_wait_s));
  } catch (const tf2::TransformException& e) {
    ++counts_.nav_tf_missing;
    NODELET_WARN_THROTTLE(5, "odometry: no nav for the frame at %.3f: %s (%ld frames so far)", stamp.toSec(), e.what(),
                          counts_.nav_tf_missing);
    return std::nullopt;
  }
  core::Pose2 vehicle;
  if (!rc::fromMsg(t.transform, &vehicle)) {  // not finite, or a zero quaternion
    ++counts_.nav_tf_missing;
    return std::nullopt;
  }
  if (last_tf_nav_) tf_nav_distance_m_ += (vehicle.translation() - last_tf_nav_->translation()).norm();
  last_tf_nav_ = vehicle;
  core::NavRecord r;
  r.stamp_s = stamp.toSec();
  r.pose = core::cameraFromVehicle(vehicle, mount_);
  r.sigma_xy_m = options_.nav_tf_drift * tf_nav_distance_m_;
  r.sigma_yaw_rad = options_.nav_tf_yaw_drift * tf_nav_distance_m_;
  return r;
}

std::optional<core::NavRecord> OdometryNodelet::navAt(double stamp_s) {
  if (!config_.odometry.nav.enabled) return std::nullopt;
  std::unique_lock<std::mutex> lock(nav_mutex_);
  core::NavRecord r;
  // The frame is newer than the newest reading while readings keep coming: its own is on the way
  // (another connection than the image's), wait for it up to ~nav_wait_s.
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(options_.nav_wait_s);
  auto waiting = [&] {
    return !nav_.empty() && nav_.rows().back().stamp_s < stamp_s && !last_nav_wall_.isZero() &&
           (ros::WallTime::now() - last_nav_wall_).toSec() < 1.0;
  };
  while (waiting() && nav_cv_.wait_until(lock, deadline) != std::cv_status::timeout) {
  }
  if (!nav_.at(stamp_s, &r)) return std::nullopt;
  return r;
}

void OdometryNodelet::chooseImageTransport() {
  // ~image_transport, as image_transport itself reads it (default raw).
  const std::string transport =
      image_transport::TransportHints("raw", ros::TransportHints(), getPrivateNodeHandle()).getTransport();
  // Plugins that load, as "<package>/<transport>" (image_transport/raw, image_transport/compressed, ...).
  const std::vector<std::string> loadable = it_->getLoadableTransports();
  std::string names;
  bool installed = false;
  for (const std::string& l : loadable) {
    const std::string name = l.substr(l.rfind('/') + 1);
    installed = installed || name == transport;
    names += (names.empty() ? "" : ", ") + name;
  }
  const std::string base = getNodeHandle().resolveName(topics::kImage);
  image_transport_ = transport;
  image_topic_ = transport == "raw" ? base : base + "/" + transport;
  builtin_decoder_ = transport == "compressed" && !installed;
  if (builtin_decoder_) {
    NODELET_INFO(
        "odometry: image transport 'compressed' on %s (sensor_msgs/CompressedImage, jpeg or png): the built-in "
        "OpenCV decoder, as image_transport has no compressed plugin (loadable: %s)",
        image_topic_.c_str(), names.c_str());
  } else if (installed) {
    NODELET_INFO("odometry: image transport '%s' on %s: image_transport's plugin", transport.c_str(),
                 image_topic_.c_str());
  } else {
    const std::string why = getPrivateNodeHandle().resolveName("image_transport") + " = '" + transport +
                            "': no image_transport plugin for it is installed (loadable: " + names +
                            "; 'compressed' also works without its plugin)";
    NODELET_FATAL("odometry: not starting: %s", why.c_str());
    throw std::invalid_argument(why);
  }
}

void OdometryNodelet::onImage(const sensor_msgs::ImageConstPtr& image) { addPending({image, nullptr, 0.0}); }

void OdometryNodelet::onCompressedImage(const sensor_msgs::CompressedImageConstPtr& image) {
  addPending({nullptr, image, 0.0});  // decoded by the worker, so a corrupt one is counted like any bad image
}

void OdometryNodelet::addPending(Pending p) {
  const double now = wallNow();
  ++images_in_, last_image_ = now;
  if (images_since_range_++ == 0) first_image_since_range_ = now;
  if (images_since_sync_++ == 0) first_image_since_sync_ = now;
  p.arrived = now;
  std::lock_guard<std::mutex> lock(pairing_mutex_);
  pending_.push_back(std::move(p));
  pairPending(now);
}

void OdometryNodelet::onCameraInfo(const sensor_msgs::CameraInfoConstPtr& info) {
  const double now = wallNow();
  ++infos_in_, last_info_ = now;
  std::lock_guard<std::mutex> lock(pairing_mutex_);
  // A stamp far back (a bag that loops): the older ones belong to another time.
  if (!infos_.empty() &&
      info->header.stamp.toSec() < infos_.back()->header.stamp.toSec() - options_.reorder_tolerance_s) {
    infos_.clear();
  }
  infos_.push_back(info);
  while (infos_.size() > kCameraInfosKept) infos_.pop_front();
  pairPending(now);
}

void OdometryNodelet::onRange(const sensor_msgs::RangeConstPtr& range) {
  const double now = wallNow();
  ++ranges_in_, images_since_range_ = 0, last_range_ = now;
  double altitude = std::numeric_limits<double>::quiet_NaN();
  std::string why;
  if (!rc::altitudeFromMsg(*range, config_.odometry.max_altitude_m, &altitude, &why)) {
    altitude = std::numeric_limits<double>::quiet_NaN();  // kept as an invalid reading
    ++ranges_refused_;
    if (std::isfinite(range->range) && range->range > config_.odometry.max_altitude_m) ++ranges_above_max_;
    NODELET_WARN_THROTTLE(
        5, "odometry: %s: images at this reading's stamp get no altitude (the last valid one is used)", why.c_str());
  }
  std::lock_guard<std::mutex> lock(pairing_mutex_);
  const double last = altitudes_->empty() ? 0.0 : altitudes_->newest();
  if (altitudes_->add(range->header.stamp.toSec(), altitude) == core::AltitudeBuffer::AddResult::kCleared) {
    ++altitude_clears_;
    NODELET_WARN(
        "odometry: altitude stamps jumped back by %.3f s (a bag that loops, or a clock reset): earlier "
        "readings dropped",
        last - range->header.stamp.toSec());
  }
  pairPending(now);
}

void OdometryNodelet::onPairingTimer(const ros::WallTimerEvent&) {
  std::lock_guard<std::mutex> lock(pairing_mutex_);
  pairPending(wallNow());
}

bool OdometryNodelet::cameraInfoAt(double stamp_s, bool final_answer, sensor_msgs::CameraInfoConstPtr* info) const {
  info->reset();
  double best = std::numeric_limits<double>::infinity();
  bool later = false;  // one at or after the stamp has arrived: later ones cannot be nearer
  for (const auto& i : infos_) {
    const double t = i->header.stamp.toSec();
    later = later || t >= stamp_s;
    const double d = std::abs(t - stamp_s);
    if (d <= options_.sync_max_interval_s && d <= best) best = d, *info = i;  // the latest of equals
  }
  // No camera_info ever: the calibration of ~camera_info_url, once an image has waited its longest.
  if (!*info && fallback_info_ && infos_in_ == 0 && (final_answer || fallback_in_use_)) {
    *info = fallback_info_;
    return true;
  }
  // Without a candidate yet, a later camera_info does not settle it: the image's own may come late.
  return final_answer || best == 0.0 || (later && *info);
}

void OdometryNodelet::pairPending(double now) {
  const std::size_t max_pending = 2 * static_cast<std::size_t>(options_.sync_queue_size);
  while (!pending_.empty()) {
    const Pending& p = pending_.front();
    const double stamp = p.header().stamp.toSec();
    // Waited long enough, or too many waiting: decide with what has arrived.
    const bool final_answer = now - p.arrived >= options_.altitude_max_age_s || pending_.size() > max_pending;
    Frame f;
    f.image = p.image;
    f.compressed = p.compressed;
    if (!cameraInfoAt(stamp, final_answer, &f.info)) return;
    core::AltitudeAt altitude;
    if (altitudes_) {
      altitude = altitudes_->at(stamp, final_answer);
      if (altitude.status == core::AltitudeStatus::kPending) return;
    }
    pending_.pop_front();
    if (f.info && f.info == fallback_info_ && !fallback_in_use_) {
      fallback_in_use_ = true;
      NODELET_WARN("odometry: no camera_info on %s: images use the calibration of ~camera_info_url %s",
                   info_sub_.getTopic().c_str(), options_.camera_info_url.c_str());
    }
    if (!f.info) {
      ++no_camera_info_;
      skipStamp(stamp);
      NODELET_WARN_THROTTLE(5,
                            "odometry: image at %.3f skipped: no camera_info within ~sync_max_interval_s %.3f s of "
                            "its stamp (%ld so far)",
                            stamp, options_.sync_max_interval_s, no_camera_info_.load());
      continue;
    }
    if (altitudes_) {
      f.altitude_m = core::cameraAltitude(altitude.altitude_m, mount_);  // the altimeter's range -> the camera's
      f.bad_altitude = altitude.status == core::AltitudeStatus::kInvalid;
      if (altitude.status == core::AltitudeStatus::kStale) {
        // The fallback altitude only while the topic is silent (images without a reading for input_timeout_s).
        const bool silent = images_since_range_ > 0 && now - first_image_since_range_ >= options_.input_timeout_s;
        if (!(options_.fallback_altitude_m > 0 && silent)) {
          ++no_altitude_;
          skipStamp(stamp);
          NODELET_WARN_THROTTLE(5,
                                "odometry: image at %.3f skipped: no altitude reading within ~altitude_max_age_s "
                                "%.2f s of its stamp (%ld so far)",
                                stamp, options_.altitude_max_age_s, no_altitude_.load());
          continue;
        }
        f.fixed_altitude = true;
      }
    }
    push(std::move(f));
  }
}

void OdometryNodelet::skipStamp(double stamp_s) {
  // Bounded: after this many unpaired images in a row (minutes of them) the oldest are forgotten,
  // and the gap they leave may start a session, as a long outage should.
  constexpr std::size_t kMaxSkippedStamps = 4096;
  if (skipped_stamps_.size() >= kMaxSkippedStamps) skipped_stamps_.erase(skipped_stamps_.begin());
  skipped_stamps_.push_back(stamp_s);
}

void OdometryNodelet::push(Frame f) {
  images_since_sync_ = 0;
  f.passed_over = std::move(skipped_stamps_);  // images received before it, unpaired: seen, not a gap
  skipped_stamps_.clear();
  queue_->push(std::move(f));
}

bool OdometryNodelet::onPause(uw_multislam::OperatorCommand::Request&, uw_multislam::OperatorCommand::Response& res) {
  return setPaused(true, &res);
}

bool OdometryNodelet::onResume(uw_multislam::OperatorCommand::Request&, uw_multislam::OperatorCommand::Response& res) {
  return setPaused(false, &res);
}

bool OdometryNodelet::setPaused(bool paused, uw_multislam::OperatorCommand::Response* res) {
  std::lock_guard<std::mutex> lock(pause_mutex_);
  if (paused_ == paused) {
    res->status.code = uw_multislam::Status::FAILED_PRECONDITION;
    res->status.message = paused ? "the odometry is already paused (call resume)" : "the odometry is not paused";
  } else {
    paused_ = paused;
    paused_by_finish_ = false;
    res->status.code = uw_multislam::Status::OK;
    NODELET_INFO("odometry: %s (%ld frames dropped while paused so far)",
                 paused ? "paused by the operator: frames are dropped until resume" : "resumed", dropped_paused_.load());
  }
  res->paused = paused_;
  res->frames_dropped_paused = dropped_paused_;
  return true;
}

void OdometryNodelet::onActiveSession(const uw_multislam::SessionStateConstPtr& msg) {
  if (msg->session < 0 || msg->session > core::kMaxSessionId) {
    NODELET_WARN_THROTTLE(10, "odometry: ignoring active_session with id %d, outside [0, %d]", msg->session,
                          core::kMaxSessionId);
    return;
  }
  {
    std::lock_guard<std::mutex> lock(session_mutex_);
    next_free_session_ = msg->next_session;
    // Another vehicle's session took an id: nothing is asked of us (a subscriber that comes now,
    // a respawned odometry, takes the request it repeats).
    if (msg->next_session_only && had_request_) return;
    had_request_ = true;
    requested_session_ = msg->session;
  }
  std::lock_guard<std::mutex> lock(pause_mutex_);
  if (msg->state == uw_multislam::SessionState::FINISHED) {
    // finish_session: no session records; frames are dropped until start_session or resume.
    paused_ = true;
    paused_by_finish_ = true;
    NODELET_INFO("odometry: the session was finished: frames are dropped until start_session or resume (then "
                 "session %d starts)", msg->session);
  } else if (paused_by_finish_) {
    paused_ = false;
    paused_by_finish_ = false;
    NODELET_INFO("odometry: session %d requested after finish_session: frames are processed again", msg->session);
  }
}

void OdometryNodelet::work() {
  last_stats_ = ros::WallTime::now();
  // Frames taken out of the FIFO, oldest first; those after the first are being prepared ahead
  // (~prepare_threads) by prepare_pool_. Long-lived threads: a std::async thread per frame made
  // the odometry slower than without (bench_load.sh: 32 frames/s held against 48, each new
  // thread's allocations starting cold).
  struct Taken {
    Frame frame;
    std::future<Ahead> ahead;  // not valid: processed without preparation ahead
  };
  std::deque<Taken> taken;
  const std::size_t max_taken = 1 + static_cast<std::size_t>(options_.prepare_threads);
  for (;;) {
    if (taken.empty()) {
      Taken t;
      if (!queue_->pop(&t.frame)) break;  // false once closed and drained
      taken.push_back(std::move(t));
    }
    // Never waits for a frame: only those already in the FIFO are taken ahead.
    Taken next;
    while (taken.size() < max_taken && queue_->tryPop(&next.frame)) {
      auto task = std::make_shared<std::packaged_task<Ahead()>>([this, frame = next.frame] { return prepareAhead(frame); });
      next.ahead = task->get_future();
      boost::asio::post(*prepare_pool_, [task] { (*task)(); });
      taken.push_back(std::move(next));
      next = Taken();
    }
    Taken t = std::move(taken.front());
    taken.pop_front();
    const Frame& f = t.frame;
    counts_.dropped = queue_->dropped();
    const ros::WallTime start = ros::WallTime::now();
    try {
      if (t.ahead.valid()) {
        Ahead a = t.ahead.get();  // prepareAhead catches everything
        process(f, &a);
      } else {
        process(f);
      }
    } catch (const std::exception& e) {  // the core throws only on programming errors: log, keep going
      NODELET_ERROR_THROTTLE(5, "odometry: frame skipped, %s", e.what());
    }
    const double ms = (ros::WallTime::now() - start).toSec() * 1e3;
    counts_.total_ms += ms;
    counts_.max_ms = std::max(counts_.max_ms, ms);
    counts_.last_ms = ms;
    counts_.session = session_;
    {
      std::lock_guard<std::mutex> lock(stats_mutex_);
      published_ = counts_;
    }
    if ((ros::WallTime::now() - last_stats_).toSec() >= options_.stats_period_s) {
      logStats("so far");
      last_stats_ = ros::WallTime::now();
    }
  }
}

void OdometryNodelet::startSession(int id, const core::CameraIntrinsics& camera, const std::string& why) {
  if (odometry_) logStats(("at the end of session " + std::to_string(session_)).c_str());
  odometry_ = std::make_unique<core::SegmentedOdometry>(camera, config_.odometry, config_.tracking);
  camera_ = camera;
  session_ = id;
  frame_index_ = 0;
  ++counts_.sessions;
  std::ostringstream d;
  for (double k : camera.distortion) d << " " << k;
  NODELET_INFO("odometry: session %d starts (%s), camera %dx%d fx %.1f fy %.1f cx %.1f cy %.1f, distortion %s%s", id,
               why.c_str(), camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy,
               core::distortionModelName(camera.distortion_model).c_str(), d.str().c_str());
}

OdometryNodelet::Conversion OdometryNodelet::convert(const Frame& f, core::CameraIntrinsics* camera, cv::Mat* image,
                                                     std::string* why, rc::ImageRefusal* refusal) const {
  if (!rc::cameraFromMsg(*f.info, options_.rectified_images, camera, why)) return Conversion::kBadCamera;
  // A compressed image (the built-in decoder) is decoded here, then takes the raw path.
  sensor_msgs::ImagePtr decoded;
  const std::uint64_t max_pixels = static_cast<std::uint64_t>(options_.max_image_pixels);
  const bool decodes = !f.compressed || rc::imageFromCompressedMsg(*f.compressed, &decoded, why, refusal, max_pixels);
  if (!decodes || !rc::imageFromMsg(f.compressed ? decoded : f.image, image, why, refusal, max_pixels))
    return Conversion::kBadImage;
  return Conversion::kOk;
}

OdometryNodelet::Ahead OdometryNodelet::prepareAhead(const Frame& f) const {
  Ahead a;
  try {
    cv::Mat image;
    std::string why;
    rc::ImageRefusal refusal = rc::ImageRefusal::kNone;
    if (convert(f, &a.camera, &image, &why, &refusal) == Conversion::kOk)
      a.prepared = core::FramePreparer(a.camera, config_.odometry).prepare(image);
  } catch (const std::exception&) {
    a.prepared = core::PreparedFrame();  // process() converts the frame again and reports what is wrong
  }
  return a;
}

void OdometryNodelet::process(const Frame& f, Ahead* ahead) {
  ++counts_.frames;
  for (double t : f.passed_over) stamps_->passOver(t);  // received but not processed: seen, not a gap
  if (paused_) {  // dropped and counted; its stamp seen like a queue drop's (the pause is no time gap)
    stamps_->passOver(f.header().stamp.toSec());
    ++counts_.dropped_paused;
    dropped_paused_ = counts_.dropped_paused;
    return;
  }
  std::string why;
  core::CameraIntrinsics camera;
  cv::Mat image;
  rc::ImageRefusal refusal = rc::ImageRefusal::kNone;
  const Conversion converted = convert(f, &camera, &image, &why, &refusal);
  if (converted == Conversion::kBadCamera) {
    ++counts_.bad_camera;
    NODELET_WARN_THROTTLE(5, "odometry: frame skipped: %s (%ld so far)", why.c_str(), counts_.bad_camera);
    return;
  }
  if (converted == Conversion::kBadImage) {
    ++counts_.bad_image;
    switch (refusal) {
      case rc::ImageRefusal::kEmpty:
        ++counts_.empty_image;
        break;
      case rc::ImageRefusal::kTooSmall:
        ++counts_.tiny_image;
        break;
      case rc::ImageRefusal::kLayout:
        ++counts_.bad_layout;
        break;
      case rc::ImageRefusal::kCorrupt:
        ++counts_.corrupt_image;
        break;
      case rc::ImageRefusal::kTooLarge:
        ++counts_.too_large;
        break;
      default:
        ++counts_.bad_encoding;
        break;
    }
    NODELET_WARN_THROTTLE(5, "odometry: frame skipped: %s (%ld so far)", why.c_str(), counts_.bad_image);
    return;
  }
  if (image.cols != camera.width || image.rows != camera.height) {
    ++counts_.bad_image;
    ++counts_.size_mismatch;
    NODELET_WARN_THROTTLE(5, "odometry: frame skipped: image %dx%d but camera_info says %dx%d (%ld so far)", image.cols,
                          image.rows, camera.width, camera.height, counts_.bad_image);
    return;
  }
  // Stamps: duplicates and late frames are skipped before they touch the odometry (or count a bad altitude).
  const ros::Time stamp = f.header().stamp;
  const core::StampClass timing = stamps_->accept(stamp.toSec());
  if (timing == core::StampClass::kDuplicate) {
    ++counts_.duplicates;
    NODELET_WARN_THROTTLE(5, "odometry: frame skipped: stamp %.6f seen before (duplicated frame; %ld so far)",
                          stamp.toSec(), counts_.duplicates);
    return;
  }
  if (timing == core::StampClass::kOutOfOrder) {
    ++counts_.out_of_order;
    NODELET_WARN_THROTTLE(5,
                          "odometry: frame skipped: stamp %.6f is %.3f s before the last frame's (out of order; "
                          "%ld so far)",
                          stamp.toSec(), stamps_->last() - stamp.toSec(), counts_.out_of_order);
    return;
  }

  double altitude = options_.altitude_m;
  if (f.fixed_altitude) {
    altitude = options_.fallback_altitude_m;
    ++counts_.fixed_altitude;
    NODELET_WARN_THROTTLE(10,
                          "odometry: no altitude on %s for %.0f s: the fixed ~fallback_altitude %.2f m is used "
                          "(%ld frames so far)",
                          range_sub_.getTopic().c_str(), options_.input_timeout_s, altitude, counts_.fixed_altitude);
  } else if (options_.use_altitude_topic) {
    altitude = f.altitude_m;
    if (f.bad_altitude) {
      ++counts_.bad_altitude;
      NODELET_WARN_THROTTLE(5,
                            "odometry: the altitude at %.3f would use an invalid reading (NaN, <= 0 or out of "
                            "range): the last valid altitude is used (%ld so far)",
                            stamp.toSec(), counts_.bad_altitude);
      altitude = std::numeric_limits<double>::quiet_NaN();  // the core reuses the last valid one, or skips
    }
  }

  // Session changes, in order of precedence: the back-end's request, a time jump, a new camera.
  int requested = -1, next_free = 0;
  {
    std::lock_guard<std::mutex> lock(session_mutex_);
    std::swap(requested, requested_session_);
    next_free = next_free_session_;
  }
  // A session the odometry starts by itself takes the next id, past those other vehicles'
  // sessions took in the back-end (active_session's next_session).
  const int next_own = std::max(session_ + 1, next_free);
  if (!odometry_) {
    startSession(requested >= 0 ? requested : session_, camera, "first frame");
  } else if (requested >= 0 && requested != session_) {
    startSession(requested, camera, "requested on " + std::string(topics::kActiveSession));
  } else if (core::StampGuard::startsSession(timing)) {
    ++(timing == core::StampClass::kJumpBack ? counts_.jumps_back : counts_.jumps_forward);
    if (timing == core::StampClass::kJumpBack) {
      NODELET_WARN("odometry: image stamps jumped back by %.3f s (a bag that loops, or a clock reset)",
                   -stamps_->lastJump());
    } else {
      NODELET_INFO("odometry: image stamps jumped forward by %.3f s (a gap in the images)", stamps_->lastJump());
    }
    startSession(next_own, camera, "image stamps jumped by " + std::to_string(stamps_->lastJump()) + " s");
  } else {
    if (camera_ != camera) {
      startSession(next_own, camera, "camera intrinsics changed");
    }
  }

  const std::optional<core::NavRecord> nav =
      !config_.odometry.nav.enabled ? std::nullopt : tf_buffer_ ? navFromTf(stamp) : navAt(stamp.toSec());
  if (nav) ++counts_.frames_with_nav;
  // Prepared ahead with this frame's camera: the session's (a new camera has started a session above).
  core::PreparedFrame* prepared = nullptr;
  if (ahead && ahead->prepared.done && ahead->camera == camera_) {
    prepared = &ahead->prepared;
    ++counts_.prepared_ahead;
  }
  const core::SegmentedOdometry::Step step =
      odometry_->process({frame_index_++, stamp.toSec(), altitude, image, nav}, prepared);
  const core::OdometryUpdate& u = step.update;
  if (u.status != core::FrameStatus::kSkipped && u.source == core::MotionSource::kNav) ++counts_.nav_motions;
  if (u.status != core::FrameStatus::kSkipped && u.source == core::MotionSource::kFused) ++counts_.fused_motions;
  if (!u.nav_note.empty()) {
    ++counts_.nav_implausible;
    NODELET_WARN_THROTTLE(5, "odometry: frame %d: %s", u.index, u.nav_note.c_str());
  }
  if (step.session_started && odometry_->sessions() > 1) {
    session_ = std::max(session_ + 1, next_free);
    ++counts_.sessions;
    NODELET_INFO("odometry: tracking resumed at frame %d: session %d starts", u.index, session_);
  }
  if (u.status == core::FrameStatus::kSkipped) {
    ++counts_.skipped_by_odometry;
    NODELET_WARN_THROTTLE(5, "odometry: frame %d skipped: %s", u.index, u.reason.c_str());
    return;
  }
  if (u.status == core::FrameStatus::kFallback) {
    ++counts_.fallbacks;
    NODELET_WARN_THROTTLE(5, "odometry: frame %d: fallback motion (%s)", u.index, u.reason.c_str());
  }
  publishKeyframes(f, image, u);
  if (step.session_closed) {
    ++counts_.losses;
    NODELET_WARN(
        "odometry: tracking lost at frame %d (%d unmatched frames): session %d closed; the next frame with "
        "%d features starts session %d",
        u.index, config_.tracking.max_fallbacks, session_, config_.tracking.min_features, session_ + 1);
  }

  // base_link in the z-up session frame, with the covariance of the motions since its first frame.
  pose_pub_.publish(rc::toPoseWithCovarianceStampedMsg(
      core::vehicleFromCamera(core::UncertainPose2(u.pose, u.covariance), mount_),
      options_.session_frame_prefix + std::to_string(session_), stamp));
}

void OdometryNodelet::publishKeyframes(const Frame& f, const cv::Mat& image, const core::OdometryUpdate& u) {
  const core::Odometry& odometry = *odometry_->odometry();
  for (const auto& kf : odometry_->newKeyframes()) {
    rc::KeyframeData data = rc::keyframeData(odometry, kf, u, session_);
    data.hash = hasher_->hash(kf.features.descriptors);  // once here; the loop detector and back-end reuse it
    // The store's keyframe image (config store.*), made as offline_slam makes it; a promoted
    // keyframe's image is gone.
    if (data.frame_index == u.index) data.thumbnail = core::encodeKeyframeImage(image, config_.store_image);
    std_msgs::Header header = f.header();
    if (data.frame_index != u.index) header.stamp.fromSec(odometry.keyframes()[kf.id].stamp_s);  // promoted or held
    keyframe_pub_.publish(boost::make_shared<uw_multislam::Keyframe>(rc::toKeyframeMsg(data, header)));
    ++counts_.keyframes;
    if (data.frame_index == u.index && keyframe_image_pub_.getNumSubscribers() > 0) {
      cv::Mat drawn;
      cv::drawKeypoints(image, kf.features.keypoints, drawn, cv::Scalar(0, 255, 0));
      keyframe_image_pub_.publish(cv_bridge::CvImage(header, "bgr8", drawn).toImageMsg());
    }
  }
}

std::string OdometryNodelet::silentInput(double now) const {
  const double timeout = options_.input_timeout_s;
  const double image = last_image_;
  // No image: a wrong topic or transport when none ever came (and start-up is long past), or a
  // dead camera when camera_info or altitude keep coming. A pause of every input (a bag that
  // ended) is not a silent image.
  const bool others = now - last_info_ <= timeout || now - last_range_ <= timeout;
  if ((image <= 0 && now - started_ > timeout) || (image > 0 && now - image > timeout && others)) {
    std::ostringstream os;
    os << "no image on " << image_topic_ << " (transport '" << image_transport_ << "') "
       << (image > 0 ? "for " : "in the ") << std::fixed << std::setprecision(0)
       << now - (image > 0 ? image : started_) << (image > 0 ? " s" : " s since start") << ", while "
       << (now - last_info_ <= timeout ? "camera_info arrives" : "no camera_info arrives either") << " and "
       << (now - last_range_ <= timeout ? "altitude arrives" : "no altitude arrives either")
       << ": check the topic name (rostopic list; launch argument image:=) and the transport";
    return os.str();
  }
  if (image <= 0 || now - image > timeout) return "";  // no images (a pause of every input): nothing to pair
  if (images_since_sync_ == 0 || now - first_image_since_sync_ <= timeout) return "";  // pairs are coming
  auto age = [&](double last) { return now - (last > 0 ? last : started_); };
  std::ostringstream os;
  os << "images arrive on " << image_topic_ << " but none was paired for " << std::fixed
     << std::setprecision(0) << now - first_image_since_sync_ << " s: ";
  if (age(last_info_) > timeout && !fallback_in_use_) {
    os << "no camera_info on " << info_sub_.getTopic();
  } else if (options_.use_altitude_topic && images_since_range_ > 0 && now - first_image_since_range_ > timeout) {
    os << "no altitude on " << range_sub_.getTopic()
       << " (set ~fallback_altitude to fly on a fixed altitude, or ~use_altitude_topic false)";
  } else {
    os << "their stamps are further apart than ~sync_max_interval_s " << options_.sync_max_interval_s
       << " s (camera_info) or ~altitude_max_age_s " << options_.altitude_max_age_s << " s (altitude)";
  }
  return os.str();
}

void OdometryNodelet::onWatchdog(const ros::WallTimerEvent&) {
  const std::string silent = silentInput(wallNow());
  if (!silent.empty()) NODELET_WARN_THROTTLE(10, "odometry: %s", silent.c_str());
  updater_->force_update();
}

void OdometryNodelet::fillDiagnostics(diagnostic_updater::DiagnosticStatusWrapper& stat) {
  Counters c;
  {
    std::lock_guard<std::mutex> lock(stats_mutex_);
    c = published_;
  }
  const long images = images_in_;
  const long dropped = queue_->dropped(), queued = static_cast<long>(queue_->size());
  const long synced = queue_->pushed(), taken = queue_->popped();
  // Images not paired: skipped for want of a camera_info or an altitude, or still waiting.
  const long not_paired = std::max(0L, images - synced);
  long waiting = 0;
  {
    std::lock_guard<std::mutex> lock(pairing_mutex_);
    waiting = static_cast<long>(pending_.size());
  }
  const double processed = static_cast<double>(c.frames);  // frames finished (for the mean time)
  using ros_diagnostics::Counter;
  diagnostic_status_.fill(
      stat,
      {{"images_received", static_cast<double>(images)},
       {"camera_infos_received", static_cast<double>(infos_in_)},
       {"altitudes_received", static_cast<double>(ranges_in_)},
       // Readings, not frames: an altimeter without bottom lock (the descent) refuses readings
       // no frame may use; the frames that do use one are the WARN (bad_altitude_replaced).
       {"altitudes_refused", static_cast<double>(ranges_refused_)},
       {"altitudes_above_max_altitude", static_cast<double>(ranges_above_max_)},
       {"frames_synchronised", static_cast<double>(synced)},
       {"images_not_paired", static_cast<double>(not_paired)},
       {"images_waiting_pairing", static_cast<double>(waiting)},
       {"skipped_no_camera_info", static_cast<double>(no_camera_info_), true},
       {"skipped_no_altitude", static_cast<double>(no_altitude_), true},
       {"altitude_stamps_jumped_back", static_cast<double>(altitude_clears_)},
       {"frames_processed", static_cast<double>(taken)},  // taken by the worker (finished or in progress)
       {"frames_finished", processed},                    // done with (published or skipped): idle when equal
       {"dropped_queue_full", static_cast<double>(dropped), true},
       {"paused", paused_ ? 1.0 : 0.0},
       {"frames_dropped_paused", static_cast<double>(c.dropped_paused)},
       {"queue_length", static_cast<double>(queued)},
       {"skipped_empty_image", static_cast<double>(c.empty_image), true},
       {"skipped_encoding", static_cast<double>(c.bad_encoding), true},
       {"skipped_corrupt_image", static_cast<double>(c.corrupt_image), true},
       {"skipped_image_layout", static_cast<double>(c.bad_layout), true},
       {"skipped_tiny_image", static_cast<double>(c.tiny_image), true},
       {"skipped_image_too_large", static_cast<double>(c.too_large), true},
       {"skipped_size_mismatch", static_cast<double>(c.size_mismatch), true},
       {"skipped_camera_info", static_cast<double>(c.bad_camera), true},
       {"skipped_duplicate_stamp", static_cast<double>(c.duplicates), true},
       {"skipped_out_of_order", static_cast<double>(c.out_of_order), true},
       {"skipped_by_odometry", static_cast<double>(c.skipped_by_odometry), true},
       {"bad_altitude_replaced", static_cast<double>(c.bad_altitude), true},
       {"fixed_altitude_frames", static_cast<double>(c.fixed_altitude), true},
       {"time_jumps_back", static_cast<double>(c.jumps_back), true},
       {"time_jumps_forward", static_cast<double>(c.jumps_forward), true},
       {"fallbacks", static_cast<double>(c.fallbacks), true},
       {"tracking_losses", static_cast<double>(c.losses), true},
       {"nav_received", static_cast<double>(nav_in_.load())},
       {"nav_refused", static_cast<double>(nav_refused_.load()), true},
       {"frames_with_nav", static_cast<double>(c.frames_with_nav)},
       {"nav_motions", static_cast<double>(c.nav_motions)},
       {"fused_motions", static_cast<double>(c.fused_motions)},
       {"nav_implausible", static_cast<double>(c.nav_implausible), true},
       {"nav_tf_missing", static_cast<double>(c.nav_tf_missing), true},
       {"prepared_ahead", static_cast<double>(c.prepared_ahead)},
       {"sessions", static_cast<double>(c.sessions)},
       {"session", static_cast<double>(c.session)},
       {"keyframes", static_cast<double>(c.keyframes)},
       {"ms_per_frame_mean", processed > 0 ? c.total_ms / processed : 0.0},
       {"ms_per_frame_max", c.max_ms},
       {"ms_last_frame", c.last_ms}},
      wallNow(), silentInput(wallNow()));
}

void OdometryNodelet::logStats(const char* when) {
  const core::Odometry* odo = odometry_ ? odometry_->odometry() : nullptr;
  const core::OdometryStats s = odo ? odo->stats() : core::OdometryStats();
  const double ms = odometry_ ? odometry_->times().get("odometry_total").meanMs() : 0.0;
  // Live, readings above max_altitude_m are refused before the core sees them: counted as
  // readings above, not as the core's altitude_out_of_range (always 0 here).
  NODELET_INFO(
      "odometry %s: %ld frames received, %ld dropped (queue full), %ld bad images (%ld too large), %ld bad "
      "camera_info, "
      "%ld bad altitudes (%ld readings refused, %ld above odometry.max_altitude_m), %ld duplicated and %ld late stamps "
      "skipped, %ld time jumps, %ld keyframes published, %ld "
      "fallbacks, %ld sessions (%ld after tracking loss); current "
      "session %d: %d frames, "
      "%d keyframes, %d altitudes reused, %.1f ms/frame",
      when, counts_.frames, counts_.dropped, counts_.bad_image, counts_.too_large, counts_.bad_camera,
      counts_.bad_altitude, ranges_refused_.load(), ranges_above_max_.load(), counts_.duplicates, counts_.out_of_order,
      counts_.jumps_back + counts_.jumps_forward, counts_.keyframes, counts_.fallbacks, counts_.sessions,
      counts_.losses, session_, s.frames, s.keyframes, s.altitude_reused, ms);
}

}  // namespace nodelets
}  // namespace uw_multislam

PLUGINLIB_EXPORT_CLASS(uw_multislam::nodelets::OdometryNodelet, nodelet::Nodelet)
