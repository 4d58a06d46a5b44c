// The odometry nodelet's options: its own parameters (~ private; config/default.yaml and
// doc/ros_api.md document each), the SLAM configuration it runs, the frames and the
// fallback calibration (the sensors' mount comes from tf at the first frame, ros/camera_mount.h), read and validated
// once by odometryNodeletOptions() (the nodelet never reads a parameter itself). Tested in rostest bad_input (each
// refusal names the key).
#pragma once

#include <ros/node_handle.h>
#include <sensor_msgs/CameraInfo.h>

#include <cstddef>
#include <string>
#include <vector>

#include "uw_multislam/core/frontend/input_pairing.h"
#include "uw_multislam/core/geometry/vehicle_frame.h"
#include "uw_multislam/core/session/slam_config.h"
#include "uw_multislam/ros/nav_input.h"
#include "uw_multislam/ros/topics.h"

namespace uw_multislam {
namespace ros_params {

struct OdometryNodeletOptions {
  bool use_altitude_topic = true;
  double altitude_m = 0.0;             // used when use_altitude_topic is false
  int queue_size = 5;                  // frames waiting for the worker
  std::string drop_policy = "newest";  // newest: the newest safe frame is taken (core::FrameSkipRule); oldest: FIFO
  int prepare_threads = 0;             // threads preparing frames ahead (newest: on arrival; oldest: those waiting)
  double stale_fraction = 0.25;        // newest: wait for the next frame rather than start one older than this
                                       // fraction of the input period (core::waitForNext; 1: never)
  bool keyframe_lookahead = true;    // newest only: keyframes ahead of frames that will wait (core::keyframeLookaheadS)
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
  int max_image_pixels = 25000000;   // larger images are skipped before any conversion (counted)
  std::string nav_source = "topic";  // topic: nav/odom (nav_msgs/Odometry); tf: odom -> base_link; none
  double nav_tf_wait_s = 0.05;       // tf: how long a frame waits for its transform
  double nav_wait_s = 0.05;          // topic: how long a frame newer than the newest reading waits
  double nav_tf_drift = 0.01;        // tf: sigma_xy = this x the distance travelled
  double nav_tf_yaw_drift = 0.001;   // tf: sigma_yaw = this (rad/m) x the distance travelled
  double nav_buffer_s = 60.0;        // nav readings kept this long behind the newest
  bool nav_world_fixed = false;      // the nav's frame never resets: new sessions placed by it (NavSessionPlacer)
  bool rectified_images = false;     // the images are rectified: P, no distortion; else K with D
  std::string camera_info_url;       // calibration used when no camera_info arrives; empty = none
  std::string session_frame_prefix = topics::kDefaultSessionFramePrefix;
  std::string odom_frame = "odom", base_frame = "base_link";  // frames/ (~nav_source tf)

  double mount_wait_s = 2.0;         // frames/mount_wait_s: the first frame waits this long for the mount in tf
  double max_camera_tilt_deg = 5.0;  // frames/max_camera_tilt_deg: a more tilted camera is refused

  core::SlamConfig config;                               // slam/ (config/slam.yaml), validated
  sensor_msgs::CameraInfoConstPtr fallback_camera_info;  // from camera_info_url (null without one)

  /// The worker's queue of frames: ~queue_size with oldest; with newest core::newestCapacity(queue_size), deeper,
  /// so that the skip rule (core::FrameSkipRule), not a full queue, decides which frames are passed over.
  std::size_t workerQueueSize() const;
  /// The input subscribers' queues: ~sync_queue_size, and at least core::newestCapacity(queue_size) with either
  /// policy, so that a stalled callback thread does not make roscpp drop images: a run of those, uncounted, is a
  /// gap in the stamps the node cannot tell from an outage (a false session), where the worker's own queue drops
  /// them counted, their stamps handed on (and with newest the skip rule sees every one).
  int inputQueueSize() const;
  /// The pairing rules these options give (core::InputPairing).
  core::InputPairingOptions pairing() const;
  /// The nav input's options (~nav_*, frames/).
  ros_inputs::NavInputOptions nav() const;
};

/// Reads and validates the odometry nodelet's parameters (`nh`: the pipeline's namespace, `pnh`:
/// the node's private one); std::invalid_argument naming the key for a bad value.
OdometryNodeletOptions odometryNodeletOptions(const ros::NodeHandle& nh, const ros::NodeHandle& pnh);

/// The start-up log lines: the effective options.
std::vector<std::string> describe(const OdometryNodeletOptions& o);

/// The resolved names of the odometry's inputs, for the messages.
struct InputTopics {
  std::string image, transport, camera_info, altitude;
};
/// The warning for a silent input (core::InputPairing::silence); empty for kNone.
std::string silenceMessage(const core::InputSilence& silence, const OdometryNodeletOptions& o,
                           const InputTopics& topics);

}  // namespace ros_params
}  // namespace uw_multislam
