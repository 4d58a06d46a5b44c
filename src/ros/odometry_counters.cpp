#include "uw_multislam/ros/odometry_counters.h"

#include <cstdio>

namespace uw_multislam {
namespace ros_diagnostics {

const CounterTable<OdometryCounters>& odometryCounterTable() {
  using C = OdometryCounters;
  constexpr bool kWarn = true;  // a drop or a skip: the status WARNs while it grows
  static const CounterTable<C> table = {
      {"images_received", &C::images_received, "images received (raw or compressed)"},
      {"camera_infos_received", &C::camera_infos_received, "camera_info messages received"},
      {"altitudes_received", &C::altitudes_received, "altitude readings received"},
      // Readings, not frames: an altimeter without bottom lock (the descent) refuses readings no
      // frame may use; the frames that do use one are the WARN (bad_altitude_replaced).
      {"altitudes_refused", &C::altitudes_refused,
       "altitude readings refused: NaN, <= 0, outside the sensor's range or above slam/odometry/max_altitude_m"},
      {"altitudes_above_max_altitude", &C::altitudes_above_max_altitude,
       "of the refused readings, those above slam/odometry/max_altitude_m"},
      {"frames_synchronised", &C::frames_synchronised,
       "images paired with their camera_info and altitude, pushed onto the worker's FIFO"},
      {"images_not_paired", &C::images_not_paired,
       "images not paired (skipped for want of a camera_info or an altitude, or still waiting)"},
      {"images_waiting_pairing", &C::images_waiting_pairing, "images waiting for their camera_info or altitude now"},
      {"skipped_no_camera_info", &C::skipped_no_camera_info,
       "images skipped: no camera_info within ~sync_max_interval_s of their stamp", kWarn},
      {"skipped_no_altitude", &C::skipped_no_altitude,
       "images skipped: no altitude reading within ~altitude_max_age_s of their stamp", kWarn},
      {"altitude_stamps_jumped_back", &C::altitude_stamps_jumped_back,
       "altitude stamps jumped back (a bag that loops, a clock reset): the earlier readings dropped"},
      {"frames_processed", &C::frames_processed, "frames the worker took (finished or in progress)"},
      {"frames_finished", &C::frames_finished, "frames the worker is done with (published or skipped)"},
      {"dropped_queue_full", &C::dropped_queue_full, "frames the worker's queue dropped when full (the oldest)", kWarn},
      // Deliberate (bounded latency); the WARN is the budget's, while the input outruns the odometry.
      {"skipped_for_newest", &C::skipped_for_newest,
       "frames the worker passed over for a newer one it could safely take (~drop_policy newest: it was behind)"},
      {"waits_for_fresher", &C::waits_for_fresher,
       "times the worker waited for the next frame rather than start one that had waited over ~stale_fraction of "
       "an input period (when the next one came, the stale one was skipped: skipped_for_newest)"},
      {"paused", &C::paused, "1 while paused by the operator (services pause, resume), else 0"},
      {"frames_dropped_paused", &C::frames_dropped_paused,
       "frames the worker dropped while paused, among the finished"},
      {"queue_length", &C::queue_length, "frames waiting in the worker's queue"},
      {"skipped_empty_image", &C::skipped_empty_image, "frames skipped: an empty image", kWarn},
      {"skipped_encoding", &C::skipped_encoding,
       "frames skipped: an encoding the odometry cannot use (float, YUV, ...), or a compressed format neither jpeg "
       "nor png",
       kWarn},
      {"skipped_corrupt_image", &C::skipped_corrupt_image, "frames skipped: a compressed image that does not decode",
       kWarn},
      {"skipped_image_layout", &C::skipped_image_layout,
       "frames skipped: a step or data size that does not fit the image", kWarn},
      {"skipped_tiny_image", &C::skipped_tiny_image, "frames skipped: an image under 32 px in either direction", kWarn},
      {"skipped_image_too_large", &C::skipped_image_too_large,
       "frames skipped: more than ~max_image_pixels pixels, by the size the header declares", kWarn},
      {"skipped_size_mismatch", &C::skipped_size_mismatch, "frames skipped: the image size differs from camera_info's",
       kWarn},
      {"skipped_camera_info", &C::skipped_camera_info,
       "frames skipped: an unusable camera_info (no focal length, principal point outside, zero P for rectified "
       "images, unsupported distortion model)",
       kWarn},
      {"skipped_duplicate_stamp", &C::skipped_duplicate_stamp, "frames skipped: the stamp of the frame before", kWarn},
      {"skipped_out_of_order", &C::skipped_out_of_order,
       "frames skipped: a stamp up to ~reorder_tolerance_s before the last frame's", kWarn},
      {"skipped_by_odometry", &C::skipped_by_odometry, "frames the core odometry skipped (e.g. no valid altitude yet)",
       kWarn},
      {"skipped_no_mount", &C::skipped_no_mount,
       "frames refused: no base_link -> camera (image frame_id) or -> altimeter (Range frame_id) transform in tf, or "
       "a tilted camera (the status is ERROR while they are)",
       kWarn},
      {"mount_changes", &C::mount_changes,
       "times the sensors' mount in tf moved after it was found (a second mount publisher?): the new one is used",
       kWarn},
      {"bad_altitude_replaced", &C::bad_altitude_replaced,
       "frames whose altitude would use an invalid reading: the last valid altitude is used", kWarn},
      {"fixed_altitude_frames", &C::fixed_altitude_frames,
       "frames processed at ~fallback_altitude while the altitude topic is silent", kWarn},
      {"time_jumps_back", &C::time_jumps_back,
       "image stamps jumped back by more than ~reorder_tolerance_s: a new session", kWarn},
      {"time_jumps_forward", &C::time_jumps_forward,
       "image stamps jumped forward by more than ~session_gap_s and ~session_gap_periods frame periods: a new "
       "session",
       kWarn},
      {"fallbacks", &C::fallbacks, "frames given the previous motion again (no match; paper section 5)", kWarn},
      {"tracking_losses", &C::tracking_losses, "sessions closed by the tracking-loss rule", kWarn},
      {"dense_tries", &C::dense_tries, "dense registrations tried where the normal one failed (slam/odometry/dense)"},
      {"dense_matches", &C::dense_matches, "dense registrations accepted: frames kept in the session"},
      {"restarts", &C::restarts,
       "tracking losses where a frame registers only with the unmatched frame before it: the next session starts "
       "there",
       kWarn},
      {"visual_bridges", &C::visual_bridges,
       "pieces after a tracking loss joined to the piece before by registering a keyframe with its last one "
       "(slam/tracking/rejoin_keyframes)"},
      {"nav_received", &C::nav_received, "nav/odom readings received (~nav_source topic)"},
      {"nav_refused", &C::nav_refused,
       "nav readings refused: frames other than odom / odom_ned and base_link / base_link_frd, not finite, a "
       "negative variance, a zero stamp or not after the last one",
       kWarn},
      {"nav_covariance_replaced", &C::nav_covariance_replaced,
       "nav readings whose covariance did not grow over 2 m travelled (constant or zero): the drift model's sigmas "
       "used (~nav_tf_drift)",
       kWarn},
      {"frames_with_nav", &C::frames_with_nav, "frames given a nav pose"},
      {"nav_motions", &C::nav_motions, "motions taken from the nav (vision failed, or the gate refused its motion)"},
      {"fused_motions", &C::fused_motions, "visual motions fused with the nav's (slam/odometry/nav/fuse)"},
      {"nav_implausible", &C::nav_implausible,
       "frames whose nav step was too fast to be a motion (slam/odometry/nav/max_speed_m_s): nav not used", kWarn},
      {"nav_placements_refused", &C::nav_placements_refused,
       "new pieces or sessions not placed by the nav: its step across the gap from the last accepted reading is "
       "no motion of the vehicle (slam/odometry/nav/max_speed_m_s, max_yaw_rate_rad_s)",
       kWarn},
      {"nav_tf_missing", &C::nav_tf_missing, "frames without the odom -> base_link transform (~nav_source tf)", kWarn},
      {"prepared_ahead", &C::prepared_ahead,
       "frames prepared (conversion, enhancement, features) ahead on another thread (~prepare_threads)"},
      {"sessions", &C::sessions, "sessions started"},
      {"session", &C::session, "the current session's id"},
      {"keyframes", &C::keyframes, "keyframes published"},
      {"early_keyframes", &C::early_keyframes,
       "keyframes made ahead of the keyframe rule, at a frame processed while behind, because the rule would take a "
       "frame that would wait behind a newer one (~keyframe_lookahead)"},
      {"ms_per_frame_mean", &C::ms_per_frame_mean, "mean time per finished frame, ms"},
      {"ms_per_frame_max", &C::ms_per_frame_max, "longest time of a frame, ms"},
      {"ms_last_frame", &C::ms_last_frame, "time of the last frame, ms"},
      {"ms_per_frame_recent", &C::ms_per_frame_recent, "the budget: mean time of the last ~20 frames, ms"},
      {"input_period_ms", &C::input_period_ms,
       "mean interval between the last ~20 paired frames' arrivals, ms (WARN while ms_per_frame_recent is above it)"},
  };
  return table;
}

void setPairingCounters(const core::InputPairingCounts& in, std::size_t waiting, OdometryCounters* c) {
  c->images_received = in.images;
  c->camera_infos_received = in.camera_infos;
  c->altitudes_received = in.altitudes;
  c->skipped_no_camera_info = in.skipped_no_camera_info;
  c->skipped_no_altitude = in.skipped_no_altitude;
  c->altitude_stamps_jumped_back = in.altitude_clears;
  c->images_waiting_pairing = static_cast<long>(waiting);
}

std::string budgetProblem(const OdometryCounters& c, const std::string& drop_policy, bool arriving) {
  if (!arriving || c.input_period_ms <= 0 || c.ms_per_frame_recent <= c.input_period_ms) return "";
  char line[320];
  std::snprintf(line, sizeof(line),
                "the input outruns the odometry: %.1f ms per frame against an input period of %.1f ms (%s: %ld "
                "frames skipped for a newer one, %ld dropped from a full queue so far)",
                c.ms_per_frame_recent, c.input_period_ms,
                drop_policy == "newest" ? "the newest frame that is safe to take" : "every frame in order",
                c.skipped_for_newest, c.dropped_queue_full);
  return line;
}

long OdometryCounters::*imageRefusalCounter(ros_conversions::ImageRefusal refusal) {
  using R = ros_conversions::ImageRefusal;
  switch (refusal) {
    case R::kEmpty:
      return &OdometryCounters::skipped_empty_image;
    case R::kTooSmall:
      return &OdometryCounters::skipped_tiny_image;
    case R::kLayout:
      return &OdometryCounters::skipped_image_layout;
    case R::kCorrupt:
      return &OdometryCounters::skipped_corrupt_image;
    case R::kTooLarge:
      return &OdometryCounters::skipped_image_too_large;
    case R::kSizeMismatch:
      return &OdometryCounters::skipped_size_mismatch;
    default:
      return &OdometryCounters::skipped_encoding;
  }
}

}  // namespace ros_diagnostics
}  // namespace uw_multislam
