// Tracking loss (core/frontend/tracking.h): a blank stretch closes the session, the next textured frame
// starts a new one; short dropouts and blank starts do not make sessions. With a nav prior
// (core/frontend/nav_prior.h) the nav carries the blank stretch and a wrong visual motion is refused.
#include <gtest/gtest.h>

#include "../../common/rendered_seabed.h"
#include "uw_multislam/core/frontend/tracking.h"

#include <cmath>
#include <functional>

namespace uw_multislam {
namespace core {
namespace {

class TrackingTest : public testing_util::RenderedSeabedTest {
 protected:
  // A straight pass 0.25 m per frame; frames in [blank_from, blank_to) are uniform grey water.
  std::vector<SegmentedOdometry::Step> fly(SegmentedOdometry* odo, int frames, int blank_from, int blank_to,
                                           std::vector<int>* keyframes_per_session = nullptr) {
    std::vector<SegmentedOdometry::Step> steps;
    const cv::Mat grey(240, 320, CV_8UC3, cv::Scalar(90, 110, 60));
    for (int k = 0; k < frames; ++k) {
      const cv::Mat image = (k >= blank_from && k < blank_to) ? grey : render(Pose2(2.0 + 0.25 * k, 4.0, 0.0), 2.0);
      OdometryInput in{k, 1.0 * k, 2.0, image};
      if (nav) in.nav = nav(k);
      steps.push_back(odo->process(in));
      if (steps.back().session_closed) {
        kept_at_close = odo->keptKeyframes();
        made_at_close = static_cast<int>(odo->odometry()->keyframes().size());
        fallback_kept_at_close = false;
        for (int i = 0; i < kept_at_close; ++i) fallback_kept_at_close |= odo->odometry()->keyframes()[i].fallback;
      }
      released += static_cast<int>(odo->newKeyframes().size());
      if (keyframes_per_session && steps.back().session_started) keyframes_per_session->push_back(0);
      if (keyframes_per_session && odo->odometry() && !keyframes_per_session->empty())
        keyframes_per_session->back() = static_cast<int>(odo->odometry()->keyframes().size());
    }
    return steps;
  }
  std::function<NavRecord(int)> nav;  // the nav pose of frame k (none when empty)
  int kept_at_close = -1, made_at_close = -1, released = 0;
  bool fallback_kept_at_close = true;
};

TEST_F(TrackingTest, ABlankStretchClosesTheSessionAndTheNextTexturedFrameStartsOne) {
  TrackingLossOptions loss;
  loss.max_fallbacks = 3;
  OdometryOptions reuse;
  reuse.fallback.bridge_frames = 0;  // reused motions, held back (bridged frames make no keyframe: below)
  SegmentedOdometry odo(camera_, reuse, loss);
  std::vector<int> kfs;
  const auto steps = fly(&odo, 30, 10, 18, &kfs);
  int closed_at = -1, started_at = -1;
  for (int k = 0; k < 30; ++k) {
    if (steps[k].session_closed) closed_at = k;
    if (steps[k].session_started && k > 0) started_at = k;
  }
  EXPECT_TRUE(steps[0].session_started);
  EXPECT_EQ(closed_at, 12) << "the third unmatched frame closes the session";
  EXPECT_EQ(started_at, 18) << "the first textured frame after the stretch is the new origin";
  for (int k = 13; k < 18; ++k) EXPECT_EQ(steps[k].update.status, FrameStatus::kSkipped) << k;
  EXPECT_EQ(odo.sessions(), 2);
  EXPECT_EQ(odo.losses(), 1);
  EXPECT_EQ(odo.framesLost(), 5);
  // The unmatched frames' keyframes (reused motions) were held back and dropped at the close:
  // the first session ends at its last measured keyframe.
  EXPECT_LT(kept_at_close, made_at_close);
  EXPECT_FALSE(fallback_kept_at_close);
  EXPECT_EQ(released, kept_at_close + odo.keptKeyframes());  // exactly the kept ones were released
  ASSERT_EQ(kfs.size(), 2u);
  EXPECT_GE(kfs[1], 3);  // the second session tracks again (2.75 m, a keyframe a metre)
  // The new session's own frame: its origin is frame 18, its last keyframe ~2.75 m further on.
  const Pose2 last = odo.odometry()->trajectory().absolutePoses().back();
  EXPECT_NEAR(last.x(), 0.25 * (odo.odometry()->keyframes().back().frame_index - 18), 0.05);
}

TEST_F(TrackingTest, ABridgedBlankStretchMakesNoKeyframeAndClosesTheSessionAlike) {
  TrackingLossOptions loss;
  loss.max_fallbacks = 3;
  SegmentedOdometry odo(camera_, OdometryOptions(), loss);
  const auto steps = fly(&odo, 30, 10, 18);
  int closed_at = -1;
  for (int k = 0; k < 30; ++k)
    if (steps[k].session_closed) closed_at = k;
  EXPECT_EQ(closed_at, 12) << "the third unmatched frame closes the session";
  for (int k = 10; k <= 12; ++k) {
    EXPECT_EQ(steps[k].update.status, FrameStatus::kFallback) << k;
    EXPECT_EQ(steps[k].update.keyframe_id, -1) << k;
  }
  EXPECT_EQ(kept_at_close, made_at_close);  // nothing made up, nothing to drop
  EXPECT_FALSE(fallback_kept_at_close);
  EXPECT_EQ(odo.sessions(), 2);
}

TEST_F(TrackingTest, OneBlankFrameIsBridgedInTheSession) {
  // One blank frame: frames 9 and 11 overlap, the session goes on, every keyframe measured.
  SegmentedOdometry odo(camera_, OdometryOptions(), TrackingLossOptions());
  fly(&odo, 16, 10, 11);
  EXPECT_EQ(odo.sessions(), 1);
  const Odometry& o = *odo.odometry();
  EXPECT_EQ(o.stats().bridged, 1);
  for (const KeyframeInfo& k : o.keyframes()) EXPECT_FALSE(k.fallback) << k.frame_index;
  EXPECT_NEAR(o.trajectory().absolutePoses().back().x(), 0.25 * o.keyframes().back().frame_index, 0.05);
}

// The vehicle jumps (frames 0-4 along one line, then 5-11 along another 4 m away): frame 5 matches
// nothing, frame 6 registers with frame 5 only. The session ends at frame 6 and the next one starts
// at frame 5, so frames 6, 7, ... are not failed one by one against frame 4, and no frame is lost.
TEST_F(TrackingTest, AFrameThatRegistersOnlyWithTheUnmatchedOneBeforeStartsTheNextSessionThere) {
  SegmentedOdometry odo(camera_, OdometryOptions(), TrackingLossOptions());
  std::vector<SegmentedOdometry::Step> steps;
  std::vector<std::vector<int>> released;  // frame indexes of the keyframes each step released
  const auto at = [](int k) { return k < 5 ? Pose2(2.0 + 0.25 * k, 2.5, 0.0) : Pose2(2.0 + 0.25 * (k - 5), 6.0, 0.0); };
  for (int k = 0; k < 12; ++k) {
    steps.push_back(odo.process({k, 1.0 * k, 2.0, render(at(k), 2.0)}));
    released.emplace_back();
    for (const auto& kf : odo.newKeyframes()) released.back().push_back(odo.odometry()->keyframes()[kf.id].frame_index);
  }
  EXPECT_EQ(steps[5].update.status, FrameStatus::kFallback);
  EXPECT_EQ(steps[5].update.restart_index, -1);
  EXPECT_FALSE(steps[5].session_closed);
  EXPECT_EQ(steps[6].update.restart_index, 5) << steps[6].update.reason;
  EXPECT_TRUE(steps[6].session_closed);
  EXPECT_TRUE(steps[7].session_started);
  ASSERT_FALSE(released[7].empty());
  EXPECT_EQ(released[7].front(), 5) << "the new session's origin is the unmatched frame";
  EXPECT_EQ(odo.sessions(), 2);
  EXPECT_EQ(odo.losses(), 1);
  EXPECT_EQ(odo.framesLost(), 0);
  for (int k = 7; k < 12; ++k) EXPECT_NE(steps[k].update.status, FrameStatus::kFallback) << k;
  // The new session's frame is frame 5's: frame 11 is 1.5 m along x from it.
  EXPECT_TRUE(approxEqual(steps[11].update.pose, Pose2(1.5, 0.0, 0.0), 0.02, 0.01)) << steps[11].update.pose;
  // The pieces never overlap again: no keyframe of the new one registers with the old one.
  for (int k = 0; k < 12; ++k) EXPECT_FALSE(steps[k].placement) << k;
  EXPECT_GT(odo.rejoinTries(), 0);
  EXPECT_EQ(odo.rejoins(), 0);
}

// The vehicle side-steps by more than its footprint (frames 5 and 6, 1.7 m over a 1.6 m high
// footprint), then comes back half-way (frame 7): frame 6 registers only with frame 5, so the
// session restarts at frame 5, and frame 7, a keyframe of the new piece, registers with frame 4,
// the old piece's last keyframe: the new piece is placed against it by that registration.
TEST_F(TrackingTest, APieceAfterARestartIsBridgedToThePieceBeforeByTheFirstKeyframeThatRegistersWithIt) {
  SegmentedOdometry odo(camera_, OdometryOptions(), TrackingLossOptions());
  std::vector<SegmentedOdometry::Step> steps;
  const std::vector<Pose2> at = {Pose2(2.0, 2.5, 0.0),  Pose2(2.25, 2.5, 0.0), Pose2(2.5, 2.5, 0.0),
                                 Pose2(2.75, 2.5, 0.0), Pose2(3.0, 2.5, 0.0),  Pose2(3.0, 4.2, 0.0),
                                 Pose2(3.5, 4.2, 0.0),  Pose2(3.75, 3.3, 0.0), Pose2(4.0, 3.3, 0.0)};
  int anchor = -1;
  for (int k = 0; k < static_cast<int>(at.size()); ++k) {
    steps.push_back(odo.process({k, 1.0 * k, 2.0, render(at[k], 2.0)}));
    if (steps.back().session_closed) anchor = static_cast<int>(odo.odometry()->keyframes().size()) - 1;
  }
  ASSERT_TRUE(steps[6].session_closed) << steps[6].update.reason;
  EXPECT_EQ(steps[6].update.restart_index, 5);
  ASSERT_TRUE(steps[7].session_started);
  ASSERT_TRUE(steps[7].placement) << "frame 7 (" << statusName(steps[7].update.status) << ") registers with frame 4";
  EXPECT_TRUE(steps[7].placement->visual);
  EXPECT_EQ(steps[7].placement->keyframe, anchor);
  EXPECT_TRUE(approxEqual(steps[7].placement->z.mean, between(at[4], at[7]), 0.03, 0.01))
      << steps[7].placement->z.mean << " vs " << between(at[4], at[7]);
  EXPECT_GT(steps[7].placement->z.covariance(0, 0), 0.0);
  EXPECT_GT(steps[7].placement->z.covariance(2, 2), 0.0);
  EXPECT_EQ(odo.rejoins(), 1);
  EXPECT_FALSE(steps[8].placement) << "one bridge per piece";
  EXPECT_EQ(odo.sessions(), 2);

  // rejoin_keyframes 0: the same frames, no bridge.
  TrackingLossOptions never;
  never.rejoin_keyframes = 0;
  SegmentedOdometry plain(camera_, OdometryOptions(), never);
  for (int k = 0; k < static_cast<int>(at.size()); ++k)
    EXPECT_FALSE(plain.process({k, 1.0 * k, 2.0, render(at[k], 2.0)}).placement) << k;
  EXPECT_EQ(plain.rejoinTries(), 0);
}

TEST_F(TrackingTest, AShortDropoutStaysInTheSession) {
  TrackingLossOptions loss;
  loss.max_fallbacks = 5;
  SegmentedOdometry odo(camera_, OdometryOptions(), loss);
  const auto steps = fly(&odo, 20, 8, 10);
  EXPECT_EQ(odo.sessions(), 1);
  EXPECT_EQ(odo.losses(), 0);
  for (const auto& s : steps) EXPECT_FALSE(s.session_closed);
}

TEST_F(TrackingTest, ABlankStartWaitsForTexture) {
  SegmentedOdometry odo(camera_, OdometryOptions(), TrackingLossOptions());
  const auto steps = fly(&odo, 8, 0, 3);
  for (int k = 0; k < 3; ++k) {
    EXPECT_EQ(steps[k].update.status, FrameStatus::kSkipped);
    EXPECT_FALSE(steps[k].session_started);
    EXPECT_NE(steps[k].update.reason.find("needed to start"), std::string::npos) << steps[k].update.reason;
  }
  EXPECT_TRUE(steps[3].session_started);
  EXPECT_EQ(odo.sessions(), 1);
  EXPECT_EQ(odo.framesLost(), 0);  // before the first session nothing is "lost"
}

TEST_F(TrackingTest, ZeroNeverClosesAndBadOptionsAreRefused) {
  TrackingLossOptions never;
  never.max_fallbacks = 0;
  SegmentedOdometry odo(camera_, OdometryOptions(), never);
  fly(&odo, 24, 6, 20);
  EXPECT_EQ(odo.sessions(), 1);
  TrackingLossOptions bad;
  bad.min_features = 0;
  EXPECT_THROW(SegmentedOdometry(camera_, OdometryOptions(), bad), std::invalid_argument);
}

// The nav of the straight pass: the truth in the first frame's axes, scaled by (1 + scale) (a DVL
// scale error), its sigma growing 1 % of the distance.
NavRecord straightNav(int k, double scale = 0.0) {
  return {1.0 * k, Pose2(0.25 * k * (1.0 + scale), 0.0, 0.0), 0.01 * 0.25 * k, 0.001};
}

TEST_F(TrackingTest, WithNavTheBlankStretchIsDeadReckonedInOneSession) {
  TrackingLossOptions loss;
  loss.max_fallbacks = 3;
  nav = [](int k) { return straightNav(k, 0.01); };
  SegmentedOdometry odo(camera_, OdometryOptions(), loss);
  const auto steps = fly(&odo, 30, 10, 18);
  EXPECT_EQ(odo.sessions(), 1);
  EXPECT_EQ(odo.losses(), 0);
  const Odometry& o = *odo.odometry();
  EXPECT_EQ(o.stats().fallbacks, 0);
  EXPECT_GE(o.stats().nav_frames, 8);  // the 8 blank frames, and the first one back (its keyframe is blank)
  int nav_keyframes = 0;
  for (const KeyframeInfo& kf : o.keyframes()) {
    if (kf.source != MotionSource::kNav) continue;
    ++nav_keyframes;
    EXPECT_GE(kf.frame_index, 10);
    EXPECT_LE(kf.frame_index, 18);
  }
  EXPECT_GE(nav_keyframes, 2);
  for (int k = 10; k < 18; ++k) EXPECT_EQ(steps[k].update.source, MotionSource::kNav) << k;
  EXPECT_EQ(steps[25].update.source, MotionSource::kVisual);
  // The end: within the nav's 1 % scale error over the 2 m blind (5 mm with the visual chain).
  const Pose2 end = o.trajectory().absolutePoses().back();
  const double truth = 0.25 * o.keyframes().back().frame_index;
  EXPECT_NEAR(end.x(), truth, 0.01 * 2.0 + 0.005);
  EXPECT_NEAR(end.y(), 0.0, 0.005);
  // Policy new_session: as without nav, the stretch closes the session.
  OdometryOptions split;
  split.nav.on_tracking_loss = TrackingLossPolicy::kNewSession;
  SegmentedOdometry odo2(camera_, split, loss);
  fly(&odo2, 30, 10, 18);
  EXPECT_EQ(odo2.losses(), 1);
  EXPECT_EQ(odo2.sessions(), 2);
}

TEST_F(TrackingTest, AVisualMotionTheNavContradictsIsRefusedAndCounted) {
  // From frame 12 on the nav says the vehicle moved 0.3 m sideways: every visual motion from a
  // keyframe before it disagrees by 0.3 m (nav sigma ~1 cm): refused, the nav's used.
  nav = [](int k) {
    NavRecord r = straightNav(k);
    if (k >= 12) r.pose = Pose2(r.pose.x(), 0.3, 0.0);
    return r;
  };
  OdometryOptions no_ransac_gate;  // (c) alone: RANSAC finds the visual motion, the gate refuses it
  no_ransac_gate.nav.gate_ransac = false;
  SegmentedOdometry odo(camera_, no_ransac_gate, TrackingLossOptions());
  const auto steps = fly(&odo, 16, 100, 100);
  const OdometryStats& st = odo.odometry()->stats();
  EXPECT_EQ(st.hypotheses_gated, 0);
  EXPECT_GE(st.gate_checks, 14);
  EXPECT_GE(st.gate_refusals, 1);
  EXPECT_TRUE(steps[12].update.gate_refused);
  EXPECT_EQ(steps[12].update.source, MotionSource::kNav);
  EXPECT_NE(steps[12].update.reason.find("refused by the nav gate"), std::string::npos) << steps[12].update.reason;
  for (int k = 1; k < 12; ++k)
    EXPECT_FALSE(steps[k].update.gate_refused) << k << " d2 " << steps[k].update.gate_distance2;
  // (a) with the RANSAC gate (the default) no hypothesis near the visual motion is even scored:
  // frame 12 finds no consensus and the nav carries it.
  SegmentedOdometry odo2(camera_, OdometryOptions(), TrackingLossOptions());
  const auto steps2 = fly(&odo2, 16, 100, 100);
  EXPECT_EQ(steps2[12].update.source, MotionSource::kNav);
  EXPECT_FALSE(steps2[12].update.gate_refused);
  EXPECT_NE(steps2[12].update.reason.find("dead reckoning"), std::string::npos) << steps2[12].update.reason;
  EXPECT_GT(odo2.odometry()->stats().hypotheses_gated, 0);
  for (int k = 1; k < 12; ++k) EXPECT_EQ(steps2[k].update.source, MotionSource::kVisual) << k;
  // A nav that agrees, with nav.fuse: the motions are combined (source fused), none refused.
  nav = [](int k) { return straightNav(k); };
  OdometryOptions fused;
  fused.nav.fuse = true;
  SegmentedOdometry odo3(camera_, fused, TrackingLossOptions());
  const auto fused_steps = fly(&odo3, 8, 100, 100);
  EXPECT_EQ(fused_steps[5].update.source, MotionSource::kFused);
  EXPECT_EQ(odo3.odometry()->stats().gate_refusals, 0);
}

// The vehicle pivots 2.5 rad between frames 11 and 12, inside a black-out (frames 10-17), and flies
// on along its new heading: its nav (an INS heading, right) turns faster than
// nav.max_yaw_rate_rad_s, so frame 12's reading is refused, and frame 13's too (2.5 rad from the
// last accepted one, frame 11's). The images after the black-out are the straight pass, which is
// the same body-frame motion.
NavRecord turnNav(int k) {
  const double turn = 2.5;
  if (k < 12) return straightNav(k);
  const double d = 0.25 * (k - 12);
  return {1.0 * k, Pose2(0.25 * 12 + d * std::cos(turn), d * std::sin(turn), turn), 0.01 * 0.25 * k, 0.001};
}

TEST_F(TrackingTest, ARefusedTurnInABlackoutEndsThePieceRatherThanExtrapolate) {
  // One bridged frame: frame 13 has neither a visual motion nor an accepted reading. The piece
  // ends there, as it would without nav; before, frame 13 became a keyframe with the previous
  // motion reused (no turn) and the nav carried on from it, the 2.5 rad lost for good.
  nav = turnNav;
  OdometryOptions one_bridged;
  one_bridged.fallback.bridge_frames = 1;
  SegmentedOdometry odo(camera_, one_bridged, TrackingLossOptions());  // max_fallbacks 5
  const auto steps = fly(&odo, 30, 10, 18);
  int closed_at = -1;
  for (int k = 0; k < 30; ++k)
    if (steps[k].session_closed) closed_at = k;
  EXPECT_EQ(closed_at, 13);
  EXPECT_TRUE(steps[13].update.nav_loss);
  EXPECT_NE(steps[13].update.reason.find("tracking lost"), std::string::npos) << steps[13].update.reason;
  EXPECT_FALSE(fallback_kept_at_close) << "no extrapolated keyframe is kept";
  EXPECT_EQ(odo.losses(), 1);
  EXPECT_EQ(odo.sessions(), 2);
  EXPECT_NE(steps[12].update.nav_note.find("max_yaw_rate_rad_s"), std::string::npos) << steps[12].update.nav_note;
  EXPECT_NE(steps[13].update.nav_note.find("max_yaw_rate_rad_s"), std::string::npos) << steps[13].update.nav_note;
}

TEST_F(TrackingTest, TheReadingAfterARefusedSpikeIsTakenFromTheLastAcceptedOne) {
  // Frame 12's heading reads 2.5 rad off, frame 13's is right again, in the black-out. Frame 12's
  // reading is refused (counted, noted) and bridged; frame 13's is compared with frame 11's (the
  // last accepted), not with the refused one, and carried from the anchor the refusal kept. Before,
  // frame 13 was refused too (against frame 12's as received), the refusal dropped the anchor, and
  // after the bridged frames the previous motion was reused (a fallback keyframe).
  nav = [](int k) {
    NavRecord r = straightNav(k);
    if (k == 12) r.pose = Pose2(r.pose.x(), r.pose.y(), 2.5);
    return r;
  };
  OdometryOptions three_bridged;
  three_bridged.fallback.bridge_frames = 3;
  SegmentedOdometry odo(camera_, three_bridged, TrackingLossOptions());
  const auto steps = fly(&odo, 30, 10, 18);
  EXPECT_EQ(odo.sessions(), 1);
  EXPECT_EQ(odo.losses(), 0);
  const Odometry& o = *odo.odometry();
  EXPECT_EQ(o.stats().nav_implausible, 1);
  EXPECT_EQ(o.stats().nav_losses, 0);
  EXPECT_NE(steps[12].update.nav_note.find("max_yaw_rate_rad_s"), std::string::npos) << steps[12].update.nav_note;
  EXPECT_EQ(steps[12].update.status, FrameStatus::kFallback);  // bridged: no motion made up
  EXPECT_EQ(steps[12].update.keyframe_id, -1);
  EXPECT_TRUE(steps[13].update.nav_note.empty()) << steps[13].update.nav_note;
  EXPECT_EQ(steps[13].update.source, MotionSource::kNav);
  for (const KeyframeInfo& kf : o.keyframes()) EXPECT_FALSE(kf.fallback) << kf.frame_index;
  // The end: the straight pass (the nav has no scale error here), heading 0.
  const Pose2 end = o.trajectory().absolutePoses().back();
  EXPECT_NEAR(end.x(), 0.25 * o.keyframes().back().frame_index, 0.01);
  EXPECT_NEAR(end.y(), 0.0, 0.01);
  EXPECT_NEAR(end.yaw(), 0.0, 0.005);
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
