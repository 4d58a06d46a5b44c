// The sigmas of a dead-reckoned nav that does not give usable ones (core/frontend/nav_prior.h reads
// the motion's uncertainty from the GROWTH of the nav's sigma between two stamps).
//
// NavDriftModel: sigma grows with the distance travelled, sigma_xy = xy_per_m x distance and
// sigma_yaw = yaw_per_m x distance (a DVL/INS drifts by about 1 % of the distance). The live
// odometry's tf nav input uses it (tf has no covariance), and so does its topic input when the
// topic's covariance is unusable.
//
// NavCovarianceCheck: whether a nav topic's covariance is usable, per component (x-y and yaw). A
// dead reckoning's sigma grows along the trajectory; a constant one (a driver that fills a fixed
// matrix) or a zero one gives relative motions of zero uncertainty, which the nav prior floors to
// 5 mm / 5 mrad: a confident prior it has no grounds for. So:
//   - a component's own sigma is used once it has grown above its first reading's;
//   - until then the drift model's is used; once the vehicle has travelled kDecideAfterM without
//     growth the component is NOT GROWING (ZERO when it stayed 0) and the drift model is kept,
//     each such reading counted (the live node WARNs);
//   - the check restarts with the track (a new clock).
// Tested in test/core/frontend/test_nav_drift.cpp.
#pragma once

#include <Eigen/Core>

#include <optional>
#include <string>

#include "uw_multislam/core/frontend/nav_prior.h"

namespace uw_multislam {
namespace core {

class NavDriftModel {
 public:
  NavDriftModel(double xy_per_m, double yaw_per_m) : xy_per_m_(xy_per_m), yaw_per_m_(yaw_per_m) {}
  /// The vehicle is at `position`: the distance grows by the step from the last one.
  void advance(const Eigen::Vector2d& position);
  void reset();
  double distance() const { return distance_m_; }
  double sigmaXy() const { return xy_per_m_ * distance_m_; }
  double sigmaYaw() const { return yaw_per_m_ * distance_m_; }

 private:
  double xy_per_m_, yaw_per_m_;
  std::optional<Eigen::Vector2d> last_;
  double distance_m_ = 0.0;
};

class NavCovarianceCheck {
 public:
  /// Travelled this far without growth, a component's covariance is decided unusable.
  static constexpr double kDecideAfterM = 2.0;
  enum class Verdict { kUndecided, kGrowing, kNotGrowing, kZero };
  struct Result {
    NavRecord row;  // the reading with the sigmas to use
    Verdict xy = Verdict::kUndecided, yaw = Verdict::kUndecided;
    bool replaced = false;  // a decided-unusable component's sigma was replaced by the drift model's
    bool decided = false;   // this reading decided a component unusable (log it once)
  };

  NavCovarianceCheck(double xy_per_m, double yaw_per_m) : drift_(xy_per_m, yaw_per_m) {}
  /// The next reading of the track (in order).
  Result add(const NavRecord& reading);
  /// The track restarted.
  void reset();
  double distance() const { return drift_.distance(); }

 private:
  struct Component {
    std::optional<double> first;
    bool grown = false;
    Verdict last = Verdict::kUndecided;
    Verdict verdict(double sigma, double distance) const;
  };
  NavDriftModel drift_;
  Component xy_, yaw_;
};

std::string verdictName(NavCovarianceCheck::Verdict v);

}  // namespace core
}  // namespace uw_multislam
