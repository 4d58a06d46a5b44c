// The status topic's parts (ros/slam_status.h): the odometry's state from its counters, the
// back-end's from a session manager, and the two combined; set_mode's words.
#include <gtest/gtest.h>

#include "uw_multislam/ros/backend_conversions.h"
#include "uw_multislam/ros/slam_status.h"

namespace uw_multislam {
namespace ros_status {
namespace {

using uw_multislam::SlamStatus;

constexpr double kTimeout = 5.0;

TEST(SlamStatus, TheOdometryStateFollowsSessionsLossesAndPauses) {
  OdometryStateTracker t;
  ros_diagnostics::OdometryCounters c;
  c.images_received = 3, c.skipped_no_mount = 3;  // frames came, none accepted: no session yet
  SlamStatus s = t.update(c, 0.0, kTimeout);
  EXPECT_EQ(s.state, SlamStatus::NO_INPUT);
  EXPECT_EQ(s.session, -1);
  EXPECT_EQ(s.frames_skipped, 3);
  c.sessions = 1, c.session = 4, c.ms_last_frame = 12.5;
  s = t.update(c, 0.0, kTimeout);
  EXPECT_EQ(s.state, SlamStatus::TRACKING);
  EXPECT_EQ(s.state_name, "tracking");
  EXPECT_EQ(s.session, 4);
  EXPECT_DOUBLE_EQ(s.frame_ms, 12.5);
  EXPECT_EQ(s.map, -1);   // the back-end's part: not the odometry's to say
  c.tracking_losses = 1;  // the frame that closed session 4
  EXPECT_EQ(t.update(c, 0.0, kTimeout).state, SlamStatus::LOST);
  c.skipped_by_odometry = 2;       // frames while lost
  s = t.update(c, 0.4, kTimeout);  // the timer between frames: still lost
  EXPECT_EQ(s.state, SlamStatus::LOST);
  EXPECT_EQ(s.session, 4);  // the closed one, until the next starts
  EXPECT_EQ(s.frames_skipped, 5);
  EXPECT_EQ(s.tracking_losses, 1);
  c.sessions = 2, c.session = 5;  // the seabed is back
  EXPECT_EQ(t.update(c, 0.0, kTimeout).state, SlamStatus::TRACKING);
  c.paused = 1, c.frames_dropped_paused = 1;
  s = t.update(c, 0.0, kTimeout);
  EXPECT_EQ(s.state, SlamStatus::PAUSED);
  EXPECT_EQ(s.frames_skipped, 6);
  c.paused = 0;
  EXPECT_EQ(t.update(c, kTimeout + 0.1, kTimeout).state, SlamStatus::NO_INPUT);  // no frame for too long
  EXPECT_EQ(t.update(c, -1.0, kTimeout).state, SlamStatus::NO_INPUT);            // none yet
  EXPECT_EQ(t.update(c, kTimeout - 0.1, kTimeout).state, SlamStatus::TRACKING);
}

TEST(SlamStatus, FramesSkippedCountsEveryDropAndRefusal) {
  ros_diagnostics::OdometryCounters c;
  long n = 0;
  for (long ros_diagnostics::OdometryCounters::*k :
       {&ros_diagnostics::OdometryCounters::skipped_no_camera_info,
        &ros_diagnostics::OdometryCounters::skipped_no_altitude, &ros_diagnostics::OdometryCounters::dropped_queue_full,
        &ros_diagnostics::OdometryCounters::skipped_for_newest,
        &ros_diagnostics::OdometryCounters::frames_dropped_paused, &ros_diagnostics::OdometryCounters::skipped_encoding,
        &ros_diagnostics::OdometryCounters::skipped_camera_info,
        &ros_diagnostics::OdometryCounters::skipped_duplicate_stamp,
        &ros_diagnostics::OdometryCounters::skipped_out_of_order, &ros_diagnostics::OdometryCounters::skipped_no_mount,
        &ros_diagnostics::OdometryCounters::skipped_by_odometry}) {
    c.*k = ++n;
  }
  EXPECT_EQ(framesSkipped(c), n * (n + 1) / 2);
  c.keyframes = 100, c.frames_finished = 100, c.images_received = 100;  // not skips
  EXPECT_EQ(framesSkipped(c), n * (n + 1) / 2);
}

core::KeyframeInput keyframe(int session, int k) {
  core::KeyframeInput in;
  in.session = session, in.keyframe = k, in.frame_index = k;
  in.stamp_s = 100.0 * session + k;
  in.odometry_pose = core::Pose2(0.5 * k, 0.0, 0.0);
  in.motion = core::UncertainPose2(core::Pose2(k > 0 ? 0.5 : 0.0, 0.0, 0.0), Eigen::Matrix3d::Identity() * 1e-4);
  return in;
}

TEST(SlamStatus, TheBackEndPartAndTheWholeFromASessionManager) {
  core::SessionManagerOptions o;
  o.backend.join_min_loops = 0;
  core::SessionManager m(o);
  for (int s = 0; s < 2; ++s)
    for (int k = 0; k < 4; ++k) ASSERT_TRUE(m.addKeyframe(keyframe(s, k)).ok());
  BackendPart b = backendPart(m.view());
  EXPECT_EQ(b.sessions.size(), 2u);
  EXPECT_EQ(b.maps, 2);
  EXPECT_EQ(b.keyframes, 8);
  EXPECT_EQ(b.loops, 0);
  EXPECT_EQ(b.last_loop_stamp, -1.0);
  EXPECT_EQ(b.active, 1);
  core::Loop l;  // session 1's keyframe 3 (stamp 103) seen from keyframe 0
  l.session_a = l.session_b = 1, l.keyframe_a = 0, l.keyframe_b = 3, l.inliers = 50;
  l.z = core::UncertainPose2(core::Pose2(1.5, 0.0, 0.0), Eigen::Matrix3d::Identity() * 1e-4);
  ASSERT_TRUE(m.addLoop(l).ok());
  l.keyframe_b = 2, l.z = core::UncertainPose2(core::Pose2(1.0, 3.0, 0.0), Eigen::Matrix3d::Identity() * 1e-4);
  ASSERT_TRUE(m.addLoop(l).ok());  // 3 m off: the gate refuses it, not counted
  ASSERT_TRUE(m.view().loopRefused(1));
  b = backendPart(m.view());
  EXPECT_EQ(b.loops, 1);
  EXPECT_DOUBLE_EQ(b.last_loop_stamp, 103.0);

  ros_diagnostics::OdometryCounters c;
  c.sessions = 2, c.session = 1;
  OdometryStateTracker t;
  SlamStatus s = combine(t.update(c, 0.0, kTimeout), b, 110.0, 103.0);
  EXPECT_EQ(s.state, SlamStatus::TRACKING);
  EXPECT_EQ(s.session, 1);
  EXPECT_EQ(s.map, m.view().mapOf(1));
  EXPECT_EQ(s.session_keyframes, 4);
  EXPECT_EQ(s.sessions, 2);
  EXPECT_EQ(s.maps, 2);
  EXPECT_EQ(s.keyframes, 8);
  EXPECT_EQ(s.loops, 1);
  EXPECT_DOUBLE_EQ(s.last_loop_age_s, 7.0);
  EXPECT_FALSE(s.localisation);
  EXPECT_NE(s.text.find("TRACKING  session 1 (map 1), 4 keyframes"), std::string::npos) << s.text;
  EXPECT_NE(s.text.find("1 loops, last 7 s ago"), std::string::npos) << s.text;

  // set_mode in either spelling: tracking in localisation mode is LOCALISATION.
  EXPECT_TRUE(ros_conversions::setMode(&m, "localization").ok());
  b = backendPart(m.view());
  EXPECT_TRUE(b.localisation);
  s = combine(t.update(c, 0.0, kTimeout), b, 110.0, 103.0);
  EXPECT_EQ(s.state, SlamStatus::LOCALISATION);
  EXPECT_EQ(s.state_name, "localisation");
  EXPECT_TRUE(ros_conversions::setMode(&m, "mapping").ok());
  EXPECT_TRUE(ros_conversions::setMode(&m, "localisation").ok());
  EXPECT_TRUE(m.view().localising());
  const core::Status bad = ros_conversions::setMode(&m, "survey");
  EXPECT_EQ(bad.code, core::StatusCode::kInvalidArgument);
  EXPECT_NE(bad.message.find("'survey' is neither 'mapping' nor 'localisation'"), std::string::npos) << bad.message;
  EXPECT_TRUE(m.view().localising());  // a refused word changes nothing
  c.tracking_losses = 1;
  EXPECT_EQ(combine(t.update(c, 0.0, kTimeout), b, 110.0, 103.0).state, SlamStatus::LOST);  // lost wins over the mode
  // No word from the odometry yet: the back-end's active session, NO_INPUT.
  SlamStatus none;
  none.session = -1;
  s = combine(none, b, 110.0, -1.0);
  EXPECT_EQ(s.state, SlamStatus::NO_INPUT);
  EXPECT_EQ(s.session, 1);
}

}  // namespace
}  // namespace ros_status
}  // namespace uw_multislam
