// What the odometry nodelet's worker says about a frame: each outcome counted in OdometryCounters
// and logged once (throttled), with the same words in every place it can happen.
#pragma once

#include <string>

#include "uw_multislam/core/frontend/input_pairing.h"
#include "uw_multislam/core/frontend/odometry.h"
#include "uw_multislam/core/frontend/stamp_guard.h"
#include "uw_multislam/core/session/frame_stream.h"
#include "uw_multislam/ros/camera_mount.h"
#include "uw_multislam/ros/odometry_counters.h"

namespace uw_multislam {
namespace ros_diagnostics {

/// An image the pairing skipped: no camera_info within `bound_s` of its stamp (`no_camera_info`), or no altitude
/// reading within `bound_s`; logged with the count so far.
void reportUnpaired(bool no_camera_info, double stamp_s, double bound_s, const core::InputPairingCounts& n);

/// A frame refused before the odometry (its image or camera_info; `counter`, e.g. skipped_encoding), counted and
/// logged with `why`.
void reportRefusal(long OdometryCounters::*counter, const std::string& why, OdometryCounters* c);

/// The sensors' mount from tf for a frame: unresolved, the frame is skipped (false), counted and logged (no
/// tracking without a mount: there is no default one); resolved for the first time, logged; moved, counted and
/// warned (the new one is used).
bool reportMount(const ros_frames::SensorMount::Lookup& mount, OdometryCounters* c);

/// What the front end did with a frame (`r`), logged: a skipped stamp, a jump, the odometry's answer
/// (reportUpdate), sessions started and closed by tracking loss (`loss`: the rule), the nav's placements; the
/// stream's counts copied into `c`.
void reportFrame(const core::FrameResult& r, const core::FrameStream& stream, const core::TrackingLossOptions& loss,
                 OdometryCounters* c);

/// A frame's altitude that is not a fresh reading: the fixed fallback (the altitude topic `topic` silent for
/// `timeout_s`) or an invalid reading replaced by the last valid one.
void reportAltitude(core::PairedAltitude kind, double altitude_m, double stamp_s, const std::string& topic,
                    double timeout_s, OdometryCounters* c);

/// The odometry's answer for a frame: nav and fused motions, an implausible nav reading, a skip, a fallback.
/// Returns true when the frame moved the odometry (not skipped).
bool reportUpdate(const core::OdometryUpdate& u, OdometryCounters* c);

}  // namespace ros_diagnostics
}  // namespace uw_multislam
