#include "uw_multislam/core/frontend/nav_prior.h"

#include <Eigen/Cholesky>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <sstream>
#include <stdexcept>

#include "uw_multislam/core/backend/loop_consistency.h"

namespace uw_multislam {
namespace core {

std::string trackingLossPolicyName(TrackingLossPolicy p) {
  return p == TrackingLossPolicy::kNewSession ? "new_session" : "dead_reckoning";
}

bool parseTrackingLossPolicy(const std::string& name, TrackingLossPolicy* p) {
  for (const TrackingLossPolicy c : {TrackingLossPolicy::kNewSession, TrackingLossPolicy::kDeadReckoning}) {
    if (name == trackingLossPolicyName(c)) {
      *p = c;
      return true;
    }
  }
  return false;
}

const char* motionSourceName(MotionSource s) {
  switch (s) {
    case MotionSource::kVisual:
      return "visual";
    case MotionSource::kNav:
      return "nav";
    case MotionSource::kFused:
      return "fused";
    case MotionSource::kFallback:
      return "fallback";
  }
  return "visual";
}

bool parseMotionSource(const std::string& name, MotionSource* s) {
  for (const MotionSource c :
       {MotionSource::kVisual, MotionSource::kNav, MotionSource::kFused, MotionSource::kFallback}) {
    if (name == motionSourceName(c)) {
      *s = c;
      return true;
    }
  }
  return false;
}

std::string NavPriorOptions::validate() const {
  std::ostringstream os;
  // Upper bounds keep a nav motion's covariance finite and invertible (1e308 or 1e154 had ended
  // the run in the back-end).
  if (!(inflation >= 1.0 && inflation <= 1e6)) {
    os << "inflation " << inflation << " must be in [1, 1e6] (the nav is never trusted more than it claims)";
  } else if (!(min_sigma_m > 0.0 && min_sigma_m <= 1000.0) || !(min_sigma_rad > 0.0 && min_sigma_rad <= 10.0)) {
    os << "min_sigma_m must be in (0, 1000] and min_sigma_rad in (0, 10]";
  } else if (!(gate_confidence == 0.0 || (gate_confidence > 0.5 && gate_confidence < 1.0))) {
    os << "gate_confidence " << gate_confidence << " must be in (0.5, 1), or 0 for no gate";
  } else if (min_features_to_restart < 1) {
    os << "min_features_to_restart must be >= 1";
  } else if (!(max_speed_m_s > 0.0 && std::isfinite(max_speed_m_s))) {
    os << "max_speed_m_s " << max_speed_m_s << " must be positive";
  } else if (!(max_yaw_rate_rad_s > 0.0 && std::isfinite(max_yaw_rate_rad_s))) {
    os << "max_yaw_rate_rad_s " << max_yaw_rate_rad_s << " must be positive";
  }
  return os.str();
}

std::string NavTrack::invalid(const NavRecord& r) {
  if (!std::isfinite(r.stamp_s) || !r.pose.isFinite() || !(r.sigma_xy_m >= 0) || !(r.sigma_yaw_rad >= 0) ||
      !std::isfinite(r.sigma_xy_m) || !std::isfinite(r.sigma_yaw_rad))
    return "a value is not finite or a sigma is negative";
  return "";
}

NavTrack::NavTrack(std::vector<NavRecord> rows) : rows_(std::move(rows)) {
  for (std::size_t i = 0; i < rows_.size(); ++i) {
    const std::string bad = invalid(rows_[i]);
    if (!bad.empty()) throw std::invalid_argument("nav row " + std::to_string(i) + ": " + bad);
    if (i > 0 && !(rows_[i].stamp_s > rows_[i - 1].stamp_s))
      throw std::invalid_argument("nav row " + std::to_string(i) + ": stamps must increase strictly");
  }
}

bool NavTrack::append(const NavRecord& row, std::string* why, double restart_after_s) {
  std::string bad = invalid(row);
  if (bad.empty() && restart_after_s > 0 && !rows_.empty() && row.stamp_s < rows_.back().stamp_s - restart_after_s) {
    if (why)
      *why = "stamp " + std::to_string(row.stamp_s) + " jumped back from " + std::to_string(rows_.back().stamp_s) +
             ": the track starts again";
    rows_.assign(1, row);
    return true;
  }
  if (bad.empty() && !rows_.empty() && !(row.stamp_s > rows_.back().stamp_s))
    bad = "stamp " + std::to_string(row.stamp_s) + " not after the last one, " + std::to_string(rows_.back().stamp_s);
  if (bad.empty()) rows_.push_back(row);
  if (why) *why = bad;
  return bad.empty();
}

void NavTrack::dropBefore(double stamp_s) {
  const auto hi =
      std::lower_bound(rows_.begin(), rows_.end(), stamp_s, [](const NavRecord& r, double s) { return r.stamp_s < s; });
  if (hi - rows_.begin() > 1) rows_.erase(rows_.begin(), hi - 1);
}

std::size_t NavTrack::dropClockBefore(double stamp_s, double tolerance_s) {
  if (rows_.empty() || !(rows_.back().stamp_s > stamp_s + tolerance_s)) return 0;
  const std::size_t n = rows_.size();
  rows_.clear();
  return n;
}

bool NavTrack::at(double stamp_s, NavRecord* out) const {
  if (rows_.empty() || !(stamp_s >= rows_.front().stamp_s) || !(stamp_s <= rows_.back().stamp_s)) return false;
  const auto hi =
      std::lower_bound(rows_.begin(), rows_.end(), stamp_s, [](const NavRecord& r, double s) { return r.stamp_s < s; });
  if (hi->stamp_s == stamp_s) {
    *out = *hi;
    return true;
  }
  const NavRecord& b = *hi;
  const NavRecord& a = *(hi - 1);
  const double t = (stamp_s - a.stamp_s) / (b.stamp_s - a.stamp_s);
  auto lerp = [t](double u, double v) { return u + t * (v - u); };
  // Yaw on the circle: a's yaw plus t times the wrapped difference (the shorter arc).
  const double yaw = a.pose.yaw() + t * normalizeAngle(b.pose.yaw() - a.pose.yaw());
  out->stamp_s = stamp_s;
  out->pose = Pose2(lerp(a.pose.x(), b.pose.x()), lerp(a.pose.y(), b.pose.y()), yaw);
  out->sigma_xy_m = lerp(a.sigma_xy_m, b.sigma_xy_m);
  out->sigma_yaw_rad = lerp(a.sigma_yaw_rad, b.sigma_yaw_rad);
  return true;
}

UncertainPose2 navMotion(const NavRecord& a, const NavRecord& b, const NavPriorOptions& o) {
  const double sxy = std::max(o.min_sigma_m, o.inflation * std::abs(b.sigma_xy_m - a.sigma_xy_m));
  const double syaw = std::max(o.min_sigma_rad, o.inflation * std::abs(b.sigma_yaw_rad - a.sigma_yaw_rad));
  return UncertainPose2(between(a.pose, b.pose), Eigen::Vector3d(sxy * sxy, sxy * sxy, syaw * syaw).asDiagonal());
}

UncertainPose2 navPlacement(const NavRecord& a, const NavRecord& b, const NavPriorOptions& o, bool one_track) {
  if (one_track) return navMotion(a, b, o);
  // b's position error in a's frame: both positions' errors, and a's heading error turning the
  // vector between them (first order).
  const double reach = a.sigma_yaw_rad * (b.pose.translation() - a.pose.translation()).norm();
  const double sxy = std::max(o.min_sigma_m, o.inflation * std::sqrt(a.sigma_xy_m * a.sigma_xy_m +
                                                                     b.sigma_xy_m * b.sigma_xy_m + reach * reach));
  const double syaw = std::max(o.min_sigma_rad, o.inflation * std::hypot(a.sigma_yaw_rad, b.sigma_yaw_rad));
  return UncertainPose2(between(a.pose, b.pose), Eigen::Vector3d(sxy * sxy, sxy * sxy, syaw * syaw).asDiagonal());
}

double navGateDistance2(const UncertainPose2& visual, const UncertainPose2& nav) {
  ConsistencyOptions no_floor;  // the nav covariance has its own floors
  no_floor.min_sigma_m = 0.0;
  no_floor.min_sigma_rad = 0.0;
  const Pose2 error(visual.mean.x() - nav.mean.x(), visual.mean.y() - nav.mean.y(), visual.mean.yaw() - nav.mean.yaw());
  return mahalanobis2(error, visual.covariance + nav.covariance, no_floor);
}

double navGateThreshold(const NavPriorOptions& o) {
  return o.gate_confidence > 0 ? chiSquare3Quantile(o.gate_confidence) : std::numeric_limits<double>::infinity();
}

std::string navStepImplausible(const NavRecord& a, const NavRecord& b, const NavPriorOptions& o) {
  const double distance = std::hypot(b.pose.x() - a.pose.x(), b.pose.y() - a.pose.y());
  const double turn = std::abs(normalizeAngle(b.pose.yaw() - a.pose.yaw()));
  const double dt = std::abs(b.stamp_s - a.stamp_s);
  // navMotion's sigmas: the distance of two independent axes of sigma s has sigma sqrt(2) s;
  // three sigma above what the vehicle can do in dt.
  const Eigen::Matrix3d cov = navMotion(a, b, o).covariance;
  const double allowed_m = o.max_speed_m_s * dt + 3.0 * std::sqrt(2.0 * cov(0, 0));
  // The heading's own reading noise too (a compass reads 1-2 degrees apart from one reading to the
  // next whatever the nav's sigma columns say): 2 degrees per reading, two readings.
  constexpr double kHeadingNoiseRad = 2.0 * M_PI / 180.0;
  const double allowed_rad =
      o.max_yaw_rate_rad_s * dt + 3.0 * std::sqrt(cov(2, 2) + 2.0 * kHeadingNoiseRad * kHeadingNoiseRad);
  char why[240];
  if (!(std::isfinite(distance) && distance <= allowed_m)) {
    std::snprintf(why, sizeof why,
                  "nav step of %.3g m in %.3g s (more than max_speed_m_s %.3g m/s and 3 sigma): not used", distance, dt,
                  o.max_speed_m_s);
    return why;
  }
  if (!(std::isfinite(turn) && turn <= allowed_rad)) {
    std::snprintf(why, sizeof why,
                  "nav turn of %.3g rad in %.3g s (more than max_yaw_rate_rad_s %.3g rad/s and 3 sigma): not used",
                  turn, dt, o.max_yaw_rate_rad_s);
    return why;
  }
  return "";
}

UncertainPose2 fuseMotions(const UncertainPose2& visual, const UncertainPose2& nav) {
  // Kalman update of `visual` by the direct measurement `nav` (H = I), in (x, y, yaw) with the
  // yaw innovation wrapped: K = Pv (Pv + Pn)^-1, x = v + K (n - v), P = (I - K) Pv.
  const Eigen::Matrix3d s = visual.covariance + nav.covariance;
  const Eigen::Matrix3d k = s.ldlt().solve(visual.covariance.transpose()).transpose();
  const Eigen::Vector3d innovation(nav.mean.x() - visual.mean.x(), nav.mean.y() - visual.mean.y(),
                                   normalizeAngle(nav.mean.yaw() - visual.mean.yaw()));
  const Eigen::Matrix3d p = (Eigen::Matrix3d::Identity() - k) * visual.covariance;
  return UncertainPose2(Pose2::fromVector(visual.mean.vector() + k * innovation), 0.5 * (p + p.transpose()));
}

}  // namespace core
}  // namespace uw_multislam
