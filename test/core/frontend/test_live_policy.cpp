// The live odometry's whole newest policy in simulated time: a camera faster than the worker, the
// skip rule (FrameSkipRule), the wait for a fresher frame (waitForNext) and keyframes ahead
// (keyframeLookaheadS, as Odometry applies OdometryInput::keyframe_lookahead_s). The worker is an
// ideal odometry (true poses, a deterministic cost), so what is measured is the policy alone:
// the latency of each pose, the time-averaged age of the newest pose, and the keyframe links.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <optional>
#include <utility>
#include <vector>

#include "../../common/fixtures.h"
#include "uw_multislam/core/frontend/frame_skip.h"

namespace uw_multislam {
namespace core {
namespace {

constexpr double kAltitude = 2.0;

using testing_util::camera320;

// 0.06 m per frame along x for 80 frames, then a turn of 0.02 rad per frame while moving.
Pose2 truth(int i) {
  if (i <= 80) return Pose2(0.06 * i, 0, 0);
  Pose2 p(0.06 * 80, 0, 0);
  for (int k = 81; k <= i; ++k) p = compose(p, Pose2(0.06, 0, 0.02));
  return p;
}

struct Policy {
  bool skip = true;             // the skip rule (false: every frame in order, the reference)
  double stale_fraction = 1.0;  // waitForNext (1: never waits)
  bool lookahead = false;       // keyframes ahead
};

struct SimRun {
  std::vector<int> keyframes;        // frame indexes
  std::vector<double> link_overlap;  // each keyframe's overlap with the one before
  std::vector<double> latency;       // per pose: its publication minus its stamp, in input periods
  double mean_age = 0;               // time-averaged age of the newest pose, periods
  int waits = 0, early = 0;
};

// Frames arrive at i (periods), stamped i; a frame costs `cost` periods.
SimRun simulate(int frames, double cost, const Policy& policy) {
  const CameraIntrinsics c = camera320();
  const KeyframeOptions k;
  FrameSkipRule rule(c, k);
  SimRun run;
  int kf = -1, last = -1;
  Pose2 kf_pose;
  double free_at = 0.0;
  int next = 0;                                      // the oldest frame neither taken nor skipped
  std::vector<std::pair<double, double>> published;  // (time, stamp)
  const auto overlapFromKeyframe = [&](const Pose2& pose) {
    return footprintOverlap(c, between(kf_pose, pose), kAltitude, kAltitude);
  };
  const auto due = [&](const Pose2& pose, double stamp) {  // the keyframe rule (Odometry::needsKeyframe)
    return k.takes(overlapFromKeyframe(pose), between(kf_pose, pose).yaw(), stamp - kf);
  };
  while (next < frames) {
    double now = std::max(free_at, static_cast<double>(next));
    std::optional<double> deadline;
    int take = next;
    for (;;) {
      const int newest = std::min(frames - 1, static_cast<int>(std::floor(now + 1e-9)));
      std::vector<WaitingFrame> waiting;
      for (int i = next; i <= newest; ++i) waiting.push_back({static_cast<double>(i), kAltitude});
      const FrameSkipRule::Choice choice = policy.skip ? rule.choose(waiting) : FrameSkipRule::Choice{};
      take = next + static_cast<int>(choice.index);
      InputTiming t;
      t.now_s = now;
      t.chosen_arrival_s = take;
      t.last_arrival_s = newest;
      t.period_s = 1.0;
      t.cost_s = cost;
      const std::optional<double> until = policy.skip && newest + 1 < frames
                                              ? waitForNext(rule, waiting, choice, t, policy.stale_fraction)
                                              : std::nullopt;
      if (!until) break;
      if (!deadline) deadline = *until, ++run.waits;
      if (now >= *deadline) break;
      now = std::min(*deadline, static_cast<double>(newest + 1));  // the next arrival (always before the deadline)
    }
    const Pose2 pose = truth(take);
    bool keyframe = kf < 0;
    if (!keyframe) {
      keyframe = due(pose, take);
      if (!keyframe && policy.lookahead && last >= 0) {
        // Odometry::dueAhead: constant velocity from the previous frame processed.
        const double ahead = keyframeLookaheadS(cost, 1.0, 1.0);
        if (ahead > 0 && due(extrapolate(pose, between(truth(last), pose), ahead / (take - last)), take + ahead)) {
          keyframe = true;
          ++run.early;
        }
      }
    }
    if (keyframe) {
      if (kf >= 0) run.link_overlap.push_back(overlapFromKeyframe(pose));
      kf = take, kf_pose = pose;
      run.keyframes.push_back(take);
    }
    ProcessedFrame p;
    p.stamp_s = take;
    p.matched = true;
    p.first = run.keyframes.size() == 1 && keyframe;
    p.pose = pose;
    p.altitude_m = p.keyframe_altitude_m = kAltitude;
    p.keyframe_pose = kf_pose;
    p.keyframe_stamp_s = kf;
    rule.observe(p);
    free_at = now + cost;
    run.latency.push_back(free_at - take);
    published.emplace_back(free_at, take);
    last = take;
    next = take + 1;
  }
  double area = 0.0, freshest = published.front().second;
  for (std::size_t i = 0; i + 1 < published.size(); ++i) {
    freshest = std::max(freshest, published[i].second);
    const double d = published[i + 1].first - published[i].first;
    area += d * (published[i].first - freshest) + d * d / 2.0;
  }
  run.mean_age = area / (published.back().first - published.front().first);
  return run;
}

// The largest latency but for the first two poses (taken without a prediction) and the last one
// (nothing fresher comes to wait for), in input periods.
double steadyMax(const SimRun& r) { return *std::max_element(r.latency.begin() + 2, r.latency.end() - 1); }

const Policy kBefore{true, 1.0, false};  // the newest safe frame at once, the keyframe rule as it is
const Policy kNow{true, 0.25, true};     // the defaults

// A frame cost of 2.2 and 4.2 input periods: the phase of the worker's end against the arrivals drifts.
TEST(LivePolicy, AtAboutTwiceTheSustainableRateNoPoseIsOlderThanTheCostAndAQuarterPeriod) {
  const SimRun before = simulate(300, 2.2, kBefore), now = simulate(300, 2.2, kNow);
  // Before: a pose waited up to a period, and the first frame a keyframe is due at waited behind a
  // newer one, up to a frame cost.
  EXPECT_GT(steadyMax(before), 3.0);
  EXPECT_LE(steadyMax(now), 2.2 + 0.25 + 1e-9);
  EXPECT_GT(now.waits, 0);
  EXPECT_GT(now.early, 0);
  // Fresher on the time average, not only per pose: the age of the newest pose falls.
  EXPECT_LT(now.mean_age, before.mean_age);
}

TEST(LivePolicy, AtAboutFourTimesTheRateTheBoundHoldsToo) {
  const SimRun before = simulate(300, 4.2, kBefore), now = simulate(300, 4.2, kNow);
  EXPECT_GT(steadyMax(before), 5.2);
  EXPECT_LE(steadyMax(now), 4.2 + 0.25 + 1e-9);
  EXPECT_LT(now.mean_age, before.mean_age);
}

TEST(LivePolicy, NoKeyframeLinkIsWeakerThanProcessingEveryFrame) {
  const SimRun every = simulate(300, 0.5, Policy{false, 1.0, false});
  ASSERT_GT(every.keyframes.size(), 8u);
  const double weakest = *std::min_element(every.link_overlap.begin(), every.link_overlap.end());
  for (double cost : {2.2, 3.0, 4.2}) {
    const SimRun now = simulate(300, cost, kNow);
    for (double o : now.link_overlap) EXPECT_GE(o, weakest - 1e-9) << cost << "x";
    // Keyframes ahead come earlier, not more than one per keyframe of processing every frame.
    EXPECT_LE(now.keyframes.size(), 2 * every.keyframes.size()) << cost << "x";
  }
}

TEST(LivePolicy, AWorkerThatKeepsUpNeitherWaitsNorMakesKeyframesAhead) {
  const SimRun every = simulate(300, 0.5, Policy{false, 1.0, false});
  const SimRun now = simulate(300, 0.5, kNow);
  EXPECT_EQ(now.keyframes, every.keyframes);
  EXPECT_EQ(now.waits, 0);
  EXPECT_EQ(now.early, 0);
  for (double l : now.latency) EXPECT_DOUBLE_EQ(l, 0.5);
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
