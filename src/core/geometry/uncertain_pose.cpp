#include "uw_multislam/core/geometry/uncertain_pose.h"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/LU>

#include <algorithm>
#include <cmath>
#include <sstream>

namespace uw_multislam {
namespace core {

UncertainPose2 compose(const UncertainPose2& a, const UncertainPose2& b) {
  const Eigen::Matrix3d j1 = composeJacobianFirst(a.mean, b.mean);
  const Eigen::Matrix3d j2 = composeJacobianSecond(a.mean, b.mean);
  return UncertainPose2(compose(a.mean, b.mean),
                        j1 * a.covariance * j1.transpose() + j2 * b.covariance * j2.transpose());
}

UncertainPose2 invert(const UncertainPose2& a) {
  const Eigen::Matrix3d j = invertJacobian(a.mean);
  return UncertainPose2(invert(a.mean), j * a.covariance * j.transpose());
}

std::string checkCovariance(const Eigen::Matrix3d& p) {
  if (!p.allFinite()) return "covariance has non-finite entries";
  const double scale = std::max(p.cwiseAbs().maxCoeff(), 1e-300);
  if ((p - p.transpose()).cwiseAbs().maxCoeff() > 1e-9 * scale) return "covariance is not symmetric";
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(p);
  const double min_eig = eig.eigenvalues().minCoeff();
  if (min_eig < -1e-12 * scale) {
    std::ostringstream os;
    os << "covariance is not positive semi-definite (smallest eigenvalue " << min_eig << ")";
    return os.str();
  }
  return {};
}

std::string checkUncertainPose(const UncertainPose2& u, bool invertible) {
  std::string bad = checkCovariance(u.covariance);
  if (bad.empty() && !u.mean.isFinite()) bad = "mean not finite";
  // Every pose these functions see is a relative motion between two keyframes (odometry, a loop,
  // a link, a map's motion): one beyond kMaxRelativeTranslationM is a damaged row or message, and
  // its square (1e300 m in a stored loop had been written to the maps' outputs) overflows the
  // solvers' residuals.
  if (bad.empty() &&
      (std::abs(u.mean.x()) > kMaxRelativeTranslationM || std::abs(u.mean.y()) > kMaxRelativeTranslationM))
    bad = "mean farther than 1e7 m (not a motion between keyframes)";
  // The inverse itself must be finite: 1e-110 * I passes the Cholesky test, its inverse overflows
  // (the pose graph's edge weight came out inf and the solver failed).
  if (bad.empty() && invertible &&
      (Eigen::LLT<Eigen::Matrix3d>(u.covariance).info() != Eigen::Success || !u.covariance.inverse().allFinite()))
    bad = "covariance is singular (no information matrix: some uncertainty in x, y and yaw is needed)";
  return bad;
}

}  // namespace core
}  // namespace uw_multislam
