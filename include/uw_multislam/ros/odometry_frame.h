// The odometry nodelet's unit of work: an image paired with its camera_info and altitude, as it waits
// in the worker's queue, and the same frame prepared ahead on another thread (~prepare_threads).
#pragma once

#include <ros/time.h>
#include <sensor_msgs/CameraInfo.h>

#include <algorithm>
#include <chrono>
#include <cstddef>
#include <deque>
#include <string>
#include <vector>

#include "uw_multislam/core/common/work_queue.h"
#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/frontend/frame_skip.h"
#include "uw_multislam/core/frontend/input_pairing.h"
#include "uw_multislam/core/frontend/odometry.h"
#include "uw_multislam/core/geometry/vehicle_frame.h"
#include "uw_multislam/ros/image_input.h"
#include "uw_multislam/ros/odometry_counters.h"

namespace uw_multislam {
namespace ros_inputs {

struct OdometryFrame {
  ImageMsg msg;
  sensor_msgs::CameraInfoConstPtr info;
  core::PairedAltitude altitude = core::PairedAltitude::kFixed;
  double altitude_m = 0.0;          // kReading: the altimeter's range, else the camera's (NaN: the last valid one)
  std::string altimeter_frame;      // of the altitude readings (empty: none yet, or no altitude topic)
  std::vector<double> passed_over;  // stamps received before it and not processed: seen, no time gap
  std::size_t arrival = 0;          // its number among the frames prepared on arrival (~prepare_threads, newest)
  double arrived_s = 0.0;           // steady time it was paired and queued (its wait for the worker starts)
};

/// A frame the queue dropped when full: its stamps travel on with the frame after it, which the worker passes
/// over first, so the queue's own drops never look like a gap in the images (a new session).
inline void handOnDropped(OdometryFrame& dropped, OdometryFrame& next) {
  dropped.passed_over.push_back(dropped.msg.header().stamp.toSec());
  next.passed_over.insert(next.passed_over.begin(), dropped.passed_over.begin(), dropped.passed_over.end());
}

/// A frame the worker skipped for a newer one: its stamps travel on with the frame taken (seen, not a gap).
inline void handOnSkipped(OdometryFrame& skipped, OdometryFrame& taken) {
  taken.passed_over.insert(taken.passed_over.end(), skipped.passed_over.begin(), skipped.passed_over.end());
  taken.passed_over.push_back(skipped.msg.header().stamp.toSec());
  std::sort(taken.passed_over.begin(), taken.passed_over.end());
}

/// The frame as the skip rule sees it: its stamp, and the camera's altitude (a range reading through `mount`).
inline core::WaitingFrame waitingFrame(const OdometryFrame& f, const core::CameraMount& mount) {
  return {f.msg.header().stamp.toSec(),
          f.altitude == core::PairedAltitude::kReading ? core::cameraAltitude(f.altitude_m, mount) : f.altitude_m};
}

/// ~drop_policy newest: the frame `rule` (the session's; null before the first session: every frame, as the former
/// queue) takes among `waiting`, preferring one whose preparation is `started` (empty: none prepared on arrival);
/// with `timing` (the input's: FrameBudget::timing), whether to wait for the next frame instead (core::waitForNext with
/// `stale_fraction`: NewestChoice::wait_for); not with frames prepared on arrival (a frame under preparation would be
/// taken after the wait: the stale one, later).
inline core::NewestChoice chooseNewest(const core::FrameSkipRule* rule, const std::deque<OdometryFrame>& waiting,
                                       const core::CameraMount& mount, const std::vector<bool>& started,
                                       const core::InputTiming* timing = nullptr, double stale_fraction = 1.0) {
  if (!rule) return {0, false};
  std::vector<core::WaitingFrame> w;
  w.reserve(waiting.size());
  for (const OdometryFrame& f : waiting) w.push_back(waitingFrame(f, mount));
  const core::FrameSkipRule::Choice choice = rule->choose(w, started);
  core::NewestChoice c{choice.index, choice.reason != core::FrameSkipRule::Reason::kOldest};
  if (!timing || !started.empty()) return c;
  core::InputTiming t = *timing;
  t.chosen_arrival_s = waiting[choice.index].arrived_s;
  if (const std::optional<double> until = core::waitForNext(*rule, w, choice, t, stale_fraction))
    c.wait_for = std::chrono::duration_cast<std::chrono::steady_clock::duration>(
        std::chrono::duration<double>(std::max(0.0, *until - t.now_s)));
  return c;
}

/// The odometry worker's choice under ~drop_policy newest (chooseNewest), waiting for the next frame rather than
/// start a stale one (stale_fraction < 1), each take's wait counted once in the worker's `counters`.
class NewestChooser {
 public:
  /// `budget`: the odometry's (its arrivals give the input's timing); `counters`: the worker's.
  NewestChooser(double stale_fraction, const core::FrameBudget* budget, ros_diagnostics::OdometryCounters* counters)
      : stale_fraction_(stale_fraction), budget_(budget), counters_(counters) {}
  core::NewestChoice operator()(const core::FrameSkipRule* rule, const std::deque<OdometryFrame>& waiting,
                                const core::CameraMount& mount, const std::vector<bool>& started) {
    const core::InputTiming timing = budget_->timing(ros::SteadyTime::now().toSec());
    const core::NewestChoice c = chooseNewest(rule, waiting, mount, started, &timing, stale_fraction_);
    // A take asks again after each frame that arrives during its wait: counted at its first.
    if (c.wait_for && counted_take_ != counters_->frames_finished) {
      counted_take_ = counters_->frames_finished;
      ++counters_->waits_for_fresher;
    }
    return c;
  }

 private:
  double stale_fraction_;
  const core::FrameBudget* budget_;
  ros_diagnostics::OdometryCounters* counters_;  // frames_finished numbers the takes
  long counted_take_ = -1;
};

struct PreparedAhead {
  core::CameraIntrinsics camera;
  core::PreparedFrame prepared;  // prepared.done false: nothing usable (the worker converts again and reports)
};

}  // namespace ros_inputs
}  // namespace uw_multislam
