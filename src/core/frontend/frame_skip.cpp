#include "uw_multislam/core/frontend/frame_skip.h"

#include <algorithm>
#include <cmath>
#include <utility>
#include <vector>

#include "uw_multislam/core/frontend/features.h"

namespace uw_multislam {
namespace core {

namespace {

double signedArea(const std::vector<Eigen::Vector2d>& poly) {
  double a = 0.0;
  for (std::size_t i = 0, n = poly.size(); i < n; ++i) {
    const Eigen::Vector2d& p = poly[i];
    const Eigen::Vector2d& q = poly[(i + 1) % n];
    a += p.x() * q.y() - q.x() * p.y();
  }
  return 0.5 * a;
}

double cross(const Eigen::Vector2d& u, const Eigen::Vector2d& v) { return u.x() * v.y() - u.y() * v.x(); }

// The area shared by two convex polygons: `subject` clipped by each edge of `clip` in turn
// (Sutherland-Hodgman), in double. cv::intersectConvexConvex (OpenCV 4.6, float points) is wrong
// when two edges are nearly collinear, as footprints moved along an image axis are: with a rotation
// of 1e-6 rad it gave the whole footprint (overlap 1.0) for a shift that leaves 0.44, and 0.48 for
// one that leaves 0.72 (the keyframe rule then skipped a keyframe, or took one too early).
double convexIntersectionArea(std::vector<Eigen::Vector2d> subject, std::vector<Eigen::Vector2d> clip) {
  if (signedArea(clip) < 0) std::reverse(clip.begin(), clip.end());  // inside: left of each edge
  for (std::size_t i = 0; i < clip.size() && !subject.empty(); ++i) {
    const Eigen::Vector2d& a = clip[i];
    const Eigen::Vector2d edge = clip[(i + 1) % clip.size()] - a;
    std::vector<Eigen::Vector2d> out;
    for (std::size_t j = 0, n = subject.size(); j < n; ++j) {
      const Eigen::Vector2d& s = subject[j];
      const Eigen::Vector2d& e = subject[(j + 1) % n];
      const double ds = cross(edge, s - a), de = cross(edge, e - a);
      if ((ds >= 0) != (de >= 0)) out.push_back(s + (ds / (ds - de)) * (e - s));  // crosses the edge's line
      if (de >= 0) out.push_back(e);
    }
    subject = std::move(out);
  }
  return subject.size() < 3 ? 0.0 : std::abs(signedArea(subject));
}

}  // namespace

double footprintOverlap(const CameraIntrinsics& camera, const Pose2& motion, double kf_altitude_m, double altitude_m) {
  auto corners = [&](double alt, const Pose2& to_kf) {
    std::vector<Eigen::Vector2d> poly;
    for (const cv::Point2f px : {cv::Point2f(0, 0), cv::Point2f(camera.width, 0),
                                 cv::Point2f(camera.width, camera.height), cv::Point2f(0, camera.height)})
      poly.push_back(transformPoint(to_kf, pixelToMetres(px, camera, alt)));
    return poly;
  };
  const std::vector<Eigen::Vector2d> kf = corners(kf_altitude_m, Pose2()), cur = corners(altitude_m, motion);
  const double cur_area = std::abs(signedArea(cur));
  return cur_area > 0 ? std::min(1.0, convexIntersectionArea(cur, kf) / cur_area) : 0.0;
}

ProcessedFrame processedFrame(const OdometryUpdate& update, double stamp_s, double altitude_m, bool session_started,
                              const Odometry* odometry) {
  ProcessedFrame p;
  p.stamp_s = stamp_s;
  p.first = session_started;
  const bool measured = update.status == FrameStatus::kFirstKeyframe || update.status == FrameStatus::kTracked ||
                        update.status == FrameStatus::kKeyframe;
  // A motion carried by the nav means vision failed: no velocity to trust for a skip.
  p.matched = odometry && measured && update.source != MotionSource::kNav && !odometry->keyframes().empty();
  if (!p.matched) return p;
  p.pose = update.pose;
  p.altitude_m = std::isfinite(altitude_m) && altitude_m > 0 ? altitude_m : odometry->keyframes().back().altitude_m;
  p.keyframe_pose = odometry->trajectory().absolutePoses().back();
  p.keyframe_altitude_m = odometry->keyframes().back().altitude_m;
  p.keyframe_stamp_s = odometry->keyframes().back().stamp_s;
  return p;
}

FrameSkipRule::FrameSkipRule(const CameraIntrinsics& camera, const KeyframeOptions& keyframes)
    : camera_(camera), keyframes_(keyframes) {}

void FrameSkipRule::observe(const ProcessedFrame& frame) {
  if (!frame.matched) {
    reset();
    return;
  }
  if (frame.first) reset();
  before_ = last_;
  last_ = frame;
}

void FrameSkipRule::reset() {
  last_.reset();
  before_.reset();
}

std::optional<bool> FrameSkipRule::keyframeDue(double stamp_s, double altitude_m) const {
  if (!last_ || !before_) return std::nullopt;
  const double dt = last_->stamp_s - before_->stamp_s;
  if (!(dt > 0) || !std::isfinite(stamp_s)) return std::nullopt;
  // Constant velocity from the last two frames: the step between them, scaled to the stamp.
  const Pose2 predicted =
      extrapolate(last_->pose, between(before_->pose, last_->pose), (stamp_s - last_->stamp_s) / dt);
  const Pose2 motion = between(last_->keyframe_pose, predicted);
  const double alt = std::isfinite(altitude_m) && altitude_m > 0 ? altitude_m : last_->altitude_m;
  return keyframes_.takes(footprintOverlap(camera_, motion, last_->keyframe_altitude_m, alt), motion.yaw(),
                          stamp_s - last_->keyframe_stamp_s);
}

FrameSkipRule::Choice FrameSkipRule::choose(const std::vector<WaitingFrame>& waiting) const {
  if (waiting.size() <= 1) return {0, Reason::kOnlyOne};
  const auto due = [&](std::size_t i) { return keyframeDue(waiting[i].stamp_s, waiting[i].altitude_m); };
  const std::optional<bool> newest = due(waiting.size() - 1);
  if (!newest) return {0, Reason::kOldest};
  if (!*newest) return {waiting.size() - 1, Reason::kNewestSafe};
  for (std::size_t i = 0; i + 1 < waiting.size(); ++i)
    if (due(i).value_or(true)) return {i, Reason::kKeyframeDue};
  return {waiting.size() - 1, Reason::kKeyframeDue};
}

FrameSkipRule::Choice FrameSkipRule::choose(const std::vector<WaitingFrame>& waiting,
                                            const std::vector<bool>& prepared) const {
  const Choice choice = choose(waiting);
  return prepared.empty() ? choice : preferPrepared(waiting, choice, prepared);
}

FrameSkipRule::Choice FrameSkipRule::preferPrepared(const std::vector<WaitingFrame>& waiting, Choice choice,
                                                    const std::vector<bool>& prepared) const {
  if (choice.index >= waiting.size() || prepared.size() != waiting.size() || prepared[choice.index]) return choice;
  for (std::size_t i = choice.index; i-- > 0;)
    if (prepared[i] && keyframeDue(waiting[i].stamp_s, waiting[i].altitude_m) == std::optional<bool>(false))
      return {i, Reason::kPrepared};
  return choice;
}

void FrameBudget::arrived(double now_s, double stamp_s) {
  MutexLock lock(&mutex_);
  if (last_arrival_s_ && now_s > *last_arrival_s_) {
    const double ms = (now_s - *last_arrival_s_) * 1e3;
    if (intervals_ > 0) jitter_ms_ += alpha_ * (std::abs(ms - period_ms_) - jitter_ms_);
    period_ms_ = intervals_++ == 0 ? ms : period_ms_ + alpha_ * (ms - period_ms_);
  }
  last_arrival_s_ = now_s;
  if (!std::isfinite(stamp_s)) return;
  if (last_stamp_s_ && stamp_s > *last_stamp_s_) {
    const double d = stamp_s - *last_stamp_s_;
    stamp_period_s_ = stamp_intervals_++ == 0 ? d : stamp_period_s_ + alpha_ * (d - stamp_period_s_);
  }
  last_stamp_s_ = stamp_s;
}

InputTiming FrameBudget::timing(double now_s) const {
  MutexLock lock(&mutex_);
  InputTiming t;
  t.now_s = now_s;
  t.last_arrival_s = last_arrival_s_.value_or(0.0);
  t.period_s = period_ms_ / 1e3;
  t.jitter_s = jitter_ms_ / 1e3;
  t.stamp_period_s = stamp_period_s_;
  t.cost_s = ms_ / 1e3;
  return t;
}

std::optional<double> waitForNext(const FrameSkipRule& rule, const std::vector<WaitingFrame>& waiting,
                                  const FrameSkipRule::Choice& choice, const InputTiming& t, double stale_fraction) {
  using R = FrameSkipRule::Reason;
  if (waiting.empty() || choice.index + 1 != waiting.size()) return std::nullopt;
  if (choice.reason != R::kNewestSafe && choice.reason != R::kOnlyOne) return std::nullopt;
  const WaitingFrame& newest = waiting.back();
  // Safe and predicted (kOnlyOne says neither): a keyframe due at it, or no prediction, is taken now.
  if (rule.keyframeDue(newest.stamp_s, newest.altitude_m) != std::optional<bool>(false)) return std::nullopt;
  if (!(stale_fraction < 1.0) || !(t.period_s > 0) || !(t.last_arrival_s > 0)) return std::nullopt;
  if (!(t.cost_s > t.period_s) || !(t.jitter_s <= 0.5 * t.period_s)) return std::nullopt;  // keeping up, or irregular
  const double next = t.last_arrival_s + t.period_s;  // the next frame's expected arrival
  // The margin for the arrivals' jitter: four mean deviations, within [1/8, 1/2] period. Overdue
  // beyond it (the input stopped or slowed: the last frame of a run) or a clock step: no wait.
  const double until = next + std::clamp(4.0 * t.jitter_s, 0.125 * t.period_s, 0.5 * t.period_s);
  if (until <= t.now_s || next - t.now_s > t.period_s) return std::nullopt;
  if (t.now_s - t.chosen_arrival_s <= stale_fraction * t.period_s) return std::nullopt;
  return until;
}

double keyframeLookaheadS(double cost_s, double period_s, double stamp_period_s) {
  if (!(cost_s > period_s) || !(period_s > 0) || !(stamp_period_s > 0) || !std::isfinite(cost_s)) return 0.0;
  return (std::ceil(cost_s / period_s) - 1.0) * stamp_period_s;
}

void FrameBudget::processed(double ms) {
  MutexLock lock(&mutex_);
  ms_ = any_ms_ ? ms_ + alpha_ * (ms - ms_) : ms;
  any_ms_ = true;
}

}  // namespace core
}  // namespace uw_multislam
