// uw_multislam/Odometry: the visual odometry of paper 000 §5 (core::Odometry) on live images.
//
// Inputs (relative names, remapped in launch files; include/uw_multislam/ros/topics.h):
//   camera/image_raw    image_transport (raw by default; ~image_transport: compressed etc.).
//                       ~image_transport compressed without image_transport's compressed plugin
//                       (Debian ships none): sensor_msgs/CompressedImage on
//                       camera/image_raw/compressed, decoded by the worker with OpenCV
//                       (ros_conversions::imageFromCompressedMsg), then the raw path. Which of
//                       the two is used is logged at start-up.
//   camera/camera_info  sensor_msgs/CameraInfo (read with image_geometry::PinholeCameraModel, binning
//                       and ROI applied): K with D (plumb_bob, rational_polynomial), only the feature
//                       points undistorted; P when ~rectified_images (image_proc's image_rect).
//                       Without any camera_info, the calibration file of ~camera_info_url is used.
//   altitude            sensor_msgs/Range (only with ~use_altitude_topic: true, else ~altitude)
//   active_session      uw_multislam/SessionState from the back-end: a new id starts a session
//   nav/odom            nav_msgs/Odometry, the vehicle's dead reckoning (base_link in its odom
//                       frame, with covariance; issue 16), with ~nav_source topic (the default):
//                       kept for ~nav_buffer_s and interpolated at each frame's stamp (no
//                       extrapolation: a frame after the last reading goes without). A frame with
//                       a nav pose gets the core's nav prior (slam/odometry/nav: gate, dead
//                       reckoning through vision failures, fusion); without readings the odometry
//                       is exactly as without nav. Bad readings (not finite, negative variance,
//                       zero stamp, not after the last one) are skipped and counted (nav_refused).
//                       A frame newer than the newest reading waits up to ~nav_wait_s for the
//                       next one while readings keep coming (the nav and the image travel on
//                       separate connections: the image can be first); without readings for 1 s
//                       (a nav outage) it does not wait.
//   tf odom -> base_link with ~nav_source tf: the vehicle's dead reckoning from tf (frames/odom_frame
//                       -> frames/base_frame) at each frame's stamp (waiting up to ~nav_tf_wait_s);
//                       tf has no covariance, so sigma grows with the distance travelled:
//                       ~nav_tf_drift (fraction, default 0.01) and ~nav_tf_yaw_drift (rad per m,
//                       default 0.001). Refused at start-up while the back-end publishes
//                       odom -> base_link itself (backend_node/publish_odom_tf true: it would be the
//                       visual odometry fed back). A frame without the transform goes without nav
//                       (counted nav_tf_missing).
// Pairing by stamp (issue 15): each image waits (in arrival order, in a short list of pending
// images) for
//   - its camera_info: the one with the nearest stamp within ~sync_max_interval_s, reused by as
//     many images as need it. Decided as soon as the one with the image's own stamp has arrived,
//     or a later one while one within the bound is there (later ones cannot be nearer). A
//     camera_info per image, not just the latest one, so a change of intrinsics takes effect at
//     its own image; nearest, not exact, so a driver that stamps camera_info a little apart still
//     pairs.
//   - its altitude (with ~use_altitude_topic): core::AltitudeBuffer over the recent readings,
//     linear between the two readings around the image stamp (at most ~altitude_max_age_s
//     apart), else the nearest reading within ~altitude_max_age_s. Decided as soon as a reading
//     at or after the image stamp has arrived, so every image of a 10 Hz camera is used with a
//     2 Hz altimeter (an image waits for the next reading, at most ~0.5 s then).
// An image waits at most ~altitude_max_age_s (wall time) from its arrival; it is then decided
// with what has arrived (the last reading if within ~altitude_max_age_s of its stamp). Images
// without a camera_info or an altitude by then are skipped and counted (skipped_no_camera_info,
// skipped_no_altitude). At most 2 x ~sync_queue_size images wait; beyond that the oldest is
// decided at once.
// Outputs:
//   keyframes                uw_multislam/Keyframe, each new keyframe with its features and its
//                            hash (computed here once, with the slam/loops/global hash options)
//   odometry/pose            geometry_msgs/PoseWithCovarianceStamped, each processed frame: base_link
//                            in the session's z-up frame, the covariance of the motions composed
//   odometry/keyframe_image  the new keyframe's image with its features (only when subscribed)
//
// Threading model: the image, camera_info and altitude callbacks (any of the manager's threads)
// pair under a mutex of their own and push the paired message pointers onto a bounded FIFO of
// ~queue_size frames (ros/work_queue.h); when the FIFO is full the OLDEST frame is dropped and
// counted (live, the newest image matters; a gap is bridged by the keyframe rule or the
// fallback). One worker thread owns core::Odometry and does everything else: conversion, SIFT,
// RANSAC, publishing. Session switches requested on active_session are handed to the worker
// under a small mutex of their own. On unload the FIFO is closed and the worker processes the
// frames still in it before it is joined. Messages are published as shared pointers, so the loop
// nodelets in the same manager receive them without a copy. With ~prepare_threads N > 0 (issue 19,
// item 3: a second core) the worker takes up to N frames already waiting in the FIFO out early and
// prepares each (conversion, enhancement, SIFT: core::FramePreparer) on a thread of its own while
// it processes the frame before them; a frame is never waited for, so there is no added latency
// when frames are not backing up, and the odometry is the same as without (the preparation is a
// pure function of the image and camera; it is used only when its camera is the session's).
//
// Sessions: the first session has id ~session. A new session starts (the odometry restarts, the
// next keyframe is the new origin) when the back-end asks for another id on active_session, when
// the image stamps jump back in time or forward by more than ~session_gap_s, when the camera
// intrinsics change, or when tracking is lost (core/frontend/tracking.h: tracking.max_fallbacks unmatched
// frames close the session, the next frame with tracking.min_features features starts the next;
// keyframes with reused motions are published only once tracking is confirmed). Without a
// back-end the ids simply count up.
//
// Pause (services pause / resume, uw_multislam/OperatorCommand): while paused the worker drops
// every frame it takes, counted (frames_dropped_paused on /diagnostics), its stamp passed over like
// a queue drop, so the pause is no time gap and the session goes on: the first frame after resume
// is matched to the last keyframe as usual (a long pause over moving seabed ends in the tracking
// loss rule, as a blackout would). A second pause, or resume while running, is refused with
// FAILED_PRECONDITION and changes nothing.
//
// Bad input never stops the node and never reaches the map; each kind is counted, logged
// (throttled) and published on /diagnostics (diagnostic_updater, every ~diagnostic_period s,
// WARN while a drop or skip counter grows; keys in README "Diagnostics"):
//   - images: encodings are converted or refused as ros/sensor_conversions.h documents
//     (rgba/bgra drop alpha, 16 bits scaled, Bayer debayered; float/YUV refused); empty, tiny
//     (< 32 px) or wrongly laid out images and images whose size differs from camera_info are
//     skipped; so are images of more than ~max_image_pixels, by the size their header declares
//     (raw or compressed), before anything is converted, decoded or allocated; so are compressed images (built-in decoder) that do not decode (corrupt) or whose
//     format is neither jpeg nor png;
//   - camera_info without a focal length, with the principal point outside, a zero P for rectified
//     images or an unsupported distortion model (equidistant: rectify first): frame skipped;
//   - no camera_info at all: with ~camera_info_url, images that waited ~altitude_max_age_s without
//     one are paired with that file's calibration from then on (until a camera_info arrives);
//   - altitude NaN, <= 0 or outside the sensor's range: such a reading is kept as invalid; an
//     image whose altitude would use it gets none and the core reuses the last valid one (a
//     frame before any valid altitude is skipped);
//   - stamps (core/frontend/stamp_guard.h): the same stamp twice is a duplicate, a stamp up to
//     ~reorder_tolerance_s back is late: both skipped; further back (a bag that loops, a clock
//     reset) or forward by more than ~session_gap_s: a new session. The stamps of frames the
//     worker's FIFO dropped count as seen (each travels on with the frame after it), so a gap
//     made by our own drops never starts a session;
//   - altitude and camera_info stamps: an image without an altitude reading within
//     ~altitude_max_age_s of its stamp, or without a camera_info within ~sync_max_interval_s,
//     is skipped (counted). Altitude stamps jumping back (a bag that loops) clear the readings.
//   - a silent image topic: no image in ~input_timeout_s since start, or none for that long
//     while camera_info or altitude keep arriving (the topic, the transport, a dead camera);
//   - a silent input: images arrive but none is paired for ~input_timeout_s (altitude or
//     camera_info missing, or stamps too far apart): a warning naming the input, diagnostics
//     WARN. With ~fallback_altitude > 0 frames are then processed at that fixed altitude
//     (counted); by default they are not (a wrong scale would corrupt the map).
//   - bursts: the worker's FIFO drops the oldest frame when full (counted); images not (yet)
//     paired are counted as images_not_paired.
#pragma once

#include <diagnostic_updater/diagnostic_updater.h>
#include <image_transport/image_transport.h>
#include <nav_msgs/Odometry.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/Range.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_listener.h>

#include <opencv2/core.hpp>

#include <atomic>
#include <condition_variable>
#include <deque>
#include <future>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "uw_multislam/OperatorCommand.h"
#include "uw_multislam/SessionState.h"
#include "uw_multislam/core/frontend/altitude_buffer.h"
#include "uw_multislam/core/frontend/nav_prior.h"
#include "uw_multislam/core/frontend/odometry.h"
#include "uw_multislam/core/frontend/stamp_guard.h"
#include "uw_multislam/core/frontend/tracking.h"
#include "uw_multislam/core/geometry/vehicle_frame.h"
#include "uw_multislam/core/loops/haloc.h"
#include "uw_multislam/core/session/slam_config.h"
#include "uw_multislam/ros/diagnostics.h"
#include "uw_multislam/ros/sensor_conversions.h"
#include "uw_multislam/ros/topics.h"
#include "uw_multislam/ros/work_queue.h"

namespace boost {
namespace asio {
class thread_pool;
}  // namespace asio
}  // namespace boost

namespace uw_multislam {
namespace nodelets {

/// The nodelet's own parameters (private namespace), read once.
struct OdometryNodeletOptions {
  bool use_altitude_topic = true;
  double altitude_m = 0.0;           // used when use_altitude_topic is false
  int queue_size = 5;                // frames waiting for the worker
  int prepare_threads = 0;           // frames waiting that are prepared ahead, each on its own thread
  int sync_queue_size = 10;          // subscriber queues; 2x: images waiting for their pairing
  double sync_max_interval_s = 0.1;  // largest image - camera_info stamp difference
  double altitude_max_age_s = 1.0;   // altitude: largest gap interpolated / age used alone; longest wait
  int session = 0;                   // id of the first session
  double session_gap_s = 10.0;       // stamps jumping forward more than this start a session; 0 = never
  double reorder_tolerance_s = 1.0;  // stamps at most this far back are late frames (skipped)
  double input_timeout_s = 5.0;      // images without a synchronised set this long: warn
  double fallback_altitude_m = 0.0;  // > 0: used when the altitude topic is silent; 0 = off
  double diagnostic_period_s = 1.0;
  double stats_period_s = 30.0;
  int max_image_pixels = 25000000;  // larger images are skipped before any conversion (counted)
  std::string nav_source = "topic";  // topic: nav/odom (nav_msgs/Odometry); tf: odom -> base_link; none
  double nav_tf_wait_s = 0.05;       // tf: how long a frame waits for its transform
  double nav_wait_s = 0.05;          // topic: how long a frame newer than the newest reading waits
  double nav_tf_drift = 0.01;        // tf: sigma_xy = this x the distance travelled
  double nav_tf_yaw_drift = 0.001;   // tf: sigma_yaw = this (rad/m) x the distance travelled
  double nav_buffer_s = 60.0;        // nav readings kept this long behind the newest
  bool rectified_images = false;  // the images are rectified: P, no distortion; else K with D
  std::string camera_info_url;    // calibration used when no camera_info arrives; empty = none
  std::string session_frame_prefix = topics::kDefaultSessionFramePrefix;
};

class OdometryNodelet : public nodelet::Nodelet {
 public:
  ~OdometryNodelet() override;

 private:
  struct Frame {
    sensor_msgs::ImageConstPtr image;
    sensor_msgs::CompressedImageConstPtr compressed;  // instead of image: the built-in decoder's input
    sensor_msgs::CameraInfoConstPtr info;
    double altitude_m = 0.0;      // at the image stamp (with the altitude topic)
    bool bad_altitude = false;    // it would use an invalid reading: the core reuses the last valid one
    bool fixed_altitude = false;  // the altitude topic was silent: ~fallback_altitude is used
    // Stamps of the images received just before this one but not processed (the queue dropped
    // them, or no camera_info or altitude paired with them): seen, so no time gap (issue 21, 9).
    std::vector<double> passed_over;
    const std_msgs::Header& header() const { return image ? image->header : compressed->header; }
  };
  // The recent camera_infos searched for an image's.
  static constexpr std::size_t kCameraInfosKept = 100;
  // An image waiting for its camera_info and altitude.
  struct Pending {
    sensor_msgs::ImageConstPtr image;
    sensor_msgs::CompressedImageConstPtr compressed;  // instead of image (built-in decoder)
    double arrived = 0.0;                             // wall seconds
    const std_msgs::Header& header() const { return image ? image->header : compressed->header; }
  };
  struct Counters {
    long frames = 0, dropped = 0, bad_image = 0, bad_camera = 0, bad_altitude = 0, keyframes = 0, fallbacks = 0,
         sessions = 0, losses = 0;
    // Image refusals by kind (their sum is bad_image), stamps, altitude fallback, core skips.
    long empty_image = 0, bad_encoding = 0, bad_layout = 0, tiny_image = 0, size_mismatch = 0, corrupt_image = 0,
         too_large = 0;
    long duplicates = 0, out_of_order = 0, jumps_back = 0, jumps_forward = 0;
    long fixed_altitude = 0, skipped_by_odometry = 0;
    long dropped_paused = 0;  // frames the worker dropped while paused
    long frames_with_nav = 0, nav_motions = 0, fused_motions = 0;  // frames given a nav pose; motions not visual
    long nav_implausible = 0;  // frames whose nav step was too fast to be a motion (nav.max_speed_m_s): not used
    long nav_tf_missing = 0;  // ~nav_source tf: frames whose transform was not there
    long prepared_ahead = 0;  // frames whose preparation (SIFT) ran ahead on another thread (~prepare_threads)
    double total_ms = 0.0, max_ms = 0.0, last_ms = 0.0;
    int session = 0;
  };

  void onInit() override;
  void readParameters();
  /// Decides how images come (image_topic_, image_transport_, builtin_decoder_): through
  /// image_transport with ~image_transport's plugin, or, for `compressed` without its plugin,
  /// from <image>/compressed through the built-in decoder. Throws for another missing plugin.
  void chooseImageTransport();
  void onImage(const sensor_msgs::ImageConstPtr& image);
  void onCompressedImage(const sensor_msgs::CompressedImageConstPtr& image);
  /// An image (raw or compressed) joins the images waiting for their pairing.
  void addPending(Pending p);
  void onCameraInfo(const sensor_msgs::CameraInfoConstPtr& info);
  void onRange(const sensor_msgs::RangeConstPtr& range);
  /// A nav reading into nav_ (under nav_mutex_); a bad one is counted and logged.
  void onNav(const nav_msgs::OdometryConstPtr& msg);
  /// The nav at a frame's stamp, if the readings around it are there.
  std::optional<core::NavRecord> navAt(double stamp_s);
  /// ~nav_source tf: odom -> base_link at the stamp as a nav row (worker thread only).
  std::optional<core::NavRecord> navFromTf(const ros::Time& stamp);
  void onPairingTimer(const ros::WallTimerEvent&);
  /// Pairs the pending images, oldest first, until one must wait longer. Under pairing_mutex_.
  void pairPending(double now);
  /// An image pairing skipped (no camera_info or altitude): its stamp goes with the next frame pushed.
  void skipStamp(double stamp_s);
  /// The camera_info for an image stamp: set when decided (null: none within
  /// ~sync_max_interval_s); false while a nearer one may still come. Under pairing_mutex_.
  bool cameraInfoAt(double stamp_s, bool final_answer, sensor_msgs::CameraInfoConstPtr* info) const;
  void push(Frame f);
  void onActiveSession(const uw_multislam::SessionStateConstPtr& msg);
  /// pause / resume (operator services): refused with FAILED_PRECONDITION when already in that state.
  bool onPause(uw_multislam::OperatorCommand::Request& req, uw_multislam::OperatorCommand::Response& res);
  bool onResume(uw_multislam::OperatorCommand::Request& req, uw_multislam::OperatorCommand::Response& res);
  bool setPaused(bool paused, uw_multislam::OperatorCommand::Response* res);
  // A frame's conversion and preparation, done ahead on another thread (~prepare_threads).
  struct Ahead {
    core::CameraIntrinsics camera;
    core::PreparedFrame prepared;  // prepared.done false: nothing usable (process() converts and reports)
  };
  enum class Conversion { kOk, kBadCamera, kBadImage };
  /// The frame's camera and image (a compressed one decoded), or why not (`refusal`: the image's).
  Conversion convert(const Frame& f, core::CameraIntrinsics* camera, cv::Mat* image, std::string* why,
                     ros_conversions::ImageRefusal* refusal) const;
  /// convert() then core::FramePreparer::prepare with the frame's camera; catches everything.
  Ahead prepareAhead(const Frame& f) const;
  void work();
  /// `ahead` (may be null): the frame prepared ahead.
  void process(const Frame& f, Ahead* ahead = nullptr);
  void startSession(int id, const core::CameraIntrinsics& camera, const std::string& why);
  void publishKeyframes(const Frame& f, const cv::Mat& image, const core::OdometryUpdate& u);
  void logStats(const char* when);
  void onWatchdog(const ros::WallTimerEvent&);
  void fillDiagnostics(diagnostic_updater::DiagnosticStatusWrapper& stat);
  /// Why synchronised frames are not coming although images are (empty: they are, or no images).
  std::string silentInput(double now) const;
  static double wallNow() { return ros::WallTime::now().toSec(); }

  OdometryNodeletOptions options_;
  core::SlamConfig config_;
  core::CameraMount mount_;  // the altimeter's range + its camera_above_altimeter_m; odometry/pose is base_link's

  // FIFO between the callbacks and the worker (created once ~queue_size is known); its pushed()
  // count is the frames synchronised, popped() the frames the worker took.
  std::unique_ptr<ros_work::BoundedWorkQueue<Frame>> queue_;
  std::thread worker_;
  std::unique_ptr<boost::asio::thread_pool> prepare_pool_;  // ~prepare_threads > 0: prepares frames ahead
  std::mutex session_mutex_;
  int requested_session_ = -1;  // guarded by session_mutex_; -1: none
  int next_free_session_ = 0;   // guarded by session_mutex_: active_session's next_session
  bool had_request_ = false;    // guarded by session_mutex_: an active_session request was taken
  // Paused by the operator: the worker drops each frame (counted, its stamp passed over).
  std::atomic<bool> paused_{false};
  std::atomic<long> dropped_paused_{0};
  std::mutex pause_mutex_;  // serialises pause / resume calls and finish_session's pause
  bool paused_by_finish_ = false;  // guarded by pause_mutex_: an ACTIVE active_session resumes

  // Pairing state, written by the callbacks under pairing_mutex_.
  std::mutex pairing_mutex_;
  std::deque<Pending> pending_;
  // Stamps of the images pairing skipped since the last frame pushed: the next one carries them.
  std::vector<double> skipped_stamps_;
  // The recent camera_infos, in arrival order.
  std::deque<sensor_msgs::CameraInfoConstPtr> infos_;
  // The calibration of ~camera_info_url (null without one), and whether images use it: once an
  // image has waited its longest with no camera_info ever received.
  sensor_msgs::CameraInfoConstPtr fallback_info_;
  std::atomic<bool> fallback_in_use_{false};
  std::unique_ptr<core::AltitudeBuffer> altitudes_;  // with the altitude topic
  std::atomic<long> no_camera_info_{0}, no_altitude_{0}, altitude_clears_{0};
  ros::WallTimer pairing_timer_;

  // Arrivals, written by the callbacks (wall seconds of the last one, 0 = never).
  std::atomic<long> images_in_{0}, infos_in_{0}, ranges_in_{0};
  // Altitude readings refused (NaN, <= 0, outside the sensor's range or above
  // slam/odometry/max_altitude_m), and of those above max_altitude_m: the offline odometry's
  // "above odometry.max_altitude_m" count, live.
  std::atomic<long> ranges_refused_{0}, ranges_above_max_{0};
  std::atomic<double> last_image_{0.0}, last_info_{0.0}, last_range_{0.0};
  // Images since the last altitude, and the wall time of the first of them: the altitude topic is
  // silent when images have kept coming without one for ~input_timeout_s (a pause of every input
  // is not a silent altitude).
  std::atomic<long> images_since_range_{0}, images_since_sync_{0};
  std::atomic<double> first_image_since_range_{0.0}, first_image_since_sync_{0.0};
  const double started_ = wallNow();

  // The worker's counters as last published, for the diagnostics thread.
  std::mutex stats_mutex_;
  Counters published_;  // guarded by stats_mutex_
  std::unique_ptr<diagnostic_updater::Updater> updater_;
  ros_diagnostics::CounterStatus diagnostic_status_;  // used by the updater's thread only
  ros::WallTimer watchdog_;
  // How images come, decided in onInit before any callback (chooseImageTransport).
  std::string image_topic_, image_transport_;
  bool builtin_decoder_ = false;

  // Worker-only state.
  std::unique_ptr<core::ImageHasher> hasher_;          // each keyframe's hash, paper (6)(7), for the Keyframe message
  std::unique_ptr<core::SegmentedOdometry> odometry_;  // the stream's odometry, a new session on tracking loss
  core::CameraIntrinsics camera_;
  int session_ = 0;
  int frame_index_ = 0;
  std::unique_ptr<core::StampGuard> stamps_;
  Counters counts_;
  ros::WallTime last_stats_;

  ros::Publisher keyframe_pub_, pose_pub_;
  ros::ServiceServer pause_srv_, resume_srv_;
  std::unique_ptr<image_transport::ImageTransport> it_;
  image_transport::Publisher keyframe_image_pub_;
  // Subscribers last: destroyed first, so no callback runs into destroyed members.
  ros::Subscriber session_sub_;
  image_transport::Subscriber image_sub_;
  ros::Subscriber compressed_sub_;  // the built-in decoder's subscription (instead of image_sub_)
  ros::Subscriber info_sub_;
  ros::Subscriber range_sub_, nav_sub_;
  std::mutex nav_mutex_;  // guards nav_ and last_nav_wall_
  std::condition_variable nav_cv_;  // a nav reading was appended
  core::NavTrack nav_;
  ros::WallTime last_nav_wall_;  // when the last reading was appended (zero: none yet)
  std::atomic<long> nav_in_{0}, nav_refused_{0};
  std::unique_ptr<tf2_ros::Buffer> tf_buffer_;  // ~nav_source tf
  std::unique_ptr<tf2_ros::TransformListener> tf_listener_;
  std::string odom_frame_, base_frame_;
  std::optional<core::Pose2> last_tf_nav_;  // the last tf nav pose and the distance travelled to it
  double tf_nav_distance_m_ = 0.0;
};

}  // namespace nodelets
}  // namespace uw_multislam
