// uw_multislam/Odometry: the visual odometry of paper 000 §5 (core::Odometry) on live images.
//
// Inputs (relative names, remapped in launch files; include/uw_multislam/ros/topics.h):
//   camera/image_raw    image_transport (raw by default; ~image_transport: compressed etc.)
//   camera/camera_info  sensor_msgs/CameraInfo
//   altitude            sensor_msgs/Range (only with ~use_altitude_topic: true, else ~altitude)
//   active_session      uw_multislam/SessionState from the back-end: a new id starts a session
// The three sensor topics are paired by message_filters' ApproximateTime (images without an
// altitude within ~sync_max_interval_s are never paired, so they are not processed).
// Outputs:
//   keyframes                uw_multislam/Keyframe, each new keyframe with its features
//   odometry/pose            geometry_msgs/PoseStamped, each processed frame, session frame
//   odometry/keyframe_image  the new keyframe's image with its features (only when subscribed)
//
// Threading model: the synchroniser's callback (any of the manager's threads) only pushes the
// message pointers onto a bounded FIFO of ~queue_size frames and returns; when the FIFO is full
// the OLDEST frame is dropped and counted (live, the newest image matters; a gap is bridged by
// the keyframe rule or the fallback). One worker thread owns core::Odometry and does everything
// else: conversion, SIFT, RANSAC, publishing. Session switches requested on active_session are
// handed to the worker through the same mutex. Messages are published as shared pointers, so
// the loop nodelets in the same manager receive them without a copy.
//
// Sessions: the first session has id ~session. A new session starts (the odometry restarts, the
// next keyframe is the new origin) when the back-end asks for another id on active_session, when
// the image stamps jump back in time or forward by more than ~session_gap_s, when the camera
// intrinsics change, or when tracking is lost (core/tracking.h: tracking.max_fallbacks unmatched
// frames close the session, the next frame with tracking.min_features features starts the next;
// keyframes with reused motions are published only once tracking is confirmed). Without a
// back-end the ids simply count up.
//
// Bad input never stops the node: an image of an unusable encoding or size, a camera_info
// without a focal length and an altitude that is NaN or outside the sensor's range are counted
// and logged (throttled); such a frame is skipped, except a bad altitude, which the core replaces
// by the last valid one (it counts that too). Counters are logged every ~stats_period_s.
#include <boost/bind/bind.hpp>
#include <cv_bridge/cv_bridge.h>
#include <geometry_msgs/PoseStamped.h>
#include <image_transport/image_transport.h>
#include <image_transport/subscriber_filter.h>
#include <message_filters/subscriber.h>
#include <message_filters/sync_policies/approximate_time.h>
#include <message_filters/synchronizer.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/Range.h>

#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>
#include <pluginlib/class_list_macros.hpp>

#include <cmath>
#include <limits>
#include <condition_variable>
#include <deque>
#include <memory>
#include <mutex>
#include <thread>

#include "uw_multislam/Keyframe.h"
#include "uw_multislam/SessionState.h"
#include "uw_multislam/core/odometry.h"
#include "uw_multislam/core/slam_config.h"
#include "uw_multislam/core/tracking.h"
#include "uw_multislam/ros/conversions.h"
#include "uw_multislam/ros/pipeline_conversions.h"
#include "uw_multislam/ros/sensor_conversions.h"
#include "uw_multislam/ros/slam_params.h"
#include "uw_multislam/ros/topics.h"

namespace uw_multislam {
namespace nodelets {

namespace rc = ros_conversions;

/// The nodelet's own parameters (private namespace), read once.
struct OdometryNodeletOptions {
  bool use_altitude_topic = true;
  double altitude_m = 0.0;  // used when use_altitude_topic is false
  int queue_size = 5;       // frames waiting for the worker
  int sync_queue_size = 10;
  double sync_max_interval_s = 0.1;
  int session = 0;             // id of the first session
  double session_gap_s = 10.0;  // stamps jumping forward more than this start a session; 0 = never
  double stats_period_s = 30.0;
  std::string session_frame_prefix = "session_";
};

class OdometryNodelet : public nodelet::Nodelet {
 public:
  ~OdometryNodelet() override;

 private:
  struct Frame {
    sensor_msgs::ImageConstPtr image;
    sensor_msgs::CameraInfoConstPtr info;
    sensor_msgs::RangeConstPtr range;  // null without altitude topic
  };
  struct Counters {
    long frames = 0, dropped = 0, bad_image = 0, bad_camera = 0, bad_altitude = 0, keyframes = 0, fallbacks = 0,
         sessions = 0, losses = 0;
  };
  using SyncWithAltitude = message_filters::sync_policies::ApproximateTime<sensor_msgs::Image, sensor_msgs::CameraInfo,
                                                                           sensor_msgs::Range>;
  using SyncNoAltitude = message_filters::sync_policies::ApproximateTime<sensor_msgs::Image, sensor_msgs::CameraInfo>;

  void onInit() override;
  void readParameters();
  void onSynced(const sensor_msgs::ImageConstPtr& image, const sensor_msgs::CameraInfoConstPtr& info,
                const sensor_msgs::RangeConstPtr& range);
  void onActiveSession(const uw_multislam::SessionStateConstPtr& msg);
  void work();
  void process(const Frame& f);
  void startSession(int id, const core::CameraIntrinsics& camera, const std::string& why);
  void publishKeyframes(const Frame& f, const cv::Mat& image, const core::OdometryUpdate& u);
  void logStats(const char* when);

  OdometryNodeletOptions options_;
  core::SlamConfig config_;

  // FIFO between the callbacks and the worker.
  std::mutex mutex_;
  std::condition_variable wake_;
  std::deque<Frame> queue_;     // guarded by mutex_
  int requested_session_ = -1;  // guarded by mutex_; -1: none
  bool stopping_ = false;       // guarded by mutex_
  long dropped_ = 0;            // guarded by mutex_
  std::thread worker_;

  // Worker-only state.
  std::unique_ptr<core::SegmentedOdometry> odometry_;  // the stream's odometry, a new session on tracking loss
  core::CameraIntrinsics camera_;
  int session_ = 0;
  int frame_index_ = 0;
  ros::Time last_stamp_;
  Counters counts_;
  ros::WallTime last_stats_;
  bool warned_distortion_ = false;

  ros::Publisher keyframe_pub_, pose_pub_;
  std::unique_ptr<image_transport::ImageTransport> it_;
  image_transport::Publisher keyframe_image_pub_;
  // Subscribers last: destroyed first, so no callback runs into destroyed members.
  ros::Subscriber session_sub_;
  image_transport::SubscriberFilter image_sub_;
  message_filters::Subscriber<sensor_msgs::CameraInfo> info_sub_;
  message_filters::Subscriber<sensor_msgs::Range> range_sub_;
  std::unique_ptr<message_filters::Synchronizer<SyncWithAltitude>> sync3_;
  std::unique_ptr<message_filters::Synchronizer<SyncNoAltitude>> sync2_;
};

OdometryNodelet::~OdometryNodelet() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
  }
  wake_.notify_all();
  if (worker_.joinable()) worker_.join();
  sync3_.reset();
  sync2_.reset();
  if (odometry_) logStats("at shutdown");
}

void OdometryNodelet::readParameters() {
  ros::NodeHandle& pnh = getPrivateNodeHandle();
  using ros_params::param;
  options_.use_altitude_topic = param(pnh, "use_altitude_topic", true, [](bool) { return true; }, "a bool");
  options_.altitude_m = param(pnh, "altitude", 0.0, [](double) { return true; }, "");
  if (!options_.use_altitude_topic && !(std::isfinite(options_.altitude_m) && options_.altitude_m > 0)) {
    throw std::invalid_argument(pnh.resolveName("altitude") + " = " + std::to_string(options_.altitude_m) +
                                ": must be a positive altitude in metres when use_altitude_topic is false");
  }
  options_.queue_size = param(pnh, "queue_size", 5, [](int v) { return v >= 1 && v <= 10000; }, "in [1, 10000]");
  options_.sync_queue_size =
      param(pnh, "sync_queue_size", 10, [](int v) { return v >= 1 && v <= 1000; }, "in [1, 1000]");
  options_.sync_max_interval_s = param(pnh, "sync_max_interval_s", 0.1, [](double v) { return v > 0; }, "positive");
  options_.session = param(pnh, "session", 0, [](int v) { return v >= 0; }, ">= 0");
  options_.session_gap_s = param(pnh, "session_gap_s", 10.0, [](double v) { return v >= 0; }, ">= 0 (0 = off)");
  options_.stats_period_s = param(pnh, "stats_period_s", 30.0, [](double v) { return v > 0; }, "positive");
  options_.session_frame_prefix = param(getNodeHandle(), "frames/session_frame_prefix", std::string("session_"),
                                        [](const std::string& s) { return !s.empty(); }, "non-empty");
  config_ = ros_params::slamConfigFromParams(getNodeHandle());
  const std::string bad = config_.validate();
  if (!bad.empty()) throw std::invalid_argument(getNodeHandle().resolveName("slam") + ": " + bad);
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
      "odometry: altitude from %s, queue_size %d (oldest dropped when full), sync_queue_size %d, "
      "sync_max_interval_s %.3f, first session %d, session_gap_s %.1f, stats every %.0f s; n = %d features, "
      "enhancement %s, keyframes at overlap < %.2f",
      o.use_altitude_topic ? "the altitude topic" : ("the fixed altitude " + std::to_string(o.altitude_m) + " m").c_str(),
      o.queue_size, o.sync_queue_size, o.sync_max_interval_s, o.session, o.session_gap_s, o.stats_period_s,
      config_.odometry.features.num_features, core::enhancementName(config_.odometry.enhancement.mode).c_str(),
      config_.odometry.keyframes.min_overlap);
  NODELET_DEBUG_STREAM("odometry: effective SLAM configuration:\n" << core::slamConfigToYaml(config_));
  session_ = o.session;

  ros::NodeHandle& nh = getNodeHandle();
  keyframe_pub_ = nh.advertise<uw_multislam::Keyframe>(topics::kKeyframes, 50);
  pose_pub_ = nh.advertise<geometry_msgs::PoseStamped>(topics::kOdometryPose, 10);
  it_ = std::make_unique<image_transport::ImageTransport>(nh);
  keyframe_image_pub_ = it_->advertise(topics::kKeyframeImage, 1);

  worker_ = std::thread([this] { work(); });

  session_sub_ = nh.subscribe(topics::kActiveSession, 1, &OdometryNodelet::onActiveSession, this);
  const image_transport::TransportHints hints("raw", ros::TransportHints(), getPrivateNodeHandle());
  image_sub_.subscribe(*it_, topics::kImage, o.sync_queue_size, hints);
  info_sub_.subscribe(nh, topics::kCameraInfo, o.sync_queue_size);
  const ros::Duration max_interval(o.sync_max_interval_s);
  if (o.use_altitude_topic) {
    range_sub_.subscribe(nh, topics::kAltitude, o.sync_queue_size);
    sync3_ = std::make_unique<message_filters::Synchronizer<SyncWithAltitude>>(SyncWithAltitude(o.sync_queue_size),
                                                                               image_sub_, info_sub_, range_sub_);
    sync3_->setMaxIntervalDuration(max_interval);
    sync3_->registerCallback(boost::bind(&OdometryNodelet::onSynced, this, boost::placeholders::_1, boost::placeholders::_2, boost::placeholders::_3));
  } else {
    sync2_ = std::make_unique<message_filters::Synchronizer<SyncNoAltitude>>(SyncNoAltitude(o.sync_queue_size),
                                                                             image_sub_, info_sub_);
    sync2_->setMaxIntervalDuration(max_interval);
    sync2_->registerCallback(boost::bind(&OdometryNodelet::onSynced, this, boost::placeholders::_1, boost::placeholders::_2,
                                         sensor_msgs::RangeConstPtr()));;
  }
  NODELET_INFO("odometry: image transport '%s' on %s", image_sub_.getTransport().c_str(),
               image_sub_.getTopic().c_str());
}

void OdometryNodelet::onSynced(const sensor_msgs::ImageConstPtr& image, const sensor_msgs::CameraInfoConstPtr& info,
                               const sensor_msgs::RangeConstPtr& range) {
  const Frame f{image, info, range};
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (static_cast<int>(queue_.size()) >= options_.queue_size) {
      queue_.pop_front();
      ++dropped_;
    }
    queue_.push_back(f);
  }
  wake_.notify_one();
}

void OdometryNodelet::onActiveSession(const uw_multislam::SessionStateConstPtr& msg) {
  if (msg->session < 0) {
    NODELET_WARN_THROTTLE(10, "odometry: ignoring active_session with negative id %d", msg->session);
    return;
  }
  std::lock_guard<std::mutex> lock(mutex_);
  requested_session_ = msg->session;
}

void OdometryNodelet::work() {
  last_stats_ = ros::WallTime::now();
  for (;;) {
    Frame f;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      wake_.wait(lock, [this] { return stopping_ || !queue_.empty(); });
      if (stopping_) return;
      f = queue_.front();
      queue_.pop_front();
      counts_.dropped = dropped_;
    }
    try {
      process(f);
    } catch (const std::exception& e) {  // the core throws only on programming errors: log, keep going
      NODELET_ERROR_THROTTLE(5, "odometry: frame skipped, %s", e.what());
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
  NODELET_INFO("odometry: session %d starts (%s), camera %dx%d fx %.1f fy %.1f", id, why.c_str(), camera.width,
               camera.height, camera.fx, camera.fy);
}

void OdometryNodelet::process(const Frame& f) {
  ++counts_.frames;
  std::string why;
  core::CameraIntrinsics camera;
  bool distorted = false;
  if (!rc::cameraFromMsg(*f.info, &camera, &distorted, &why)) {
    ++counts_.bad_camera;
    NODELET_WARN_THROTTLE(5, "odometry: frame skipped: %s (%ld so far)", why.c_str(), counts_.bad_camera);
    return;
  }
  if (distorted && !warned_distortion_) {
    NODELET_WARN("odometry: camera_info has distortion coefficients; they are ignored (rectify the images first)");
    warned_distortion_ = true;
  }
  cv::Mat image;
  if (!rc::imageFromMsg(f.image, &image, &why)) {
    ++counts_.bad_image;
    NODELET_WARN_THROTTLE(5, "odometry: frame skipped: %s (%ld so far)", why.c_str(), counts_.bad_image);
    return;
  }
  if (image.cols != camera.width || image.rows != camera.height) {
    ++counts_.bad_image;
    NODELET_WARN_THROTTLE(5, "odometry: frame skipped: image %dx%d but camera_info says %dx%d (%ld so far)",
                          image.cols, image.rows, camera.width, camera.height, counts_.bad_image);
    return;
  }
  double altitude = options_.altitude_m;
  if (f.range && !rc::altitudeFromMsg(*f.range, &altitude, &why)) {
    ++counts_.bad_altitude;
    NODELET_WARN_THROTTLE(5, "odometry: %s: the last valid altitude is used (%ld so far)", why.c_str(),
                          counts_.bad_altitude);
    altitude = std::numeric_limits<double>::quiet_NaN();  // the core reuses the last valid one, or skips
  }

  // Session changes, in order of precedence: the back-end's request, a time jump, a new camera.
  int requested = -1;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    std::swap(requested, requested_session_);
  }
  const ros::Time stamp = f.image->header.stamp;
  if (!odometry_) {
    startSession(requested >= 0 ? requested : session_, camera, "first frame");
  } else if (requested >= 0 && requested != session_) {
    startSession(requested, camera, "requested on " + std::string(topics::kActiveSession));
  } else if (stamp < last_stamp_ ||
             (options_.session_gap_s > 0 && (stamp - last_stamp_).toSec() > options_.session_gap_s)) {
    startSession(session_ + 1, camera,
                 "image stamps jumped by " + std::to_string((stamp - last_stamp_).toSec()) + " s");
  } else {
    const core::CameraIntrinsics& c = camera_;
    if (c.width != camera.width || c.height != camera.height || c.fx != camera.fx || c.fy != camera.fy ||
        c.cx != camera.cx || c.cy != camera.cy) {
      startSession(session_ + 1, camera, "camera intrinsics changed");
    }
  }
  last_stamp_ = stamp;

  const core::SegmentedOdometry::Step step = odometry_->process({frame_index_++, stamp.toSec(), altitude, image});
  const core::OdometryUpdate& u = step.update;
  if (step.session_started && odometry_->sessions() > 1) {
    ++session_;
    ++counts_.sessions;
    NODELET_INFO("odometry: tracking resumed at frame %d: session %d starts", u.index, session_);
  }
  if (u.status == core::FrameStatus::kSkipped) {
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
    NODELET_WARN("odometry: tracking lost at frame %d (%d unmatched frames): session %d closed; the next frame with "
                 "%d features starts session %d",
                 u.index, config_.tracking.max_fallbacks, session_, config_.tracking.min_features, session_ + 1);
  }

  auto pose = boost::make_shared<geometry_msgs::PoseStamped>();
  pose->header.stamp = stamp;
  pose->header.frame_id = options_.session_frame_prefix + std::to_string(session_);
  pose->pose = rc::toPoseMsg(u.pose);
  pose_pub_.publish(pose);
}

void OdometryNodelet::publishKeyframes(const Frame& f, const cv::Mat& image, const core::OdometryUpdate& u) {
  const core::Odometry& odometry = *odometry_->odometry();
  for (const auto& kf : odometry_->newKeyframes()) {
    const rc::KeyframeData data = rc::keyframeData(odometry, kf, u, session_);
    std_msgs::Header header = f.image->header;
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

void OdometryNodelet::logStats(const char* when) {
  const core::Odometry* odo = odometry_ ? odometry_->odometry() : nullptr;
  const core::OdometryStats s = odo ? odo->stats() : core::OdometryStats();
  const double ms = odometry_ ? odometry_->times().get("odometry_total").meanMs() : 0.0;
  NODELET_INFO(
      "odometry %s: %ld frames received, %ld dropped (queue full), %ld bad images, %ld bad camera_info, "
      "%ld bad altitudes, %ld keyframes published, %ld fallbacks, %ld sessions (%ld after tracking loss); current "
      "session %d: %d frames, "
      "%d keyframes, %d altitudes reused, %.1f ms/frame",
      when, counts_.frames, counts_.dropped, counts_.bad_image, counts_.bad_camera, counts_.bad_altitude,
      counts_.keyframes, counts_.fallbacks, counts_.sessions, counts_.losses, session_, s.frames, s.keyframes, s.altitude_reused, ms);
}

}  // namespace nodelets
}  // namespace uw_multislam

PLUGINLIB_EXPORT_CLASS(uw_multislam::nodelets::OdometryNodelet, nodelet::Nodelet)
