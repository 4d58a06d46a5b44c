#include "uw_multislam/core/geometry/se2.h"

#include <cmath>
#include <limits>
#include <ostream>

namespace uw_multislam {
namespace core {

double normalizeAngle(double angle) {
  if (!std::isfinite(angle)) return std::numeric_limits<double>::quiet_NaN();
  // std::remainder is exact and returns a value in [-pi, pi]; -pi is folded onto +pi so the
  // range is the half-open (-pi, pi] and every heading has exactly one representation.
  double r = std::remainder(angle, 2.0 * M_PI);
  if (r <= -M_PI) r += 2.0 * M_PI;
  return r;
}

Pose2::Pose2(double x, double y, double yaw) : x_(x), y_(y), yaw_(normalizeAngle(yaw)) {}

Pose2 Pose2::fromVector(const Eigen::Vector3d& v) { return Pose2(v.x(), v.y(), v.z()); }

Eigen::Matrix2d Pose2::rotation() const {
  const double c = std::cos(yaw_), s = std::sin(yaw_);
  Eigen::Matrix2d r;
  r << c, -s, s, c;
  return r;
}

Eigen::Matrix3d Pose2::matrix() const {
  Eigen::Matrix3d m = Eigen::Matrix3d::Identity();
  m.topLeftCorner<2, 2>() = rotation();
  m(0, 2) = x_;
  m(1, 2) = y_;
  return m;
}

bool Pose2::isFinite() const { return std::isfinite(x_) && std::isfinite(y_) && std::isfinite(yaw_); }

Pose2 compose(const Pose2& a, const Pose2& b) {
  const double c = std::cos(a.yaw()), s = std::sin(a.yaw());
  return Pose2(a.x() + c * b.x() - s * b.y(), a.y() + s * b.x() + c * b.y(), a.yaw() + b.yaw());
}

Pose2 invert(const Pose2& a) {
  const double c = std::cos(a.yaw()), s = std::sin(a.yaw());
  return Pose2(-c * a.x() - s * a.y(), s * a.x() - c * a.y(), -a.yaw());
}

Pose2 between(const Pose2& a, const Pose2& b) { return compose(invert(a), b); }

Eigen::Vector2d transformPoint(const Pose2& a, const Eigen::Vector2d& p) { return a.rotation() * p + a.translation(); }

Eigen::Matrix3d composeJacobianFirst(const Pose2& a, const Pose2& b) {
  const double c = std::cos(a.yaw()), s = std::sin(a.yaw());
  Eigen::Matrix3d j = Eigen::Matrix3d::Identity();
  j(0, 2) = -s * b.x() - c * b.y();
  j(1, 2) = c * b.x() - s * b.y();
  return j;
}

Eigen::Matrix3d composeJacobianSecond(const Pose2& a, const Pose2& /*b*/) {
  Eigen::Matrix3d j = Eigen::Matrix3d::Identity();
  j.topLeftCorner<2, 2>() = a.rotation();
  return j;
}

Eigen::Matrix3d invertJacobian(const Pose2& a) {
  const double c = std::cos(a.yaw()), s = std::sin(a.yaw());
  Eigen::Matrix3d j;
  j << -c, -s, a.x() * s - a.y() * c,  //
      s, -c, a.x() * c + a.y() * s,    //
      0.0, 0.0, -1.0;
  return j;
}

Eigen::Matrix<double, 2, 3> transformPointJacobianPose(const Pose2& a, const Eigen::Vector2d& p) {
  const double c = std::cos(a.yaw()), s = std::sin(a.yaw());
  Eigen::Matrix<double, 2, 3> j;
  j << 1.0, 0.0, -s * p.x() - c * p.y(),  //
      0.0, 1.0, c * p.x() - s * p.y();
  return j;
}

Eigen::Matrix2d transformPointJacobianPoint(const Pose2& a) { return a.rotation(); }

Eigen::Vector3d poseError(const Pose2& estimate, const Pose2& reference) {
  return Eigen::Vector3d(estimate.x() - reference.x(), estimate.y() - reference.y(),
                         normalizeAngle(estimate.yaw() - reference.yaw()));
}

bool approxEqual(const Pose2& a, const Pose2& b, double tol_xy, double tol_yaw) {
  const Eigen::Vector3d e = poseError(a, b);
  return std::abs(e.x()) <= tol_xy && std::abs(e.y()) <= tol_xy && std::abs(e.z()) <= tol_yaw;
}

std::ostream& operator<<(std::ostream& os, const Pose2& p) {
  return os << "(" << p.x() << ", " << p.y() << ", " << p.yaw() << ")";
}

}  // namespace core
}  // namespace uw_multislam
