// The odometry nodelet's counters (/diagnostics status "<node>: odometry", and its periodic and
// shutdown log lines): one field each, named once in odometryCounterTable() with its help text;
// doc/diagnostics.md documents them and test/ros/test_diagnostics.cpp checks it against the table.
#pragma once

#include <cstddef>
#include <string>

#include "uw_multislam/core/frontend/input_pairing.h"
#include "uw_multislam/ros/diagnostics.h"
#include "uw_multislam/ros/sensor_conversions.h"

namespace uw_multislam {
namespace ros_diagnostics {

struct OdometryCounters {
  // Inputs and their pairing (core::InputPairing, the callbacks).
  long images_received = 0, camera_infos_received = 0, altitudes_received = 0;
  long altitudes_refused = 0, altitudes_above_max_altitude = 0;
  long frames_synchronised = 0, images_not_paired = 0, images_waiting_pairing = 0;
  long skipped_no_camera_info = 0, skipped_no_altitude = 0, altitude_stamps_jumped_back = 0;
  // The worker's FIFO.
  long frames_processed = 0, frames_finished = 0, dropped_queue_full = 0, skipped_for_newest = 0, queue_length = 0;
  long paused = 0, frames_dropped_paused = 0;
  long waits_for_fresher = 0;  // takes that waited for the next frame (core::waitForNext)
  // Frames the worker skipped, by kind (the image refusals of ros/sensor_conversions.h, stamps).
  long skipped_empty_image = 0, skipped_encoding = 0, skipped_corrupt_image = 0, skipped_image_layout = 0;
  long skipped_tiny_image = 0, skipped_image_too_large = 0, skipped_size_mismatch = 0, skipped_camera_info = 0;
  long skipped_duplicate_stamp = 0, skipped_out_of_order = 0, skipped_by_odometry = 0, skipped_no_mount = 0;
  // Altitude, sessions and motions.
  long bad_altitude_replaced = 0, fixed_altitude_frames = 0, time_jumps_back = 0, time_jumps_forward = 0;
  long fallbacks = 0, tracking_losses = 0, dense_tries = 0, dense_matches = 0, restarts = 0, visual_bridges = 0;
  long nav_received = 0, nav_refused = 0, frames_with_nav = 0, nav_motions = 0, fused_motions = 0;
  long nav_implausible = 0, nav_tf_missing = 0, nav_covariance_replaced = 0, prepared_ahead = 0;
  long nav_placements_refused = 0, mount_changes = 0;
  long sessions = 0, session = 0, keyframes = 0, early_keyframes = 0;
  double ms_per_frame_mean = 0.0, ms_per_frame_max = 0.0, ms_last_frame = 0.0;
  double ms_per_frame_recent = 0.0, input_period_ms = 0.0;  // the budget (core::FrameBudget)

  // Not published: the sum of the image refusals, and the time of the finished frames.
  long badImages() const {
    return skipped_empty_image + skipped_encoding + skipped_corrupt_image + skipped_image_layout + skipped_tiny_image +
           skipped_image_too_large + skipped_size_mismatch;
  }
  double total_ms = 0.0;
  void frameTime(double ms) {
    total_ms += ms;
    ms_per_frame_max = ms > ms_per_frame_max ? ms : ms_per_frame_max;
    ms_last_frame = ms;
  }
};

const CounterTable<OdometryCounters>& odometryCounterTable();

/// The pairing's counters (core::InputPairing) into `c`.
void setPairingCounters(const core::InputPairingCounts& in, std::size_t waiting, OdometryCounters* c);

/// The WARN while the input outruns the odometry (its recent ms per frame above the recent input
/// period, `arriving`: frames still come), naming both and what `drop_policy` does; else empty.
std::string budgetProblem(const OdometryCounters& c, const std::string& drop_policy, bool arriving);

/// The counter of an image refusal (ros/sensor_conversions.h), e.g. &OdometryCounters::skipped_encoding.
long OdometryCounters::*imageRefusalCounter(ros_conversions::ImageRefusal refusal);

}  // namespace ros_diagnostics
}  // namespace uw_multislam
