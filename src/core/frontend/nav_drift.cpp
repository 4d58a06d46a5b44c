#include "uw_multislam/core/frontend/nav_drift.h"

namespace uw_multislam {
namespace core {

void NavDriftModel::advance(const Eigen::Vector2d& position) {
  if (last_) distance_m_ += (position - *last_).norm();
  last_ = position;
}

void NavDriftModel::reset() {
  last_.reset();
  distance_m_ = 0.0;
}

NavCovarianceCheck::Verdict NavCovarianceCheck::Component::verdict(double sigma, double distance) const {
  if (grown) return Verdict::kGrowing;
  if (distance < kDecideAfterM) return Verdict::kUndecided;
  return sigma == 0.0 && first && *first == 0.0 ? Verdict::kZero : Verdict::kNotGrowing;
}

NavCovarianceCheck::Result NavCovarianceCheck::add(const NavRecord& reading) {
  drift_.advance(reading.pose.translation());
  Result r;
  r.row = reading;
  const double distance = drift_.distance();
  const auto check = [&](Component* c, double sigma, double drift_sigma, double* out) {
    if (!c->first) c->first = sigma;
    if (sigma > *c->first) c->grown = true;
    const Verdict v = c->verdict(sigma, distance);
    if (v != Verdict::kGrowing) *out = drift_sigma;  // not (yet) usable: the drift model's
    const bool unusable = v == Verdict::kNotGrowing || v == Verdict::kZero;
    r.replaced = r.replaced || unusable;
    r.decided = r.decided || (unusable && c->last == Verdict::kUndecided);
    c->last = v;
    return v;
  };
  r.xy = check(&xy_, reading.sigma_xy_m, drift_.sigmaXy(), &r.row.sigma_xy_m);
  r.yaw = check(&yaw_, reading.sigma_yaw_rad, drift_.sigmaYaw(), &r.row.sigma_yaw_rad);
  return r;
}

void NavCovarianceCheck::reset() {
  drift_.reset();
  xy_ = Component();
  yaw_ = Component();
}

std::string verdictName(NavCovarianceCheck::Verdict v) {
  switch (v) {
    case NavCovarianceCheck::Verdict::kUndecided:
      return "undecided";
    case NavCovarianceCheck::Verdict::kGrowing:
      return "growing";
    case NavCovarianceCheck::Verdict::kNotGrowing:
      return "not growing";
    case NavCovarianceCheck::Verdict::kZero:
      return "zero";
  }
  return "?";
}

}  // namespace core
}  // namespace uw_multislam
