// The odometry nodelet's options: its own parameters (~ private; config/default.yaml and
// doc/ros_api.md document each), the SLAM configuration it runs, the frames and the
// fallback calibration (the sensors' mount comes from tf at the first frame, ros/camera_mount.h), read and validated
// once by odometryNodeletOptions() (the nodelet never reads a parameter itself; ros_params::Params checks each
// value's type). Tested in gtest TypedParams and ConfigDefaults, rostests bad_input and bad_params (each refusal
// names the key).
#pragma once

#include <ros/node_handle.h>
#include <sensor_msgs/CameraInfo.h>

#include <cstddef>
#include <string>
#include <vector>

#include "uw_multislam/core/frontend/input_pairing.h"
#include "uw_multislam/core/frontend/stamp_guard.h"
#include "uw_multislam/core/geometry/vehicle_frame.h"
#include "uw_multislam/core/session/slam_config.h"
#include "uw_multislam/ros/camera_mount.h"
#include "uw_multislam/ros/nav_input.h"
#include "uw_multislam/ros/sensor_conversions.h"
#include "uw_multislam/ros/topics.h"
#include "uw_multislam/ros/typed_params.h"

namespace uw_multislam {
namespace ros_params {

/// Each default is written once: here, or where the options are handed on (core::InputPairingOptions for the
/// pairing, ros_inputs::NavInputOptions for the nav, ros_frames::MountOptions and topics.h for frames/).
struct OdometryNodeletOptions {
  std::string image_transport = "raw";  // image_transport's own ~image_transport (ImageInput), type-checked here
  bool use_altitude_topic = core::InputPairingOptions().altitude_topic;
  double altitude_m = core::InputPairingOptions().fixed_altitude_m;  // used when use_altitude_topic is false
  int queue_size = 5;                                                // frames waiting for the worker
  std::string drop_policy = "newest";  // newest: the newest safe frame is taken (core::FrameSkipRule); oldest: FIFO
  int prepare_threads = 0;             // threads preparing frames ahead (newest: on arrival; oldest: those waiting)
  double stale_fraction = 0.25;        // newest: wait for the next frame rather than start one older than this
                                       // fraction of the input period (core::waitForNext; 1: never)
  bool keyframe_lookahead = true;  // newest only: keyframes ahead of frames that will wait (core::keyframeLookaheadS)
  int sync_queue_size = 10;        // subscriber queues; 2x: images waiting for their pairing
  // Largest image - camera_info stamp difference.
  double sync_max_interval_s = core::InputPairingOptions().sync_max_interval_s;
  // Altitude: largest gap interpolated / age used alone; longest wait.
  double altitude_max_age_s = core::InputPairingOptions().altitude_max_age_s;
  int session = 0;                                                 // id of the first session
  double session_gap_s = core::StampGuardOptions().session_gap_s;  // forward jumps shorter never start a session
  // ... nor shorter than this many of the camera's frame periods (core::StampGuard).
  double session_gap_periods = core::StampGuardOptions().gap_periods;
  // Stamps at most this far back are late frames (skipped).
  double reorder_tolerance_s = core::InputPairingOptions().reorder_tolerance_s;
  // Images without a synchronised set this long: warn.
  double input_timeout_s = core::InputPairingOptions().input_timeout_s;
  // > 0: used when the altitude topic is silent; 0 = off.
  double fallback_altitude_m = core::InputPairingOptions().fallback_altitude_m;
  double diagnostic_period_s = 1.0;
  double stats_period_s = 30.0;
  // Larger images are skipped before any conversion (counted).
  int max_image_pixels = static_cast<int>(ros_conversions::kDefaultMaxImagePixels);
  // topic: nav/odom (nav_msgs/Odometry); tf: odom -> base_link; none.
  std::string nav_source = ros_inputs::NavInputOptions().source;
  double nav_tf_wait_s = ros_inputs::NavInputOptions().tf_wait_s;        // tf: how long a frame waits for its transform
  double nav_wait_s = ros_inputs::NavInputOptions().wait_s;              // topic: how long a newer frame waits
  double nav_tf_drift = ros_inputs::NavInputOptions().tf_drift;          // tf: sigma_xy = this x the distance
  double nav_tf_yaw_drift = ros_inputs::NavInputOptions().tf_yaw_drift;  // tf: sigma_yaw = this (rad/m) x distance
  double nav_buffer_s = ros_inputs::NavInputOptions().buffer_s;          // nav readings kept this long behind
  bool nav_world_fixed = false;   // the nav's frame never resets: new sessions placed by it (core::NavPlacer)
  bool rectified_images = false;  // the images are rectified: P, no distortion; else K with D
  std::string camera_info_url;    // calibration used when no camera_info arrives; empty = none
  // The shared frames/ (ros_params::readFrames).
  std::string session_frame_prefix = topics::kDefaultSessionFramePrefix;
  std::string odom_frame = frames::kDefaultOdomFrame, base_frame = frames::kDefaultBaseFrame;
  double mount_wait_s = ros_frames::MountOptions().wait_s;  // the first frame waits this long for the mount in tf
  double max_camera_tilt_deg = ros_frames::MountOptions().max_tilt_deg;  // a more tilted camera is refused

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
  /// The stamp rules (~reorder_tolerance_s, ~session_gap_s, ~session_gap_periods).
  core::StampGuardOptions stamps() const { return {reorder_tolerance_s, session_gap_s, session_gap_periods}; }
};

/// Reads and validates the odometry nodelet's parameters (`nh`: the pipeline's namespace, `pnh`:
/// the node's private one); std::invalid_argument naming the key for a bad value.
OdometryNodeletOptions odometryNodeletOptions(const Params& nh, const Params& pnh);
/// The same from the parameter server; first warns about an old config file's block
/// (ros_params::warnAboutFormerPrivateNamespace).
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
