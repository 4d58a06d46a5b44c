// StampGuard: duplicated, late, looping and gapped stamps (bad input), and the gap rule that follows
// the camera's own frame period.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <stdexcept>
#include <vector>

#include "uw_multislam/core/frontend/stamp_guard.h"

namespace uw_multislam {
namespace core {
namespace {

TEST(StampGuard, ClassifiesEachKindOfBadTiming) {
  StampGuard g(StampGuardOptions{1.0, 10.0});
  EXPECT_EQ(g.accept(100.0), StampClass::kFirst);
  EXPECT_EQ(g.accept(100.5), StampClass::kNext);
  EXPECT_EQ(g.accept(100.5), StampClass::kDuplicate);   // the same frame twice
  EXPECT_EQ(g.accept(100.2), StampClass::kOutOfOrder);  // late by 0.3 s
  EXPECT_DOUBLE_EQ(g.last(), 100.5) << "skipped stamps are not accepted";
  EXPECT_EQ(g.accept(101.0), StampClass::kNext);
  EXPECT_EQ(g.accept(50.0), StampClass::kJumpBack);  // the bag looped
  EXPECT_DOUBLE_EQ(g.last(), 50.0);
  EXPECT_EQ(g.accept(50.5), StampClass::kNext);  // the new session goes on from there
  EXPECT_EQ(g.accept(70.0), StampClass::kJumpForward);
  EXPECT_EQ(g.accept(std::numeric_limits<double>::quiet_NaN()), StampClass::kOutOfOrder);
  EXPECT_DOUBLE_EQ(g.last(), 70.0);
}

TEST(StampGuard, BoundariesAndOff) {
  StampGuard g(StampGuardOptions{1.0, 0.0});  // forward jumps never start a session
  g.accept(10.0);
  EXPECT_EQ(g.accept(9.0), StampClass::kOutOfOrder) << "exactly the tolerance back is still late";
  EXPECT_EQ(g.accept(1e6), StampClass::kNext);
  EXPECT_TRUE(std::isinf(g.gapThreshold()));
  // gap_periods 1: session_gap_s alone while the period is below it (the boundary itself).
  StampGuard strict(StampGuardOptions{0.0, 5.0, 1.0});
  strict.accept(10.0);
  EXPECT_EQ(strict.accept(9.99), StampClass::kJumpBack);
  EXPECT_EQ(strict.accept(14.99), StampClass::kNext);
  EXPECT_EQ(strict.accept(19.99 + 0.02), StampClass::kJumpForward);
  EXPECT_TRUE(StampGuard::skips(StampClass::kDuplicate));
  EXPECT_FALSE(StampGuard::skips(StampClass::kJumpBack));
  EXPECT_TRUE(StampGuard::startsSession(StampClass::kJumpBack));
  EXPECT_THROW(StampGuard(StampGuardOptions{-1.0, 1.0}), std::invalid_argument);
  EXPECT_THROW(StampGuard(StampGuardOptions{1.0, 1.0, 0.5}), std::invalid_argument);
  EXPECT_EQ(stampClassName(StampClass::kOutOfOrder), "out_of_order");
}

TEST(StampGuard, StampsPassedOverBridgeTheGapOurOwnDropsLeave) {
  // A 10 Hz burst of 1,000 frames of which the node's own queue kept one in 50:
  // the kept frames are 5 s apart, more than session_gap_s, but the camera never paused. (gap_periods
  // 1: session_gap_s alone, so that the frames kept alone would be gaps.)
  StampGuard g(StampGuardOptions{1.0, 2.0, 1.0});
  StampGuard without(StampGuardOptions{1.0, 2.0, 1.0});  // the same frames, the drops not passed over
  int jumps = 0, jumps_without = 0;
  for (int i = 0; i < 1000; ++i) {
    const double t = 1000.0 + 0.1 * i;
    if (i % 50 != 0) {
      g.passOver(t);  // dropped: seen, not processed
      continue;
    }
    jumps += StampGuard::startsSession(g.accept(t));
    jumps_without += StampGuard::startsSession(without.accept(t));
  }
  EXPECT_EQ(jumps, 0);
  EXPECT_EQ(jumps_without, 19) << "the scenario must produce gaps when the drops are ignored";
  ASSERT_TRUE(g.period().has_value()) << "the frames passed over give the camera's period";
  EXPECT_NEAR(*g.period(), 0.1, 1e-9);
  // A real pause of the camera among the dropped frames is still a gap: the next processed frame
  // starts the session, and lastJump() says by how much the stamps jumped.
  EXPECT_EQ(g.accept(1100.0), StampClass::kNext);
  g.passOver(1100.1);
  g.passOver(1130.0);  // the camera paused 29.9 s
  g.passOver(1130.1);
  EXPECT_EQ(g.accept(1130.2), StampClass::kJumpForward);
  EXPECT_NEAR(g.lastJump(), 29.9, 1e-9);
  EXPECT_EQ(g.accept(1130.3), StampClass::kNext);  // reported once
  // A jump back among the dropped frames (a bag that loops) likewise.
  g.passOver(500.0);
  EXPECT_EQ(g.accept(500.1), StampClass::kJumpBack);
  EXPECT_NEAR(g.lastJump(), -630.3, 1e-9);
  // Passed-over duplicates, late and non-finite stamps change nothing; the frame after them is
  // classified against the last stamp.
  g.passOver(500.1);
  g.passOver(499.9);
  g.passOver(std::numeric_limits<double>::quiet_NaN());
  EXPECT_DOUBLE_EQ(g.last(), 500.1);
  EXPECT_EQ(g.accept(500.1), StampClass::kDuplicate);
  EXPECT_EQ(g.accept(500.2), StampClass::kNext);
  // A duplicate of a passed-over stamp is the same frame again: skipped, the held jump kept for
  // the next frame.
  g.passOver(600.0);
  EXPECT_EQ(g.accept(600.0), StampClass::kDuplicate);
  EXPECT_EQ(g.accept(600.1), StampClass::kJumpForward);
}

// The gap rule with the defaults (session_gap_s 10, gap_periods 10): how many frames of `stamps`
// start a session by their stamps (jumps back or forward), the first frame aside.
int jumps(const std::vector<double>& stamps, StampGuard* g) {
  int n = 0;
  for (double t : stamps) n += StampGuard::startsSession(g->accept(t));
  return n;
}

// Skerki Bank's real ROV survey: frames 13 s apart, a 22 s pause every 30 frames (148 frames).
std::vector<double> stillsSurvey(double start_s = 0.0, int frames = 148) {
  std::vector<double> t{start_s};
  for (int i = 1; i < frames; ++i) t.push_back(t.back() + (i % 30 == 0 ? 22.0 : 13.0));
  return t;
}

TEST(StampGuardGapRule, AStillsCameraAt13SWithPausesOf22SStaysInOneSession) {
  // session_gap_s alone cut this survey into a session per frame (147 jumps, the 245-session replay).
  StampGuard g;
  EXPECT_EQ(jumps(stillsSurvey(), &g), 0);
  ASSERT_TRUE(g.period().has_value());
  EXPECT_DOUBLE_EQ(*g.period(), 13.0);
  EXPECT_DOUBLE_EQ(g.gapThreshold(), 130.0) << "10 of the camera's periods, past session_gap_s";
}

TEST(StampGuardGapRule, AStillsCameraAt0point05HzIsNotCutAtItsSecondFrame) {
  std::vector<double> t;
  for (int i = 0; i < 40; ++i) t.push_back(1000.0 + 20.0 * i);
  StampGuard g;
  EXPECT_EQ(g.accept(t[0]), StampClass::kFirst);
  EXPECT_DOUBLE_EQ(g.gapThreshold(), 100.0) << "no period yet: 10 x session_gap_s";
  EXPECT_EQ(g.accept(t[1]), StampClass::kNext);
  EXPECT_EQ(jumps({t.begin() + 2, t.end()}, &g), 0);
  EXPECT_DOUBLE_EQ(g.gapThreshold(), 200.0);
}

TEST(StampGuardGapRule, AGapAtVideoRateIsStillSessionGapS) {
  std::vector<double> t;
  for (int i = 0; i < 100; ++i) t.push_back(0.1 * i);  // 10 Hz
  StampGuard g;
  EXPECT_EQ(jumps(t, &g), 0);
  EXPECT_DOUBLE_EQ(g.gapThreshold(), 10.0) << "a camera faster than 1 Hz: session_gap_s alone";
  EXPECT_EQ(g.accept(t.back() + 5.0), StampClass::kNext) << "a 5 s hiccup is no new session";
  EXPECT_EQ(g.accept(t.back() + 5.1), StampClass::kNext);
  EXPECT_EQ(g.accept(t.back() + 5.2), StampClass::kNext);
  EXPECT_EQ(g.accept(t.back() + 17.3), StampClass::kJumpForward) << "12 s without a frame";
  EXPECT_NEAR(g.lastJump(), 12.1, 1e-9);
  EXPECT_EQ(g.accept(t.back() + 17.4), StampClass::kNext);
  EXPECT_NEAR(*g.period(), 0.1, 1e-9) << "the jump is not one of the camera's intervals";
}

TEST(StampGuardGapRule, APauseOfMinutesOfAStillsCameraStartsASession) {
  std::vector<double> t = stillsSurvey(0.0, 40);
  const std::vector<double> after = stillsSurvey(t.back() + 300.0, 40);  // 5 minutes without a frame
  t.insert(t.end(), after.begin(), after.end());
  StampGuard g;
  int n = 0, at = -1;
  for (std::size_t i = 0; i < t.size(); ++i) {
    if (StampGuard::startsSession(g.accept(t[i]))) {
      ++n;
      at = static_cast<int>(i);
    }
  }
  EXPECT_EQ(n, 1);
  EXPECT_EQ(at, 40) << "at the first frame after the pause, and only there";
  EXPECT_NEAR(g.lastJump(), 300.0, 1e-9);
}

TEST(StampGuardGapRule, AStillsBagThatLoopsStartsOneSessionAtTheLoop) {
  const std::vector<double> pass = stillsSurvey(5000.0, 60);
  std::vector<double> t = pass;
  t.insert(t.end(), pass.begin(), pass.end());  // played again: the stamps jump back
  StampGuard g;
  std::vector<StampClass> starts;
  for (double s : t)
    if (const StampClass c = g.accept(s); StampGuard::startsSession(c)) starts.push_back(c);
  ASSERT_EQ(starts.size(), 1u);
  EXPECT_EQ(starts[0], StampClass::kJumpBack);
  EXPECT_DOUBLE_EQ(*g.period(), 13.0) << "the camera's rhythm is kept across the loop";
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
