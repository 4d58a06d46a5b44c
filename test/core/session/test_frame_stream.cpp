// FrameStream, the front end both heads drive: its session starts and their ids (with and without
// an owner's hooks), the keyframes it releases, the gap rule on a stills camera, the nav asked after
// a jump back.
#include <gtest/gtest.h>

#include <optional>
#include <string>
#include <vector>

#include "../../common/rendered_seabed.h"
#include "uw_multislam/core/session/frame_stream.h"

namespace uw_multislam {
namespace core {
namespace {

class FrameStreamTest : public testing_util::RenderedSeabedTest {
 protected:
  // Frame k of a straight pass, 0.25 m a frame at 2 m altitude.
  FrameInput frame(int k, double stamp_s) const {
    FrameInput in;
    in.image = render(Pose2(2.0 + 0.25 * (k % 30), 4.0, 0.0), 2.0);
    in.camera = camera_;
    in.altitude_m = 2.0;
    in.stamp_s = stamp_s;
    return in;
  }
  SlamConfig config_;
};

TEST_F(FrameStreamTest, SessionsStartAtTheFirstFrameARequestAJumpAndANewCameraEachWithItsId) {
  FrameStream stream(config_, StampGuardOptions(), {}, 4);
  stream.beginStream();
  std::vector<FrameResult> r;
  double t = 100.0;
  for (int k = 0; k < 24; ++k) {
    FrameInput in = frame(k, t);
    if (k == 6) in.requested.session = 9;              // start_session
    if (k == 12) in.stamp_s = t += 60.0;               // a gap of 60 periods
    if (k == 18) in.camera.fx = in.camera.fy = 310.0;  // another lens
    if (k >= 18) in.camera.fx = in.camera.fy = 310.0;
    if (k >= 18) in.requested.next_free = 20;  // another vehicle's sessions took ids up to 19
    r.push_back(stream.process(in));
    t += 1.0;
  }
  const auto started = [&](int k) { return r[k].started ? r[k].started->session : -1; };
  ASSERT_TRUE(r[0].started);
  EXPECT_EQ(r[0].started->cause, SessionCause::kFirstFrame);
  EXPECT_EQ(started(0), 4) << "the first id";
  EXPECT_EQ(started(6), 9);
  EXPECT_EQ(r[6].started->cause, SessionCause::kRequested);
  EXPECT_EQ(started(12), 10);
  EXPECT_EQ(r[12].started->cause, SessionCause::kStampJump);
  EXPECT_EQ(r[12].timing, StampClass::kJumpForward);
  EXPECT_EQ(started(18), 20) << "past the ids the back-end gave away";
  EXPECT_EQ(r[18].started->cause, SessionCause::kCamera);
  for (int k = 0; k < 24; ++k) {
    EXPECT_EQ(r[k].started.has_value(), k % 6 == 0) << k;
    ASSERT_EQ(r[k].ended.size(), k % 6 == 0 && k > 0 ? 1u : 0u) << k;
    for (const FrameResult::Ended& e : r[k].ended) EXPECT_EQ(e.cause, SessionEnd::kNextSession) << k;
    EXPECT_TRUE(r[k].moved) << k;
  }
  EXPECT_EQ(r[6].ended[0].session, 4);
  EXPECT_EQ(stream.session(), 20);
  EXPECT_EQ(stream.counts().sessions, 4);
  EXPECT_EQ(stream.counts().jumps_forward, 1);
  // Each session's keyframes carry its id, its origin first, hashed once for every receiver.
  for (int k = 0; k < 24; k += 6) {
    ASSERT_FALSE(r[k].keyframes.empty()) << k;
    const KeyframeInput& first = r[k].keyframes[0].input;
    EXPECT_EQ(first.session, started(k));
    EXPECT_EQ(first.keyframe, 0);
    EXPECT_EQ(first.frame_index, 0) << "live frames are numbered from each session's start";
    EXPECT_EQ(first.hash.size(), HalocProjections::kHashSize);
  }
  long keyframes = 0;
  for (const FrameResult& x : r) keyframes += static_cast<long>(x.keyframes.size());
  EXPECT_EQ(stream.counts().keyframes, keyframes);
}

TEST_F(FrameStreamTest, AnOwnersHooksGiveTheIdsAndCloseEachSessionBeforeTheNextOpens) {
  std::vector<std::string> calls;
  SessionHooks hooks;
  hooks.open = [&](const SessionOpening& o) {
    calls.push_back("open " + std::to_string(o.piece) + " " + sessionCauseName(o.cause));
    return 100 + o.piece;
  };
  hooks.close = [&](const SessionClosing& c) {
    calls.push_back("close " + std::to_string(c.session) + (c.odometry ? " with its odometry" : ""));
  };
  FrameStream stream(config_, StampGuardOptions(), hooks);
  stream.beginStream();
  for (int k = 0; k < 8; ++k) {
    FrameInput in = frame(k, k < 4 ? 1.0 * k : 100.0 + k);  // a gap of 96 s after frame 3
    in.index = 10 + k;
    const FrameResult r = stream.process(in);
    for (const StreamKeyframe& kf : r.keyframes) {
      EXPECT_EQ(kf.input.session, k < 4 ? 100 : 101);
      EXPECT_GE(kf.input.frame_index, 10) << "the stream's own frame numbers are kept";
    }
  }
  stream.endStream(107.0);
  stream.endStream(107.0);  // nothing open: nothing closed
  EXPECT_EQ(calls, (std::vector<std::string>{"open 0 first frame", "close 100 with its odometry", "open 1 stamp jump",
                                             "close 101 with its odometry"}));
  // A new stream starts a session at its first frame, the piece count afresh.
  stream.beginStream();
  stream.process(frame(0, 0.0));
  EXPECT_EQ(calls.back(), "open 0 first frame");
}

TEST_F(FrameStreamTest, AStillsCameraGoesOnInOneSessionAndTheRuleIsSaidOnce) {
  // 13 s apart, 22 s every 6 frames: beyond session_gap_s (10 s) every time, as a survey ROV's stills.
  FrameStream stream(config_, StampGuardOptions());
  stream.beginStream();
  double t = 0.0;
  int warnings = 0;
  for (int k = 0; k < 20; ++k) {
    const FrameResult r = stream.process(frame(k, t));
    t += k % 6 == 5 ? 22.0 : 13.0;
    EXPECT_EQ(r.started.has_value(), k == 0) << k;
    for (const std::string& w : r.warnings) {
      ++warnings;
      EXPECT_NE(w.find("frame period, 13.0 s"), std::string::npos) << w;
      EXPECT_NE(w.find("beyond session_gap_s 10.0 s"), std::string::npos) << w;
      EXPECT_NE(w.find("(130.0 s now)"), std::string::npos) << w;
    }
  }
  EXPECT_EQ(warnings, 1);
  EXPECT_EQ(stream.counts().sessions, 1);
  EXPECT_EQ(stream.counts().jumps_forward, 0);
}

TEST_F(FrameStreamTest, TheNavIsAskedAfterTheStampChecksAndToldOfAJumpBack) {
  FrameStream stream(config_, StampGuardOptions());
  stream.beginStream();
  std::vector<std::pair<double, bool>> asked;
  const std::vector<double> stamps{10.0, 11.0, 11.0, 10.5, 12.0, 3.0, 4.0};
  for (std::size_t k = 0; k < stamps.size(); ++k) {
    FrameInput in = frame(static_cast<int>(k), stamps[k]);
    in.nav = [&asked, t = stamps[k]](bool jumped_back) -> std::optional<NavRecord> {
      asked.emplace_back(t, jumped_back);
      return std::nullopt;
    };
    const FrameResult r = stream.process(in);
    EXPECT_EQ(r.skipped_stamp, k == 2 || k == 3) << k;
  }
  EXPECT_EQ(asked, (std::vector<std::pair<double, bool>>{
                       {10.0, false}, {11.0, false}, {12.0, false}, {3.0, true}, {4.0, false}}))
      << "no nav for a skipped duplicate or late frame; the first frame after the jump back is told";
  EXPECT_EQ(stream.counts().duplicates, 1);
  EXPECT_EQ(stream.counts().out_of_order, 1);
  EXPECT_EQ(stream.counts().jumps_back, 1);
  // Disabled nav: not even asked.
  SlamConfig off = config_;
  off.odometry.nav.enabled = false;
  FrameStream quiet(off, StampGuardOptions());
  quiet.beginStream();
  FrameInput in = frame(0, 0.0);
  bool called = false;
  in.nav = [&called](bool) -> std::optional<NavRecord> {
    called = true;
    return std::nullopt;
  };
  quiet.process(in);
  EXPECT_FALSE(called);
}

// A piece after a tracking loss whose keyframe registers with the piece before (tracking.h's
// rejoin): that keyframe carries the placement, marked visual, against the closed session; the
// tracking loss says why it happened.
TEST_F(FrameStreamTest, AVisualBridgePlacesThePieceAfterARestartAgainstThePieceBefore) {
  FrameStream stream(config_, StampGuardOptions());
  stream.beginStream();
  const std::vector<Pose2> at = {Pose2(2.0, 2.5, 0.0),  Pose2(2.25, 2.5, 0.0), Pose2(2.5, 2.5, 0.0),
                                 Pose2(2.75, 2.5, 0.0), Pose2(3.0, 2.5, 0.0),  Pose2(3.0, 4.2, 0.0),
                                 Pose2(3.5, 4.2, 0.0),  Pose2(3.75, 3.3, 0.0), Pose2(4.0, 3.3, 0.0)};
  std::vector<FrameResult> r;
  for (int k = 0; k < static_cast<int>(at.size()); ++k) {
    FrameInput in;
    in.image = render(at[k], 2.0);
    in.camera = camera_;
    in.altitude_m = 2.0;
    in.stamp_s = 100.0 + k;
    in.index = k;
    r.push_back(stream.process(in));
  }
  ASSERT_EQ(r[6].ended.size(), 1u);
  EXPECT_EQ(r[6].ended[0].cause, SessionEnd::kTrackingLoss);
  EXPECT_NE(r[6].ended[0].why.find("unmatched frame 5"), std::string::npos) << r[6].ended[0].why;
  ASSERT_TRUE(r[7].started);
  const int previous = r[6].ended[0].session;
  int placed = 0;
  for (const FrameResult& f : r)
    for (const StreamKeyframe& k : f.keyframes)
      if (k.input.nav_placement) {
        ++placed;
        EXPECT_TRUE(k.input.nav_placement->visual);
        EXPECT_EQ(k.input.nav_placement->session, previous);
        EXPECT_EQ(k.input.session, r[7].started->session);
        EXPECT_EQ(k.input.frame_index, 7);
      }
  EXPECT_EQ(placed, 1);
  EXPECT_EQ(stream.counts().bridges, 1);
  EXPECT_EQ(stream.counts().placements, 0) << "no nav placed anything";
  EXPECT_EQ(stream.counts().restarts, 1);
  EXPECT_EQ(stream.counts().tracking_losses, 1);
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
