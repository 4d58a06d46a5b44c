// SE(2) poses and the compounding / inversion operators of Smith, Self & Cheeseman,
// as used throughout paper 000 (§4, equations (1)-(2)).
//
// Conventions (doc/dataset_format.md): x along the image columns, y along the rows, yaw turns
// x towards y; all angles in radians and normalised to (-pi, pi].
#pragma once

#include <Eigen/Core>

#include <iosfwd>

namespace uw_multislam {
namespace core {

/// Wraps an angle to (-pi, pi]. NaN and infinities give NaN (they are never silently "fixed").
double normalizeAngle(double angle);

/// A 2-D pose or relative motion (x, y, yaw). The yaw is kept normalised to (-pi, pi] by
/// every constructor and operator of this file.
class Pose2 {
 public:
  Pose2() = default;
  Pose2(double x, double y, double yaw);
  /// From a vector (x, y, yaw); the yaw is normalised.
  static Pose2 fromVector(const Eigen::Vector3d& v);
  static Pose2 identity() { return Pose2(); }

  double x() const { return x_; }
  double y() const { return y_; }
  double yaw() const { return yaw_; }
  Eigen::Vector2d translation() const { return Eigen::Vector2d(x_, y_); }
  Eigen::Vector3d vector() const { return Eigen::Vector3d(x_, y_, yaw_); }
  /// The 2x2 rotation matrix R(yaw).
  Eigen::Matrix2d rotation() const;
  /// The 3x3 homogeneous matrix [R t; 0 0 1].
  Eigen::Matrix3d matrix() const;

  /// True when every component is finite.
  bool isFinite() const;

 private:
  double x_ = 0.0;
  double y_ = 0.0;
  double yaw_ = 0.0;
};

/// Compounding a ⊕ b: the pose b, expressed in frame a, taken to a's parent frame.
Pose2 compose(const Pose2& a, const Pose2& b);
/// Inversion ⊖a: the parent frame seen from a, so that a ⊕ ⊖a = ⊖a ⊕ a = 0.
Pose2 invert(const Pose2& a);
/// The motion from a to b: ⊖a ⊕ b.
Pose2 between(const Pose2& a, const Pose2& b);
/// The point p (expressed in frame a) in a's parent frame: R(a) p + t(a).
Eigen::Vector2d transformPoint(const Pose2& a, const Eigen::Vector2d& p);

inline Pose2 operator+(const Pose2& a, const Pose2& b) { return compose(a, b); }
inline Pose2 operator-(const Pose2& a) { return invert(a); }

/// Jacobian of a ⊕ b with respect to a (Smith-Self-Cheeseman J1⊕).
Eigen::Matrix3d composeJacobianFirst(const Pose2& a, const Pose2& b);
/// Jacobian of a ⊕ b with respect to b (J2⊕).
Eigen::Matrix3d composeJacobianSecond(const Pose2& a, const Pose2& b);
/// Jacobian of ⊖a with respect to a (J⊖).
Eigen::Matrix3d invertJacobian(const Pose2& a);
/// Jacobian of transformPoint(a, p) with respect to a (2x3) and to p (2x2).
Eigen::Matrix<double, 2, 3> transformPointJacobianPose(const Pose2& a, const Eigen::Vector2d& p);
Eigen::Matrix2d transformPointJacobianPoint(const Pose2& a);

/// Difference of two poses component-wise with the yaw difference wrapped: used for errors.
Eigen::Vector3d poseError(const Pose2& estimate, const Pose2& reference);

/// Exact comparison within tolerances (translation in metres, yaw in radians, yaw wrapped).
bool approxEqual(const Pose2& a, const Pose2& b, double tol_xy = 1e-9, double tol_yaw = 1e-9);

std::ostream& operator<<(std::ostream& os, const Pose2& p);

}  // namespace core
}  // namespace uw_multislam
