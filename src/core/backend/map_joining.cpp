#include "uw_multislam/core/backend/map_joining.h"

#include <Eigen/Dense>

#include <cmath>
#include <stdexcept>

namespace uw_multislam {
namespace core {

namespace {

Pose2 predict(const JoinLoop& l, const Pose2& link) { return compose(compose(l.pe_from_pi, link), l.ci_from_cs); }

}  // namespace

// d g / d link = J1⊕(X_pe^pi ⊕ L, X_ci^cs) · J2⊕(X_pe^pi, L), i.e. (25) as derived.
Eigen::Matrix3d joinLinkJacobian(const JoinLoop& l, const Pose2& link) {
  const Pose2 a = compose(l.pe_from_pi, link);
  return composeJacobianFirst(a, l.ci_from_cs) * composeJacobianSecond(l.pe_from_pi, link);
}

JoinResult estimateJoinLink(const std::vector<JoinLoop>& loops, const IekfOptions& options) {
  if (loops.empty()) throw std::invalid_argument("map joining: no global loop");
  const std::string bad_options = options.validate();
  if (!bad_options.empty()) throw std::invalid_argument("map joining: " + bad_options);
  for (const auto& l : loops) {
    const std::string bad = checkCovariance(l.z.covariance);
    if (!bad.empty()) throw std::invalid_argument("map joining: loop covariance: " + bad);
  }
  const auto m = static_cast<Eigen::Index>(3 * loops.size());
  Eigen::MatrixXd r = Eigen::MatrixXd::Zero(m, m);  // (22)
  for (std::size_t k = 0; k < loops.size(); ++k) r.block<3, 3>(3 * k, 3 * k) = loops[k].z.covariance;

  // (32): the closed form from the first loop.
  const JoinLoop& first = loops.front();
  const Pose2 prior = compose(compose(invert(first.pe_from_pi), first.z.mean), invert(first.ci_from_cs));
  // Uninformative prior on the link: (1 km)^2 and pi^2.
  const Eigen::Matrix3d p0 = Eigen::Vector3d(1e6, 1e6, M_PI * M_PI).asDiagonal();

  JoinResult res;
  Pose2 x = prior;
  Eigen::MatrixXd g(m, 3), k_gain;
  Eigen::VectorXd nu(m);
  auto linearise = [&](const Pose2& at) {
    for (std::size_t k = 0; k < loops.size(); ++k) {
      nu.segment<3>(3 * k) = poseError(loops[k].z.mean, predict(loops[k], at));
      g.block<3, 3>(3 * k, 0) = joinLinkJacobian(loops[k], at);
    }
  };
  for (int it = 0; it < options.max_iterations; ++it) {
    linearise(x);
    const Eigen::MatrixXd s = g * p0 * g.transpose() + r;
    k_gain = p0 * g.transpose() * s.ldlt().solve(Eigen::MatrixXd::Identity(m, m));
    const Eigen::Vector3d dx = poseError(prior, x);
    const Eigen::Vector3d next = x.vector() + dx + k_gain * (nu - g * dx);
    const Pose2 nx = Pose2::fromVector(next);
    const double step = poseError(nx, x).cwiseAbs().maxCoeff();
    x = nx;
    res.iterations = it + 1;
    if (step < options.tolerance) break;
  }
  linearise(x);
  // (30) in information form, (P0⁻¹ + Gᵀ R⁻¹ G)⁻¹: the same matrix, without the cancellation of
  // (I − K G) P0 against the large uninformative P0.
  const Eigen::Matrix3d info = p0.inverse() + g.transpose() * r.ldlt().solve(g);
  Eigen::Matrix3d p = info.inverse();
  p = 0.5 * (p + p.transpose());
  double sq = 0.0;
  for (std::size_t k = 0; k < loops.size(); ++k) sq += nu.segment<2>(3 * k).squaredNorm();
  res.rms_residual_m = std::sqrt(sq / loops.size());
  res.link = UncertainPose2(x, p);
  return res;
}

Trajectory joinTrajectories(const Trajectory& previous, const UncertainPose2& link, const Trajectory& current) {
  Trajectory t = previous;  // (33)(34): motions concatenated, covariance block-diagonal
  t.append(link);
  for (std::size_t k = 1; k <= current.numMotions(); ++k) t.append(current.motion(k));
  return t;
}

}  // namespace core
}  // namespace uw_multislam
