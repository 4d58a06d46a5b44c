// FrameSkipRule and FrameBudget: which waiting frame the live odometry takes when the camera is
// faster than it, and the budget it reports.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <tuple>
#include <utility>
#include <vector>

#include "../../common/fixtures.h"
#include "uw_multislam/core/frontend/frame_skip.h"

namespace uw_multislam {
namespace core {
namespace {

using Reason = FrameSkipRule::Reason;

constexpr double kAltitude = 2.0;

using testing_util::camera320;

// A matched frame at `pose`, with the session's last keyframe at `keyframe`.
ProcessedFrame matched(double stamp_s, const Pose2& pose, const Pose2& keyframe, double keyframe_stamp_s = 0.0) {
  ProcessedFrame p;
  p.stamp_s = stamp_s;
  p.matched = true;
  p.pose = pose;
  p.altitude_m = kAltitude;
  p.keyframe_pose = keyframe;
  p.keyframe_altitude_m = kAltitude;
  p.keyframe_stamp_s = keyframe_stamp_s;
  return p;
}

std::vector<WaitingFrame> waitingAt(const std::vector<double>& stamps) {
  std::vector<WaitingFrame> w;
  for (double s : stamps) w.push_back({s, kAltitude});
  return w;
}

TEST(FootprintOverlap, IsTheSharedFractionOfTheFootprint) {
  const CameraIntrinsics c = camera320();
  EXPECT_NEAR(footprintOverlap(c, Pose2(), kAltitude, kAltitude), 1.0, 1e-6);
  // 2.1333 m wide: a quarter of the width along x leaves three quarters.
  EXPECT_NEAR(footprintOverlap(c, Pose2(0.25 * 320 / 300.0 * kAltitude, 0, 0), kAltitude, kAltitude), 0.75, 1e-4);
  EXPECT_NEAR(footprintOverlap(c, Pose2(5.0, 0, 0), kAltitude, kAltitude), 0.0, 1e-9);
}

// Footprints moved along an image axis have nearly collinear edges: with cv::intersectConvexConvex
// a rotation of 1e-6 rad gave an overlap of 1.0 for a shift that leaves 0.44 (a keyframe the rule
// never took) and 0.48 for one that leaves 0.72 (a keyframe too early).
TEST(FootprintOverlap, IsRightForFootprintsNearlyAlignedWithTheKeyframes) {
  const CameraIntrinsics c = camera320();
  const double w = 320 / 300.0 * kAltitude, h = 240 / 300.0 * kAltitude;
  for (const double x : {0.2, 0.4, 0.6, 0.8, 1.0, 1.2})
    for (const auto& [y, yaw] : std::vector<std::pair<double, double>>{
             {0.0, 0.0}, {0.0, 1e-6}, {1e-6, 1e-6}, {1e-5, -2e-5}, {-1e-6, -2e-5}, {-3e-5, 1e-6}})
      EXPECT_NEAR(footprintOverlap(c, Pose2(x, y, yaw), kAltitude, kAltitude), 1.0 - x / w, 1e-3)
          << x << " " << y << " " << yaw;
  // Along y, diagonally, and turned a quarter about the centre (a 1.6 m square of the 2.13 x 1.6 m footprint).
  EXPECT_NEAR(footprintOverlap(c, Pose2(0, 0.4, 1e-6), kAltitude, kAltitude), 0.75, 1e-3);
  EXPECT_NEAR(footprintOverlap(c, Pose2(w / 2, h / 2, 0), kAltitude, kAltitude), 0.25, 1e-6);
  EXPECT_NEAR(footprintOverlap(c, Pose2(0, 0, M_PI / 2), kAltitude, kAltitude), h / w, 1e-6);
  EXPECT_NEAR(footprintOverlap(c, Pose2(), kAltitude, 2 * kAltitude), 0.25, 1e-6) << "twice as high: a quarter seen";
  EXPECT_NEAR(footprintOverlap(c, Pose2(), 2 * kAltitude, kAltitude), 1.0, 1e-6);
}

TEST(FrameSkipRule, WithoutAPredictionTheOldestFrameIsTaken) {
  FrameSkipRule rule(camera320(), KeyframeOptions());
  EXPECT_EQ(rule.choose(waitingAt({1.0})).reason, Reason::kOnlyOne);
  const auto none = rule.choose(waitingAt({1.0, 2.0, 3.0}));
  EXPECT_EQ(none.index, 0u);
  EXPECT_EQ(none.reason, Reason::kOldest);
  // One frame of the session: no velocity yet.
  ProcessedFrame first = matched(0.0, Pose2(), Pose2());
  first.first = true;
  rule.observe(first);
  EXPECT_EQ(rule.choose(waitingAt({1.0, 2.0})).reason, Reason::kOldest);
  rule.observe(matched(1.0, Pose2(0.1, 0, 0), Pose2()));
  EXPECT_EQ(rule.choose(waitingAt({2.0, 3.0})).reason, Reason::kNewestSafe);
  // A frame that could not be matched (a fallback): the velocity is not trusted any more.
  ProcessedFrame lost;
  lost.stamp_s = 2.0;
  rule.observe(lost);
  EXPECT_FALSE(rule.keyframeDue(3.0, kAltitude).has_value());
  EXPECT_EQ(rule.choose(waitingAt({3.0, 4.0})).index, 0u);
  // A new session's origin forgets the old session's frames.
  rule.observe(matched(5.0, Pose2(), Pose2()));
  rule.observe(matched(6.0, Pose2(0.1, 0, 0), Pose2()));
  ProcessedFrame origin = matched(20.0, Pose2(), Pose2());
  origin.first = true;
  rule.observe(origin);
  EXPECT_EQ(rule.choose(waitingAt({21.0, 22.0})).reason, Reason::kOldest);
}

TEST(FrameSkipRule, TheNewestFrameIsTakenWhileNoKeyframeIsDue) {
  FrameSkipRule rule(camera320(), KeyframeOptions());
  rule.observe(matched(0.0, Pose2(), Pose2()));
  rule.observe(matched(1.0, Pose2(0.1, 0, 0), Pose2()));  // 0.1 m/s along x, keyframe at 0
  // Predicted at 4 s: 0.4 m from the keyframe, overlap 0.81 > 0.5.
  EXPECT_EQ(rule.keyframeDue(4.0, kAltitude), std::optional<bool>(false));
  const auto c = rule.choose(waitingAt({2.0, 3.0, 4.0}));
  EXPECT_EQ(c.index, 2u);
  EXPECT_EQ(c.reason, Reason::kNewestSafe);
}

TEST(FrameSkipRule, WhenTheNewestIsTooFarTheFirstFrameAKeyframeIsDueAtIsTaken) {
  FrameSkipRule rule(camera320(), KeyframeOptions());  // min_overlap 0.5: due beyond 1.067 m along x
  rule.observe(matched(0.0, Pose2(), Pose2()));
  rule.observe(matched(1.0, Pose2(0.3, 0, 0), Pose2()));  // 0.3 m/s
  // 0.9 m (overlap 0.58), 1.2 m (0.44), 1.5 m (0.30): the newest is too far from the keyframe.
  EXPECT_EQ(rule.keyframeDue(3.0, kAltitude), std::optional<bool>(false));
  EXPECT_EQ(rule.keyframeDue(4.0, kAltitude), std::optional<bool>(true));
  const auto c = rule.choose(waitingAt({2.0, 3.0, 4.0, 5.0}));
  EXPECT_EQ(c.index, 2u) << "the frame at 4 s: where processing every frame makes the keyframe";
  EXPECT_EQ(c.reason, Reason::kKeyframeDue);
  // The oldest already due: nothing is skipped.
  EXPECT_EQ(rule.choose(waitingAt({4.0, 5.0})).index, 0u);
}

// Frames prepared on arrival by another thread (~prepare_threads): an earlier safe frame whose
// preparation is under way beats a chosen one whose preparation has not started.
TEST(FrameSkipRule, AnEarlierSafeFrameUnderPreparationIsPreferredToOneNotStarted) {
  FrameSkipRule rule(camera320(), KeyframeOptions());
  rule.observe(matched(0.0, Pose2(), Pose2()));
  rule.observe(matched(1.0, Pose2(0.1, 0, 0), Pose2()));  // 0.1 m/s: no keyframe due up to 4 s
  const std::vector<WaitingFrame> w = waitingAt({2.0, 3.0, 4.0});
  const FrameSkipRule::Choice newest = rule.choose(w);
  ASSERT_EQ(newest.index, 2u);
  // The choice itself under way: kept.
  EXPECT_EQ(rule.preferPrepared(w, newest, {true, true, true}).index, 2u);
  // Not started, an earlier one under way: the newest of those.
  const FrameSkipRule::Choice earlier = rule.preferPrepared(w, newest, {true, true, false});
  EXPECT_EQ(earlier.index, 1u);
  EXPECT_EQ(earlier.reason, Reason::kPrepared);
  EXPECT_EQ(rule.preferPrepared(w, newest, {true, false, false}).index, 0u);
  // None under way (or no flags for these frames): the choice.
  EXPECT_EQ(rule.preferPrepared(w, newest, {false, false, false}).reason, Reason::kNewestSafe);
  EXPECT_EQ(rule.preferPrepared(w, newest, {true, true}).index, 2u);
  // choose() with the flags: the same preference; without any (nothing prepared on arrival): choose().
  EXPECT_EQ(rule.choose(w, {true, true, false}).index, 1u);
  EXPECT_EQ(rule.choose(w, {true, true, false}).reason, Reason::kPrepared);
  EXPECT_EQ(rule.choose(w, {}).index, 2u);
  EXPECT_EQ(rule.choose(w, {}).reason, Reason::kNewestSafe);
}

TEST(FrameSkipRule, APreparedFrameIsTakenOnlyWhereItIsSafe) {
  FrameSkipRule rule(camera320(), KeyframeOptions());
  rule.observe(matched(0.0, Pose2(), Pose2()));
  rule.observe(matched(1.0, Pose2(0.3, 0, 0), Pose2()));  // 0.3 m/s: due from 4 s on
  const std::vector<WaitingFrame> w = waitingAt({2.0, 3.0, 4.0, 5.0});
  const FrameSkipRule::Choice due = rule.choose(w);
  ASSERT_EQ(due.index, 2u);
  ASSERT_EQ(due.reason, Reason::kKeyframeDue);
  // An earlier safe frame under way: taken (the keyframe frame waits for the next choice).
  EXPECT_EQ(rule.preferPrepared(w, due, {false, true, false, true}).index, 1u);
  // Only a later frame under way: never a frame past the one a keyframe is due at.
  EXPECT_EQ(rule.preferPrepared(w, due, {false, false, false, true}).index, 2u);
  // Without a prediction nothing is known to be safe: the choice (the oldest) stays.
  FrameSkipRule fresh(camera320(), KeyframeOptions());
  const FrameSkipRule::Choice oldest = fresh.choose(w);
  ASSERT_EQ(oldest.reason, Reason::kOldest);
  EXPECT_EQ(fresh.preferPrepared(w, oldest, {false, true, true, true}).index, 0u);
  EXPECT_EQ(fresh.preferPrepared(w, {3, Reason::kNewestSafe}, {true, true, true, false}).index, 3u);
}

TEST(FrameSkipRule, ATurnOrTheTimeLimitMakeAKeyframeDueLikeTheKeyframeRule) {
  KeyframeOptions k;
  k.max_rotation_rad = 0.5;
  FrameSkipRule turning(camera320(), k);
  turning.observe(matched(0.0, Pose2(), Pose2()));
  turning.observe(matched(1.0, Pose2(0, 0, 0.2), Pose2()));  // turning in place, 0.2 rad/s
  EXPECT_EQ(turning.keyframeDue(2.0, kAltitude), std::optional<bool>(false));
  EXPECT_EQ(turning.keyframeDue(3.0, kAltitude), std::optional<bool>(true));  // 0.6 rad
  EXPECT_EQ(turning.choose(waitingAt({2.0, 3.0, 4.0})).index, 1u);
  k.max_interval_s = 2.5;
  FrameSkipRule timed(camera320(), k);
  timed.observe(matched(0.0, Pose2(), Pose2(), 0.0));
  timed.observe(matched(1.0, Pose2(), Pose2(), 0.0));  // standing still
  EXPECT_EQ(timed.keyframeDue(2.0, kAltitude), std::optional<bool>(false));
  EXPECT_EQ(timed.keyframeDue(3.0, kAltitude), std::optional<bool>(true));
}

TEST(FrameSkipRule, AHigherAltitudeWidensTheFootprint) {
  FrameSkipRule low(camera320(), KeyframeOptions());
  low.observe(matched(0.0, Pose2(), Pose2()));
  low.observe(matched(1.0, Pose2(0.3, 0, 0), Pose2()));
  EXPECT_EQ(low.keyframeDue(4.0, kAltitude), std::optional<bool>(true));  // 1.2 m of a 2.13 m footprint: 0.44
  EXPECT_EQ(low.keyframeDue(4.0, std::nan("")), std::optional<bool>(true)) << "unknown: the last frame's altitude";
  FrameSkipRule high(camera320(), KeyframeOptions());
  for (double t : {0.0, 1.0}) {
    ProcessedFrame p = matched(t, Pose2(0.3 * t, 0, 0), Pose2());
    p.altitude_m = p.keyframe_altitude_m = 4.0;
    high.observe(p);
  }
  EXPECT_EQ(high.keyframeDue(4.0, 4.0), std::optional<bool>(false)) << "1.2 m of a 4.27 m footprint: 0.72";
  EXPECT_EQ(high.keyframeDue(4.0, std::nan("")), std::optional<bool>(false));
}

// A camera `speedup` times faster than the odometry, on a lawnmower leg with a turn: the worker
// takes frames by the rule whenever it is free. With an exact prediction the keyframes are the
// very frames processing every frame makes keyframes, so no link is weaker and no session splits.
struct SkipRun {
  std::vector<int> keyframes;        // frame indexes
  std::vector<double> link_overlap;  // each keyframe's overlap with the one before
  int processed = 0;
  double worst_latency_periods = 0;  // from a frame's arrival to the end of its processing
};

Pose2 truth(int i) {
  // 0.12 m per frame along x for 40 frames, then a turn of 0.04 rad per frame while moving.
  if (i <= 40) return Pose2(0.12 * i, 0, 0);
  Pose2 p(0.12 * 40, 0, 0);
  for (int k = 41; k <= i; ++k) p = compose(p, Pose2(0.12, 0, 0.04));
  return p;
}

SkipRun simulate(int frames, double speedup, bool skip) {
  const CameraIntrinsics c = camera320();
  KeyframeOptions k;
  FrameSkipRule rule(c, k);
  SkipRun run;
  int kf = -1;
  Pose2 kf_pose;
  const double period = 1.0, cost = speedup * period;  // processing one frame takes `speedup` periods
  double free_at = 0.0;
  int next = 0;  // oldest frame not taken or skipped
  while (next < frames) {
    const double now = std::max(free_at, next * period);
    const int newest = std::min(frames - 1, static_cast<int>(std::floor(now / period + 1e-9)));
    std::vector<WaitingFrame> waiting;
    for (int i = next; i <= newest; ++i) waiting.push_back({i * period, kAltitude});
    const int take = skip ? next + static_cast<int>(rule.choose(waiting).index) : next;
    // The ideal odometry: the true pose; a keyframe when the keyframe rule says so.
    const Pose2 pose = truth(take);
    ProcessedFrame p = matched(take * period, pose, kf_pose);
    p.first = kf < 0;
    if (kf < 0) {
      kf = take, kf_pose = pose;
      run.keyframes.push_back(take);
    } else {
      const Pose2 m = between(kf_pose, pose);
      const double overlap = footprintOverlap(c, m, kAltitude, kAltitude);
      if (overlap < k.min_overlap || std::abs(m.yaw()) > k.max_rotation_rad) {
        kf = take, kf_pose = pose;
        run.keyframes.push_back(take);
        run.link_overlap.push_back(overlap);
      }
    }
    p.keyframe_pose = kf_pose;
    p.keyframe_stamp_s = kf * period;
    rule.observe(p);
    ++run.processed;
    free_at = now + cost;
    run.worst_latency_periods = std::max(run.worst_latency_periods, (free_at - take * period) / period);
    next = take + 1;
  }
  return run;
}

TEST(FrameSkipRule, SkippingKeepsTheKeyframesOfProcessingEveryFrame) {
  const SkipRun every = simulate(120, 0.5, false);  // the odometry keeps up
  ASSERT_GT(every.keyframes.size(), 10u);
  for (double speedup : {2.0, 4.0}) {
    const SkipRun skipping = simulate(120, speedup, true);
    EXPECT_EQ(skipping.keyframes, every.keyframes) << speedup << "x";
    EXPECT_LT(skipping.processed, 120 * 0.8) << "frames were skipped at " << speedup << "x";
    for (std::size_t i = 0; i < skipping.link_overlap.size(); ++i)
      EXPECT_GE(skipping.link_overlap[i], every.link_overlap[i] - 1e-9);
  }
  // Without the rule (the newest frame, always) links are weaker than processing every frame's:
  // the comparison above could fail.
  const CameraIntrinsics c = camera320();
  const double newest_link = footprintOverlap(c, between(truth(0), truth(12)), kAltitude, kAltitude);
  EXPECT_LT(newest_link, *std::min_element(every.link_overlap.begin(), every.link_overlap.end()));
}

TEST(FrameSkipRule, TheLatencyStaysBoundedWhereTheQueueWouldGrow) {
  // In order (a FIFO without drops) the latency grows with the run; with the rule it stays within
  // a few processing times (a frame waits at most for the one in progress and a keyframe's).
  const SkipRun fifo = simulate(120, 2.0, false);
  const SkipRun skipping = simulate(120, 2.0, true);
  EXPECT_GT(fifo.worst_latency_periods, 100.0);
  EXPECT_LE(skipping.worst_latency_periods, 3 * 2.0 + 1e-9);
}

TEST(FrameBudget, ComparesTheRecentCostWithTheRecentInputPeriod) {
  FrameBudget b(4);
  EXPECT_EQ(b.load(), 0.0) << "unknown";
  for (int i = 0; i < 20; ++i) b.arrived(0.05 * i);  // 20 Hz
  EXPECT_NEAR(b.inputPeriodMs(), 50.0, 1e-9);
  for (int i = 0; i < 20; ++i) b.processed(100.0);
  EXPECT_NEAR(b.msPerFrame(), 100.0, 1e-9);
  EXPECT_NEAR(b.load(), 2.0, 1e-9);
  for (int i = 0; i < 20; ++i) b.processed(25.0);  // the recent frames count, not the first ones
  EXPECT_NEAR(b.load(), 0.5, 1e-3);
  b.arrived(0.5);  // a clock that stands still or goes back adds no interval
  EXPECT_NEAR(b.inputPeriodMs(), 50.0, 1e-9);
}

TEST(FrameBudget, KeepsTheStampsPeriodApartFromTheArrivals) {
  FrameBudget b(4);  // EMA weight 2 / (4 + 1) = 0.4
  EXPECT_EQ(b.timing(0).stamp_period_s, 0.0) << "unknown";
  EXPECT_EQ(b.timing(0).last_arrival_s, 0.0) << "none yet";
  // A bag replayed twice as fast as recorded: stamps 0.1 s apart arrive every 0.05 s.
  for (int i = 0; i < 10; ++i) b.arrived(100.0 + 0.05 * i, 0.1 * i);
  EXPECT_NEAR(b.inputPeriodMs(), 50.0, 1e-9);
  EXPECT_NEAR(b.timing(0).stamp_period_s, 0.1, 1e-12);
  EXPECT_DOUBLE_EQ(b.timing(0).last_arrival_s, 100.0 + 0.05 * 9);
  // One interval of 0.2 s moves the mean by 0.4 of the difference.
  b.arrived(100.5, 1.1);
  EXPECT_NEAR(b.timing(0).stamp_period_s, 0.1 + 0.4 * (0.2 - 0.1), 1e-12);
  const double before = b.timing(0).stamp_period_s;
  // A stamp that goes back, or none (NaN), adds no stamp interval; the arrival still counts.
  b.arrived(100.55, 1.0);
  EXPECT_EQ(b.timing(0).stamp_period_s, before);
  EXPECT_DOUBLE_EQ(b.timing(0).last_arrival_s, 100.55);
  b.arrived(100.6);
  EXPECT_EQ(b.timing(0).stamp_period_s, before);
  EXPECT_DOUBLE_EQ(b.timing(0).last_arrival_s, 100.6);
  // The next stamp's interval is from the one that went back (1.0), not from 1.1.
  b.arrived(100.65, 1.1);
  EXPECT_NEAR(b.timing(0).stamp_period_s, before + 0.4 * (0.1 - before), 1e-12);
  // The first interval is taken as it is (no average of it with the unknown 0).
  FrameBudget first(4);
  first.arrived(1.0, 5.0);
  EXPECT_EQ(first.timing(0).stamp_period_s, 0.0) << "one stamp: no interval";
  first.arrived(1.01, 5.25);
  EXPECT_DOUBLE_EQ(first.timing(0).stamp_period_s, 0.25);
}

TEST(KeyframeLookahead, SpansTheFramesThatArriveWhileOneIsProcessedButTheNewest) {
  const double period = 0.125, stamps = 0.25;  // a replay twice as fast as recorded
  EXPECT_EQ(keyframeLookaheadS(0.1, period, stamps), 0.0) << "keeps up";
  EXPECT_EQ(keyframeLookaheadS(period, period, stamps), 0.0) << "exactly keeps up";
  EXPECT_EQ(keyframeLookaheadS(2 * period, period, stamps), stamps) << "2x: one frame waits behind the newest";
  EXPECT_EQ(keyframeLookaheadS(2.1 * period, period, stamps), 2 * stamps);
  EXPECT_EQ(keyframeLookaheadS(4 * period, period, stamps), 3 * stamps);
  EXPECT_EQ(keyframeLookaheadS(4 * period, period, period), 3 * period) << "in stamps, not arrivals";
  const double nan = std::nan(""), inf = std::numeric_limits<double>::infinity();
  for (const auto& [cost, p, s] : std::vector<std::tuple<double, double, double>>{{nan, period, stamps},
                                                                                  {inf, period, stamps},
                                                                                  {0.5, nan, stamps},
                                                                                  {0.5, 0.0, stamps},
                                                                                  {0.5, -0.1, stamps},
                                                                                  {0.5, period, 0.0},
                                                                                  {0.5, period, nan},
                                                                                  {0.5, period, -0.25},
                                                                                  {0.0, 0.0, 0.0}})
    EXPECT_EQ(keyframeLookaheadS(cost, p, s), 0.0) << cost << " " << p << " " << s;
}

// waitForNext: a rule at 0.1 m/s with its keyframe at 0 (no keyframe due before 10 s), frames
// arriving every 0.125 s (binary fractions: the deadlines compare exactly), regularly, the newest at
// 100 s, a worker twice as slow as the input (behind).
class WaitForNextTest : public ::testing::Test {
 protected:
  static constexpr double kPeriod = 0.125, kLast = 100.0, kFraction = 0.25;
  static constexpr double kNext = kLast + kPeriod, kUntil = kNext + kPeriod / 8;  // jitter 0: the least margin

  WaitForNextTest() : rule_(camera320(), KeyframeOptions()) {
    rule_.observe(matched(0.0, Pose2(), Pose2()));
    rule_.observe(matched(1.0, Pose2(0.1, 0, 0), Pose2()));
  }
  // The newest of the frames waiting, chosen at `now`.
  InputTiming at(double now) const {
    InputTiming t;
    t.now_s = now;
    t.chosen_arrival_s = kLast;
    t.last_arrival_s = kLast;
    t.period_s = kPeriod;
    t.cost_s = 2 * kPeriod;
    return t;
  }
  std::optional<double> advice(const std::vector<WaitingFrame>& w, const InputTiming& t,
                               double fraction = kFraction) const {
    return waitForNext(rule_, w, rule_.choose(w), t, fraction);
  }

  FrameSkipRule rule_;
  const std::vector<WaitingFrame> waiting_ = waitingAt({2.0, 3.0, 4.0});
};

TEST_F(WaitForNextTest, AStaleNewestChoiceWaitsForTheNextFrameUntilAMarginAfterItsExpectedArrival) {
  ASSERT_EQ(rule_.choose(waiting_).reason, Reason::kNewestSafe);
  const std::optional<double> a = advice(waiting_, at(kLast + kPeriod / 2));  // waited half a period > a quarter
  EXPECT_TRUE(a.has_value());
  EXPECT_EQ(a, std::optional<double>(kUntil));
  // Alone and predicted safe (kOnlyOne): the same.
  const std::vector<WaitingFrame> one = waitingAt({4.0});
  ASSERT_EQ(rule_.choose(one).reason, Reason::kOnlyOne);
  const std::optional<double> alone = advice(one, at(kLast + kPeriod / 2));
  EXPECT_TRUE(alone.has_value());
  EXPECT_EQ(alone, std::optional<double>(kUntil));
}

TEST_F(WaitForNextTest, AFreshChoiceIsTakenNow) {
  EXPECT_FALSE(advice(waiting_, at(kLast)).has_value());
  EXPECT_FALSE(advice(waiting_, at(kLast + kFraction * kPeriod)).has_value()) << "exactly the fraction";
  EXPECT_TRUE(advice(waiting_, at(kLast + kFraction * kPeriod + 1.0 / 1024)).has_value());
  // The choice's own arrival counts, not the newest arrival's.
  InputTiming older = at(kLast + kFraction * kPeriod);
  older.chosen_arrival_s = kLast - 1.0 / 1024;
  EXPECT_TRUE(advice(waiting_, older).has_value());
}

TEST_F(WaitForNextTest, ANextFrameLateWithinTheJitterMarginIsWaitedForOneLaterBeyondItIsNot) {
  const std::optional<double> late = advice(waiting_, at(kNext + kPeriod / 16));  // jitter: still expected
  EXPECT_TRUE(late.has_value());
  EXPECT_EQ(late, std::optional<double>(kUntil)) << "the same deadline, not a margin from now";
  EXPECT_FALSE(advice(waiting_, at(kUntil)).has_value()) << "the deadline itself";
  EXPECT_FALSE(advice(waiting_, at(kNext + kPeriod)).has_value()) << "the input stopped or slowed";
  // The margin is four mean deviations of the arrivals, within [1/8, 1/2] period.
  InputTiming jittery = at(kLast + kPeriod / 2);
  jittery.jitter_s = kPeriod / 16;
  EXPECT_EQ(advice(waiting_, jittery), std::optional<double>(kNext + kPeriod / 4));
  jittery.jitter_s = kPeriod / 4;
  EXPECT_EQ(advice(waiting_, jittery), std::optional<double>(kNext + kPeriod / 2));
  EXPECT_FALSE(advice(waiting_, at(kNext + kPeriod / 4)).has_value()) << "beyond the least margin";
}

TEST_F(WaitForNextTest, AClockThatSteppedBackIsNotWaitedOn) {
  // The chosen frame arrived long before; the newest arrival lies ahead of now by more than a period.
  InputTiming t = at(kLast - kPeriod);
  t.chosen_arrival_s = kLast - 1.0;
  EXPECT_FALSE(advice(waiting_, t).has_value());
  t.now_s = kLast;  // the next arrival a period ahead: waited for
  EXPECT_TRUE(advice(waiting_, t).has_value());
}

TEST_F(WaitForNextTest, AKeyframeDueOrNoPredictionIsTakenNow) {
  const InputTiming stale = at(kLast + kPeriod / 2);
  // 0.3 m/s: due at 4 s (1.2 m from the keyframe), not at 3 s.
  FrameSkipRule fast(camera320(), KeyframeOptions());
  fast.observe(matched(0.0, Pose2(), Pose2()));
  fast.observe(matched(1.0, Pose2(0.3, 0, 0), Pose2()));
  const std::vector<WaitingFrame> safe = waitingAt({2.0, 3.0});
  ASSERT_EQ(fast.choose(safe).reason, Reason::kNewestSafe);
  EXPECT_TRUE(waitForNext(fast, safe, fast.choose(safe), stale, kFraction).has_value()) << "control";
  // The newest is the first frame due: kKeyframeDue at the newest.
  const std::vector<WaitingFrame> due_newest = waitingAt({2.0, 3.0, 4.0});
  const FrameSkipRule::Choice c = fast.choose(due_newest);
  ASSERT_EQ(c.index, 2u);
  ASSERT_EQ(c.reason, Reason::kKeyframeDue);
  EXPECT_FALSE(waitForNext(fast, due_newest, c, stale, kFraction).has_value());
  // Even labelled newest-safe, a newest frame a keyframe is due at is not passed over.
  EXPECT_FALSE(waitForNext(fast, due_newest, {2, Reason::kNewestSafe}, stale, kFraction).has_value());
  // Alone and due.
  EXPECT_FALSE(waitForNext(fast, waitingAt({4.0}), {0, Reason::kOnlyOne}, stale, kFraction).has_value());
  // An older frame a keyframe is due at (newer ones waiting).
  const std::vector<WaitingFrame> due_older = waitingAt({2.0, 3.0, 4.0, 5.0});
  const FrameSkipRule::Choice older = fast.choose(due_older);
  ASSERT_EQ(older.index, 2u);
  ASSERT_EQ(older.reason, Reason::kKeyframeDue);
  EXPECT_FALSE(waitForNext(fast, due_older, older, stale, kFraction).has_value());
  // An earlier prepared frame, safe but not the newest.
  EXPECT_TRUE(advice(waiting_, stale).has_value()) << "control";
  const FrameSkipRule::Choice prepared = rule_.choose(waiting_, {true, true, false});
  ASSERT_EQ(prepared.reason, Reason::kPrepared);
  EXPECT_FALSE(waitForNext(rule_, waiting_, prepared, stale, kFraction).has_value());
  // No prediction (a fresh session): the oldest of several, or the only one, taken now.
  FrameSkipRule fresh(camera320(), KeyframeOptions());
  ASSERT_EQ(fresh.choose(waiting_).reason, Reason::kOldest);
  EXPECT_FALSE(waitForNext(fresh, waiting_, fresh.choose(waiting_), stale, kFraction).has_value());
  EXPECT_FALSE(waitForNext(fresh, waiting_, {2, Reason::kNewestSafe}, stale, kFraction).has_value());
  const std::vector<WaitingFrame> one = waitingAt({4.0});
  ASSERT_EQ(fresh.choose(one).reason, Reason::kOnlyOne);
  EXPECT_FALSE(waitForNext(fresh, one, fresh.choose(one), stale, kFraction).has_value());
  // Nothing waiting, or a choice past the end.
  EXPECT_FALSE(waitForNext(rule_, {}, {0, Reason::kOnlyOne}, stale, kFraction).has_value());
  EXPECT_FALSE(waitForNext(rule_, waiting_, {3, Reason::kNewestSafe}, stale, kFraction).has_value());
}

TEST_F(WaitForNextTest, AFractionOfOneOrAnUnknownTimingNeverWaits) {
  const InputTiming stale = at(kLast + kPeriod / 2);
  ASSERT_TRUE(advice(waiting_, stale).has_value());
  EXPECT_TRUE(advice(waiting_, stale, 0.0).has_value()) << "0: any wait is too long";
  for (const double fraction : {1.0, 2.0, std::nan("")})
    EXPECT_FALSE(advice(waiting_, stale, fraction).has_value()) << fraction;
  for (const double period : {0.0, -kPeriod, std::nan("")}) {
    InputTiming t = stale;
    t.period_s = period;
    EXPECT_FALSE(advice(waiting_, t).has_value()) << "period " << period;
  }
  InputTiming none = stale;
  none.last_arrival_s = 0.0;
  EXPECT_FALSE(advice(waiting_, none).has_value()) << "no arrival yet";
}

TEST_F(WaitForNextTest, AWorkerThatKeepsUpOnAverageOrIrregularArrivalsNeverWait) {
  InputTiming t = at(kLast + kPeriod / 2);  // stale
  ASSERT_TRUE(advice(waiting_, t).has_value());
  t.cost_s = kPeriod;  // keeps up on average: the late frame is processed, not skipped
  EXPECT_FALSE(advice(waiting_, t).has_value());
  t.cost_s = 0.0;  // not measured yet
  EXPECT_FALSE(advice(waiting_, t).has_value());
  t.cost_s = 2 * kPeriod;
  t.jitter_s = kPeriod / 2;  // at the bound: still regular
  EXPECT_TRUE(advice(waiting_, t).has_value());
  t.jitter_s = kPeriod;  // bursts (frames paired with a slower altimeter): no next arrival to wait for
  EXPECT_FALSE(advice(waiting_, t).has_value());
}

TEST(FrameBudget, TheJitterIsTheMeanDeviationOfTheIntervals) {
  FrameBudget regular(4), bursts(4);
  for (int i = 0; i < 40; ++i) regular.arrived(0.1 * i);
  EXPECT_NEAR(regular.timing(0).jitter_s, 0.0, 1e-9);
  // Five frames at once every 0.5 s (a 10 Hz camera paired with a 2 Hz altimeter): period 100 ms on
  // average, intervals 0 or 500 ms.
  for (int burst = 0; burst < 20; ++burst)
    for (int k = 0; k < 5; ++k) bursts.arrived(0.5 * burst + 1e-6 * k);
  EXPECT_GT(bursts.timing(0).jitter_s, 0.5 * bursts.timing(0).period_s);
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
