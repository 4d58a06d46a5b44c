#include "uw_multislam/ros/odometry_reports.h"

#include <ros/console.h>

namespace uw_multislam {
namespace ros_diagnostics {

void reportUnpaired(bool no_camera_info, double stamp_s, double bound_s, const core::InputPairingCounts& n) {
  if (no_camera_info)
    ROS_WARN_THROTTLE(5,
                      "odometry: image at %.3f skipped: no camera_info within ~sync_max_interval_s %.3f s of its stamp "
                      "(%ld so far)",
                      stamp_s, bound_s, n.skipped_no_camera_info);
  else
    ROS_WARN_THROTTLE(5,
                      "odometry: image at %.3f skipped: no altitude reading within ~altitude_max_age_s %.2f s of its "
                      "stamp (%ld so far)",
                      stamp_s, bound_s, n.skipped_no_altitude);
}

void reportRefusal(long OdometryCounters::*counter, const std::string& why, OdometryCounters* c) {
  ++(c->*counter);
  const long so_far = counter == &OdometryCounters::skipped_camera_info ? c->skipped_camera_info : c->badImages();
  ROS_WARN_THROTTLE(5, "odometry: frame skipped: %s (%ld so far)", why.c_str(), so_far);
}

// Counted before logging: a throttled log line does not evaluate its arguments.
bool reportStamp(core::StampClass timing, double stamp_s, double last_s, OdometryCounters* c) {
  switch (timing) {
    case core::StampClass::kDuplicate: {
      const long n = ++c->skipped_duplicate_stamp;
      ROS_WARN_THROTTLE(5, "odometry: frame skipped: stamp %.6f seen before (duplicated frame; %ld so far)", stamp_s,
                        n);
      return true;
    }
    case core::StampClass::kOutOfOrder: {
      const long n = ++c->skipped_out_of_order;
      ROS_WARN_THROTTLE(
          5, "odometry: frame skipped: stamp %.6f is %.3f s before the last frame's (out of order; %ld so far)",
          stamp_s, last_s - stamp_s, n);
      return true;
    }
    default:
      return false;
  }
}

bool reportMount(const ros_frames::SensorMount::Lookup& mount, OdometryCounters* c) {
  if (mount.state != ros_frames::SensorMount::State::kResolved) {
    const long n = ++c->skipped_no_mount;
    ROS_ERROR_THROTTLE(5, "odometry: frame skipped, tracking does not start: %s (%ld frames so far)",
                       mount.message.c_str(), n);
    return false;
  }
  if (mount.fresh) ROS_INFO("odometry: sensor mount %s", mount.message.c_str());
  return true;
}

void reportJump(core::StampClass timing, double jump_s, OdometryCounters* c) {
  if (timing == core::StampClass::kJumpBack) {
    ++c->time_jumps_back;
    ROS_WARN("odometry: image stamps jumped back by %.3f s (a bag that loops, or a clock reset)", -jump_s);
  } else {
    ++c->time_jumps_forward;
    ROS_INFO("odometry: image stamps jumped forward by %.3f s (a gap in the images)", jump_s);
  }
}

void reportAltitude(core::PairedAltitude kind, double altitude_m, double stamp_s, const std::string& topic,
                    double timeout_s, OdometryCounters* c) {
  if (kind == core::PairedAltitude::kFallback) {
    const long n = ++c->fixed_altitude_frames;
    ROS_WARN_THROTTLE(10,
                      "odometry: no altitude on %s for %.0f s: the fixed ~fallback_altitude %.2f m is used (%ld frames "
                      "so far)",
                      topic.c_str(), timeout_s, altitude_m, n);
  } else if (kind == core::PairedAltitude::kInvalidReading) {
    const long n = ++c->bad_altitude_replaced;
    ROS_WARN_THROTTLE(5,
                      "odometry: the altitude at %.3f would use an invalid reading (NaN, <= 0 or out of range): the "
                      "last valid altitude is used (%ld so far)",
                      stamp_s, n);
  }
}

bool reportUpdate(const core::OdometryUpdate& u, OdometryCounters* c) {
  const bool done = u.status != core::FrameStatus::kSkipped;
  c->nav_motions += done && u.source == core::MotionSource::kNav;
  c->fused_motions += done && u.source == core::MotionSource::kFused;
  c->early_keyframes += u.early_keyframe;
  if (!u.nav_note.empty()) {
    ++c->nav_implausible;
    ROS_WARN_THROTTLE(5, "odometry: frame %d: %s", u.index, u.nav_note.c_str());
  }
  if (!done) {
    ++c->skipped_by_odometry;
    ROS_WARN_THROTTLE(5, "odometry: frame %d skipped: %s", u.index, u.reason.c_str());
  } else if (u.status == core::FrameStatus::kFallback) {
    ++c->fallbacks;
    ROS_WARN_THROTTLE(5, "odometry: frame %d: fallback motion (%s)", u.index, u.reason.c_str());
  }
  return done;
}

}  // namespace ros_diagnostics
}  // namespace uw_multislam
