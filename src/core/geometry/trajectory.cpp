#include "uw_multislam/core/geometry/trajectory.h"

#include <algorithm>
#include <stdexcept>
#include <string>

namespace uw_multislam {
namespace core {

Trajectory::Trajectory() : absolute_{Pose2::identity()} {}

void Trajectory::append(const UncertainPose2& motion) {
  motions_.push_back(motion);
  absolute_.push_back(compose(absolute_.back(), motion.mean));
}

void Trajectory::setMotion(std::size_t k, const UncertainPose2& motion) {
  checkMotion(k);
  motions_[k - 1] = motion;
  for (std::size_t i = k; i < absolute_.size(); ++i) {
    absolute_[i] = compose(absolute_[i - 1], motions_[i - 1].mean);
  }
}

const UncertainPose2& Trajectory::motion(std::size_t k) const {
  checkMotion(k);
  return motions_[k - 1];
}

Eigen::VectorXd Trajectory::stateVector() const {
  Eigen::VectorXd x(3 * motions_.size());
  for (std::size_t k = 0; k < motions_.size(); ++k) x.segment<3>(3 * k) = motions_[k].mean.vector();
  return x;
}

Eigen::MatrixXd Trajectory::stateCovariance() const {
  const auto n = static_cast<Eigen::Index>(motions_.size());
  Eigen::MatrixXd p = Eigen::MatrixXd::Zero(3 * n, 3 * n);
  for (Eigen::Index k = 0; k < n; ++k) p.block<3, 3>(3 * k, 3 * k) = motions_[k].covariance;
  return p;
}

const Pose2& Trajectory::absolutePose(std::size_t k) const {
  checkKeyframe(k);
  return absolute_[k];
}

std::vector<Pose2> Trajectory::prefixes(std::size_t lo, std::size_t hi) const {
  std::vector<Pose2> p;
  p.reserve(hi - lo + 1);
  p.push_back(Pose2::identity());
  for (std::size_t k = lo + 1; k <= hi; ++k) p.push_back(compose(p.back(), motions_[k - 1].mean));
  return p;
}

Eigen::MatrixXd Trajectory::relativeJacobian(std::size_t i, std::size_t j) const {
  checkKeyframe(i);
  checkKeyframe(j);
  const std::size_t lo = std::min(i, j), hi = std::max(i, j);
  const std::vector<Pose2> p = prefixes(lo, hi);
  const Pose2& total = p.back();
  const auto n = static_cast<Eigen::Index>(hi - lo);
  Eigen::MatrixXd jac(3, 3 * n);
  // total = P_{b} ⊕ m_b ⊕ S_b, so d total / d m_b = J1⊕(P_{b+1}, S_b) · J2⊕(P_b, m_b), where
  // J1⊕(A, B) only needs the translation of total relative to A: column 3 = (-(ty - Ay), tx - Ax).
  for (Eigen::Index b = 0; b < n; ++b) {
    const Pose2& before = p[static_cast<std::size_t>(b)];
    const Pose2& after = p[static_cast<std::size_t>(b) + 1];
    Eigen::Matrix3d j1 = Eigen::Matrix3d::Identity();
    j1(0, 2) = -(total.y() - after.y());
    j1(1, 2) = total.x() - after.x();
    Eigen::Matrix3d j2 = Eigen::Matrix3d::Identity();
    j2.topLeftCorner<2, 2>() = before.rotation();
    jac.block<3, 3>(0, 3 * b) = j1 * j2;
  }
  if (j < i) jac = invertJacobian(total) * jac;  // X_j^i = ⊖X_i^j
  return jac;
}

UncertainPose2 Trajectory::relative(std::size_t i, std::size_t j) const {
  checkKeyframe(i);
  checkKeyframe(j);
  const std::size_t lo = std::min(i, j), hi = std::max(i, j);
  const Pose2 chain = prefixes(lo, hi).back();
  const Eigen::MatrixXd jac = relativeJacobian(i, j);
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (std::size_t k = lo + 1; k <= hi; ++k) {
    const auto b = static_cast<Eigen::Index>(3 * (k - lo - 1));
    const Eigen::Matrix3d jb = jac.block<3, 3>(0, b);
    cov += jb * motions_[k - 1].covariance * jb.transpose();
  }
  return UncertainPose2(j >= i ? chain : invert(chain), cov);
}

void Trajectory::checkKeyframe(std::size_t k) const {
  if (k >= absolute_.size()) {
    throw std::out_of_range("keyframe " + std::to_string(k) + " is past the end of a trajectory of " +
                            std::to_string(absolute_.size()) + " keyframes");
  }
}

void Trajectory::checkMotion(std::size_t k) const {
  if (k == 0 || k > motions_.size()) {
    throw std::out_of_range("motion " + std::to_string(k) + " does not exist: motions are numbered 1.." +
                            std::to_string(motions_.size()));
  }
}

}  // namespace core
}  // namespace uw_multislam
