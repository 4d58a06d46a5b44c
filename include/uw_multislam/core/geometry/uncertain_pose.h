// Gaussian poses N(mean, P) and their first-order propagation through ⊕ and ⊖
// (Smith, Self & Cheeseman; paper 000 §4: X_B^A = N(X̂_B^A, P_B^A)).
#pragma once

#include <Eigen/Core>

#include <string>

#include "uw_multislam/core/geometry/se2.h"

namespace uw_multislam {
namespace core {

struct UncertainPose2 {
  Pose2 mean;
  /// Covariance of (x, y, yaw), in m² / m·rad / rad².
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();

  UncertainPose2() = default;
  UncertainPose2(const Pose2& m, const Eigen::Matrix3d& p) : mean(m), covariance(p) {}

  /// An exactly known pose (zero covariance).
  static UncertainPose2 exact(const Pose2& m) { return UncertainPose2(m, Eigen::Matrix3d::Zero()); }
};

/// a ⊕ b for independent a and b: P = J1 Pa J1ᵀ + J2 Pb J2ᵀ.
UncertainPose2 compose(const UncertainPose2& a, const UncertainPose2& b);
/// ⊖a: P = J⊖ Pa J⊖ᵀ.
UncertainPose2 invert(const UncertainPose2& a);

/// Checks that a covariance is usable: finite, symmetric (relative tolerance) and positive
/// semi-definite. Returns an empty string when it is, else a sentence saying what is wrong.
std::string checkCovariance(const Eigen::Matrix3d& p);

/// Farthest relative motion (metres, in x or y) checkUncertainPose accepts: 10 000 km, beyond any
/// survey, well inside what a squared residual can hold.
constexpr double kMaxRelativeTranslationM = 1e7;

/// Checks that a pose with covariance is usable: checkCovariance, then a finite mean within
/// kMaxRelativeTranslationM; with
/// `invertible`, a covariance without an inverse (a measurement that needs an information matrix)
/// is refused too. Returns an empty string when it is usable, else a sentence saying what is wrong.
std::string checkUncertainPose(const UncertainPose2& u, bool invertible = false);

}  // namespace core
}  // namespace uw_multislam
