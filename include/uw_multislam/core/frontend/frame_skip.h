// Bounded latency for a live camera faster than the odometry: which waiting frame to process next.
//
// When frames arrive faster than the odometry processes them, processing them in order makes the
// latency grow to the queue's length, and dropping the oldest leaves which frames are used to
// chance. FrameSkipRule takes the NEWEST waiting frame instead, unless skipping there could change
// the keyframe chain, so that skipping never splits a session that processing every frame would
// not split (tracking is lost only when frames cannot be matched to their keyframe, paper 000 §5):
//
//   - Each waiting frame's pose is predicted from the last two frames processed (constant velocity
//     between their stamps), and with it its footprint overlap with the last keyframe and its turn
//     from it: the quantities of the keyframe rule (core/frontend/odometry.h: min_overlap,
//     max_rotation_rad, max_interval_s).
//   - A frame the keyframe rule would NOT take is "safe": processing every frame, it would be a
//     tracked frame matched to the same keyframe; skipping it changes no keyframe.
//   - The newest waiting frame is taken when it is safe (the frames before it are skipped).
//     Otherwise the first waiting frame that is not safe is taken: the frame at which processing
//     every frame would make the next keyframe, at no lower overlap than it would have then; the
//     safe frames before it are skipped and the newer ones wait for the next choice, against the
//     new keyframe.
//   - Without a prediction (a session's first frame, after a frame that could not be matched or
//     was skipped by the odometry, while tracking is lost) the oldest waiting frame is taken:
//     exactly what processing every frame does.
//
// Waiting for the next frame (waitForNext): a worker that is behind and takes the newest frame the
// moment it frees up gives each pose an age of the frame's wait (up to an input period) plus its
// processing; waiting for a frame about to arrive instead gives a later pose that is fresher by
// more than it is later. This is the "update or wait" result for the freshness of information
// (Sun, Uysal-Biyikoglu, Yates, Koksal and Shroff, "Update or Wait: How to Keep Your Data Fresh",
// IEEE Trans. Inf. Theory 63(11), 2017: starting at once is not optimal when the service time is
// long). With a frame cost of 2 input periods, starting only frames younger than a quarter period
// (else waiting for the next) lowers the time-averaged age of the newest pose from 3.50 to 3.18
// periods and its largest latency from 3 to 2.25 periods, for 12 % fewer poses (a deterministic
// model; bench_load.sh measures it). A safe frame passed over this way is skipped like any other.
//
// Keyframes ahead (keyframeLookaheadS): the first frame a keyframe is due at is taken even when a
// newer one waits, so when it arrives while another frame is processed it waits up to a frame cost.
// The odometry is told instead how far ahead the frames that will wait lie
// (core::OdometryInput::keyframe_lookahead_s): when the keyframe rule would take one of them, the
// frame it processes now becomes the keyframe, earlier and at a higher overlap.
//
// FrameBudget measures what the live node reports on /diagnostics: the recent processing time per
// frame against the recent input period.
//
// ROS-free; tested in test/core/frontend/test_frame_skip.cpp.
#pragma once

#include <cstddef>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "uw_multislam/core/common/thread_annotations.h"
#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/frontend/odometry.h"
#include "uw_multislam/core/geometry/se2.h"

namespace uw_multislam {
namespace core {

/// The fraction of the footprint of a frame at `altitude_m`, placed by `motion` in its keyframe's
/// frame, that the keyframe's footprint (at `kf_altitude_m`) covers: the keyframe rule's overlap.
double footprintOverlap(const CameraIntrinsics& camera, const Pose2& motion, double kf_altitude_m, double altitude_m);

/// A frame waiting for the odometry.
struct WaitingFrame {
  double stamp_s = 0.0;
  double altitude_m = 0.0;  // not finite or <= 0: unknown (the last frame's is assumed)
};

/// What the odometry did with a frame it processed.
struct ProcessedFrame {
  double stamp_s = 0.0;
  bool matched = false;  // a session is open and the frame's motion was measured (tracked, a keyframe, the first)
  bool first = false;    // the frame started a session (its origin: no velocity yet)
  Pose2 pose;            // in the session frame (when matched)
  double altitude_m = 0.0;
  Pose2 keyframe_pose;  // the session's last keyframe after this frame
  double keyframe_altitude_m = 0.0;
  double keyframe_stamp_s = 0.0;
};

/// The ProcessedFrame of an odometry's update (`odometry`: the session's, null while none is open).
ProcessedFrame processedFrame(const OdometryUpdate& update, double stamp_s, double altitude_m, bool session_started,
                              const Odometry* odometry);

class FrameSkipRule {
 public:
  enum class Reason {
    kOldest,       // no prediction: the oldest waiting frame, as without skipping
    kNewestSafe,   // the newest waiting frame, which the keyframe rule would not take
    kKeyframeDue,  // the first waiting frame the keyframe rule would take
    kOnlyOne,      // one frame waiting: nothing to choose
    kPrepared,     // an earlier frame than the choice, safe, whose preparation is under way (preferPrepared)
  };
  struct Choice {
    std::size_t index = 0;  // into the waiting frames; the ones before it are skipped
    Reason reason = Reason::kOnlyOne;
  };

  /// `camera`: the images' (footprints); `keyframes`: the odometry's keyframe rule.
  FrameSkipRule(const CameraIntrinsics& camera, const KeyframeOptions& keyframes);

  /// After each frame the odometry processed, in order.
  void observe(const ProcessedFrame& frame);
  /// A new session or camera: no prediction until two frames of it were matched.
  void reset();

  /// The frame to process next among `waiting` (oldest first, stamps increasing; not empty).
  Choice choose(const std::vector<WaitingFrame>& waiting) const;

  /// With frames prepared on arrival by other threads (the odometry nodelet's ~prepare_threads):
  /// `choice` (choose()'s) unless its preparation has not started (!prepared[choice.index]) while
  /// that of an earlier waiting frame has; then the newest such frame that the keyframe rule would
  /// not take (safe, as the frames before `choice` are: a tracked frame of the same keyframe, so no
  /// keyframe changes). Its pose comes out sooner than the choice's, whose preparation would only
  /// start now, and the other thread's work is used instead of repeated beside it on a second core.
  Choice preferPrepared(const std::vector<WaitingFrame>& waiting, Choice choice,
                        const std::vector<bool>& prepared) const;

  /// choose(), then preferPrepared() with `prepared` when it is given (not empty: one flag per waiting frame).
  Choice choose(const std::vector<WaitingFrame>& waiting, const std::vector<bool>& prepared) const;

  /// Whether the last two frames processed give a prediction (a velocity).
  bool predicting() const { return last_ && before_; }

  /// Whether a frame at `stamp_s` and `altitude_m` would be taken by the keyframe rule, as
  /// predicted; nullopt without a prediction.
  std::optional<bool> keyframeDue(double stamp_s, double altitude_m) const;

 private:
  CameraIntrinsics camera_;
  KeyframeOptions keyframes_;
  std::optional<ProcessedFrame> last_, before_;  // the last two matched frames of the session, newest first
};

/// What waitForNext knows of the input and the worker (wall clock, s; 0: unknown).
struct InputTiming {
  double now_s = 0.0;
  double chosen_arrival_s = 0.0;  // when the choice arrived
  double last_arrival_s = 0.0;    // when the newest frame arrived
  double period_s = 0.0;          // the recent interval between arrivals
  double jitter_s = 0.0;          // the recent mean deviation of those intervals from period_s
  double stamp_period_s = 0.0;    // the recent interval between the frames' stamps
  double cost_s = 0.0;            // the recent processing time of a frame
};

/// The worker's wait for the next frame (see above): the time (s, as timing's) until which to wait
/// rather than start the choice now, which waited longer than stale_fraction of a period while the
/// next frame is due sooner. Then (the expected arrival plus a jitter margin, 1/8 to 1/2 period)
/// the worker gives up and chooses again. nullopt: start the choice now.
/// Only for a choice that is the newest waiting frame and safe (chosen with a prediction, no
/// keyframe due at it), while the worker is behind on average (cost above the period: a worker
/// that keeps up processes a frame late after one slow frame rather than skip it), frames arrive
/// regularly (the intervals' mean deviation at most half a period: frames released in bursts, e.g.
/// paired with a slower altimeter, give no next arrival to wait for) and the next one is not
/// overdue. `stale_fraction`: of the input period (>= 1: never).
std::optional<double> waitForNext(const FrameSkipRule& rule, const std::vector<WaitingFrame>& waiting,
                                  const FrameSkipRule::Choice& choice, const InputTiming& timing,
                                  double stale_fraction);

/// The span of stamps after a frame in which the frames that arrive while it is processed lie, all
/// but the newest of them (core::OdometryInput::keyframe_lookahead_s): (ceil(cost / period) - 1)
/// stamp periods; 0 when the odometry keeps up (cost <= period) or a value is unknown (<= 0).
double keyframeLookaheadS(double cost_s, double period_s, double stamp_period_s);
/// The same from a FrameBudget's timing().
inline double keyframeLookaheadS(const InputTiming& t) {
  return keyframeLookaheadS(t.cost_s, t.period_s, t.stamp_period_s);
}

/// The recent cost of a frame against the recent input period, as exponential moving averages
/// over about `window` frames (ROS-free; the caller gives the times). Thread-safe: the frames'
/// arrivals, their processing and the diagnostics are on different threads.
class FrameBudget {
 public:
  explicit FrameBudget(int window = 20) : alpha_(2.0 / (window + 1.0)) {}
  /// A frame arrived (wall time, s): the input period is the interval between arrivals; with its
  /// stamp (s), also the interval between stamps (a bag replayed faster than recorded differs).
  void arrived(double now_s, double stamp_s = std::numeric_limits<double>::quiet_NaN());
  /// A frame was processed in `ms`.
  void processed(double ms);
  /// Mean of the recent processing times, ms (0 before any).
  double msPerFrame() const {
    MutexLock lock(&mutex_);
    return ms_;
  }
  /// Mean of the recent input intervals, ms (0 before two arrivals).
  double inputPeriodMs() const {
    MutexLock lock(&mutex_);
    return period_ms_;
  }
  /// What waitForNext and keyframeLookaheadS need, read together (chosen_arrival_s is left 0):
  /// `now_s`, the newest arrival (0 before any), the arrivals' period and mean deviation from it (0
  /// before two), the stamps' period (0 before two) and the recent cost of a frame, in s.
  InputTiming timing(double now_s) const;
  /// msPerFrame / inputPeriodMs: above 1 the input outruns the odometry (0 while unknown).
  double load() const {
    MutexLock lock(&mutex_);
    return ms_ > 0 && period_ms_ > 0 ? ms_ / period_ms_ : 0.0;
  }
  /// A frame arrived within `within_s` of `now_s` (the input is running).
  bool arriving(double now_s, double within_s) const {
    MutexLock lock(&mutex_);
    return last_arrival_s_ && now_s - *last_arrival_s_ <= within_s;
  }

 private:
  const double alpha_;
  mutable Mutex mutex_;
  double ms_ GUARDED_BY(mutex_) = 0.0;
  double period_ms_ GUARDED_BY(mutex_) = 0.0;
  double jitter_ms_ GUARDED_BY(mutex_) = 0.0;
  bool any_ms_ GUARDED_BY(mutex_) = false;
  std::optional<double> last_arrival_s_ GUARDED_BY(mutex_);
  int intervals_ GUARDED_BY(mutex_) = 0;
  std::optional<double> last_stamp_s_ GUARDED_BY(mutex_);
  double stamp_period_s_ GUARDED_BY(mutex_) = 0.0;
  int stamp_intervals_ GUARDED_BY(mutex_) = 0;
};

}  // namespace core
}  // namespace uw_multislam
