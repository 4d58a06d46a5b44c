#include "uw_multislam/ros/odometry_reports.h"

#include <ros/console.h>

#include "uw_multislam/ros/sensor_conversions.h"

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

bool reportMount(const ros_frames::SensorMount::Lookup& mount, OdometryCounters* c) {
  if (mount.state != ros_frames::SensorMount::State::kResolved) {
    const long n = ++c->skipped_no_mount;
    ROS_ERROR_THROTTLE(5, "odometry: frame skipped, tracking does not start: %s (%ld frames so far)",
                       mount.message.c_str(), n);
    return false;
  }
  if (mount.fresh) ROS_INFO("odometry: sensor mount %s", mount.message.c_str());
  if (mount.changed) {
    ++c->mount_changes;
    ROS_WARN(
        "odometry: the sensors' mount %s: the new one is used from this frame on (the vehicle's pose and the "
        "camera's altitude move with it; a second mount publisher? mount_changes %ld)",
        mount.message.c_str(), c->mount_changes);
  }
  return true;
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

void reportFrame(const core::FrameResult& r, const core::FrameStream& stream, const core::TrackingLossOptions& loss,
                 OdometryCounters* c) {
  const core::FrameStreamCounts& n = stream.counts();
  c->skipped_duplicate_stamp = n.duplicates, c->skipped_out_of_order = n.out_of_order;
  c->time_jumps_back = n.jumps_back, c->time_jumps_forward = n.jumps_forward;
  c->sessions = n.sessions, c->tracking_losses = n.tracking_losses;
  c->nav_placements_refused = n.placements_refused;
  c->dense_tries = n.dense_tries, c->dense_matches = n.dense_matches, c->restarts = n.restarts;
  c->visual_bridges = n.bridges;
  const double stamp_s = stream.stamps().last();
  if (r.timing == core::StampClass::kDuplicate)
    ROS_WARN_THROTTLE(5, "odometry: frame skipped: stamp %.6f seen before (duplicated frame; %ld so far)", stamp_s,
                      n.duplicates);
  if (r.timing == core::StampClass::kOutOfOrder)
    ROS_WARN_THROTTLE(5,
                      "odometry: frame skipped: its stamp is up to ~reorder_tolerance_s before %.6f (out of "
                      "order; %ld so far)",
                      stamp_s, n.out_of_order);
  if (r.skipped_stamp) return;
  if (r.timing == core::StampClass::kJumpBack)
    ROS_WARN("odometry: image stamps jumped back by %.3f s (a bag that loops, or a clock reset)", -r.jump_s);
  if (r.timing == core::StampClass::kJumpForward)
    ROS_INFO("odometry: image stamps jumped forward by %.3f s (a gap in the images beyond %.1f s)", r.jump_s,
             stream.stamps().gapThreshold());
  for (const std::string& line : r.warnings) ROS_WARN("odometry: %s", line.c_str());
  c->frames_with_nav += r.with_nav;
  reportUpdate(r.update, c);
  if (r.started) {
    const core::Odometry* odo = stream.odometry() ? stream.odometry()->odometry() : nullptr;
    ROS_INFO("odometry: session %d starts (%s), camera %s", r.started->session, r.started->why.c_str(),
             odo ? ros_conversions::describeCamera(odo->camera()).c_str() : "?");
  }
  for (const std::string& line : r.notes) ROS_INFO("odometry: %s", line.c_str());
  for (const core::FrameResult::Ended& e : r.ended)
    if (e.cause == core::SessionEnd::kTrackingLoss)
      ROS_WARN(
          "odometry: tracking lost at frame %d (%s): session %d closed; the next session starts at a frame with %d "
          "features",
          r.update.index, e.why.c_str(), e.session, loss.min_features);
}

}  // namespace ros_diagnostics
}  // namespace uw_multislam
