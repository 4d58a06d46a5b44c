#include "uw_multislam/core/backend/iekf.h"

#include <Eigen/Dense>

#include <algorithm>
#include <stdexcept>

namespace uw_multislam {
namespace core {

std::string IekfOptions::validate() const {
  if (max_iterations < 1) return "max_iterations must be >= 1";
  if (!(tolerance > 0)) return "tolerance must be positive";
  return {};
}

TrajectoryIekf::TrajectoryIekf(const IekfOptions& options) : options_(options) {
  const std::string bad = options.validate();
  if (!bad.empty()) throw std::invalid_argument("iekf: " + bad);
}

TrajectoryIekf::TrajectoryIekf(const IekfOptions& options, std::vector<Pose2> motions, Eigen::MatrixXd covariance)
    : TrajectoryIekf(options) {
  const auto n = static_cast<Eigen::Index>(3 * motions.size());
  if (covariance.rows() != n || covariance.cols() != n)
    throw std::invalid_argument("iekf: state of " + std::to_string(motions.size()) + " motions needs a " +
                                std::to_string(n) + " x " + std::to_string(n) + " covariance");
  motions_ = std::move(motions);
  storage_ = std::move(covariance);
}

void TrajectoryIekf::addMotion(const UncertainPose2& motion) {
  if (const std::string bad = checkUncertainPose(motion); !bad.empty())
    throw std::invalid_argument("iekf: motion: " + bad);
  // P grows by 3 rows and columns per motion. It lives in the top-left corner of a larger
  // buffer whose capacity doubles, so that trajectory building copies P O(log N) times instead of
  // at every keyframe (which made building 1000 keyframes take 14 s).
  const Eigen::Index n = 3 * static_cast<Eigen::Index>(motions_.size());
  if (storage_.rows() < n + 3) {
    const Eigen::Index cap = std::max<Eigen::Index>({2 * storage_.rows(), n + 3, 48});
    Eigen::MatrixXd grown(cap, cap);
    grown.topLeftCorner(n, n) = storage_.topLeftCorner(n, n);
    storage_ = std::move(grown);
  }
  storage_.block(n, 0, 3, n + 3).setZero();
  storage_.block(0, n, n, 3).setZero();
  storage_.block<3, 3>(n, n) = motion.covariance;
  motions_.push_back(motion.mean);
}

Trajectory TrajectoryIekf::meansOnly(const std::vector<Pose2>& motions) const {
  Trajectory t;
  for (const Pose2& m : motions) t.append(UncertainPose2::exact(m));
  return t;
}

Trajectory TrajectoryIekf::trajectory() const {
  Trajectory t;
  for (std::size_t k = 0; k < motions_.size(); ++k) {
    const auto b = static_cast<Eigen::Index>(3 * k);
    t.append(UncertainPose2(motions_[k], covariance().block<3, 3>(b, b)));
  }
  return t;
}

UncertainPose2 TrajectoryIekf::relative(int i, int j) const {
  const Trajectory t = meansOnly(motions_);
  const auto lo = static_cast<Eigen::Index>(std::min(i, j)), hi = static_cast<Eigen::Index>(std::max(i, j));
  const Eigen::MatrixXd jac = t.relativeJacobian(i, j);
  const Eigen::MatrixXd block = covariance().block(3 * lo, 3 * lo, 3 * (hi - lo), 3 * (hi - lo));
  return UncertainPose2(t.relative(i, j).mean, jac * block * jac.transpose());
}

IekfResult TrajectoryIekf::update(const std::vector<LoopMeasurement>& loops,
                                  const std::vector<PositionPrior>& positions) {
  IekfResult res;
  if ((loops.empty() && positions.empty()) || motions_.empty()) return res;
  const int n = static_cast<int>(motions_.size());
  for (const auto& l : loops) {
    if (l.i == l.j || l.i < 0 || l.j < 0 || l.i > n || l.j > n) {
      throw std::invalid_argument("iekf: loop " + std::to_string(l.i) + " -> " + std::to_string(l.j) +
                                  " is not between two keyframes of a trajectory of " + std::to_string(n + 1));
    }
    const std::string bad = checkCovariance(l.z.covariance);
    if (!bad.empty()) throw std::invalid_argument("iekf: loop covariance: " + bad);
  }
  for (const PositionPrior& p : positions)
    if (const std::string bad = checkPositionPrior(p, n + 1); !bad.empty()) throw std::invalid_argument("iekf: " + bad);
  // Rows: 3 per loop, then 2 per position prior.
  const Eigen::Index ml = static_cast<Eigen::Index>(3 * loops.size());
  const Eigen::Index m = ml + static_cast<Eigen::Index>(2 * positions.size());
  const Eigen::Index dim = 3 * n;
  Eigen::MatrixXd r = Eigen::MatrixXd::Zero(m, m);  // (13)
  for (std::size_t k = 0; k < loops.size(); ++k) r.block<3, 3>(3 * k, 3 * k) = loops[k].z.covariance;
  for (std::size_t k = 0; k < positions.size(); ++k) r.block<2, 2>(ml + 2 * k, ml + 2 * k) = positions[k].covariance;

  auto stack = [](const std::vector<Pose2>& v) {
    Eigen::VectorXd x(3 * v.size());
    for (std::size_t k = 0; k < v.size(); ++k) x.segment<3>(3 * k) = v[k].vector();
    return x;
  };
  auto unstack = [](const Eigen::VectorXd& x) {
    std::vector<Pose2> v;
    for (Eigen::Index k = 0; k < x.size() / 3; ++k) v.push_back(Pose2::fromVector(x.segment<3>(3 * k)));
    return v;
  };
  // Innovation ẑ − g(x) (15) with wrapped yaw, and G (16)(18).
  auto linearise = [&](const std::vector<Pose2>& x, Eigen::VectorXd* nu, Eigen::MatrixXd* g) {
    const Trajectory t = meansOnly(x);
    nu->resize(m);
    *g = Eigen::MatrixXd::Zero(m, dim);
    for (std::size_t k = 0; k < loops.size(); ++k) {
      const auto& l = loops[k];
      nu->segment<3>(3 * k) = poseError(l.z.mean, t.relative(l.i, l.j).mean);
      const int lo = std::min(l.i, l.j), hi = std::max(l.i, l.j);
      g->block(3 * k, 3 * lo, 3, 3 * (hi - lo)) = t.relativeJacobian(l.i, l.j);
    }
    for (std::size_t k = 0; k < positions.size(); ++k) {
      const PositionPrior& p = positions[k];
      const Pose2 at = t.relative(0, p.index).mean;
      nu->segment<2>(ml + 2 * k) = p.position - Eigen::Vector2d(at.x(), at.y());
      g->block(ml + 2 * k, 0, 2, 3 * p.index) = t.relativeJacobian(0, p.index).topRows(2);
    }
  };

  const Eigen::VectorXd prior = stack(motions_);
  Eigen::VectorXd x = prior;
  Eigen::MatrixXd k_gain, g;
  Eigen::VectorXd nu;
  for (int it = 0; it < options_.max_iterations; ++it) {
    linearise(unstack(x), &nu, &g);
    const Eigen::MatrixXd s = g * covariance() * g.transpose() + r;
    const Eigen::LDLT<Eigen::MatrixXd> s_ldlt(s);
    if (it == 0) res.chi2_before = nu.dot(s_ldlt.solve(nu));
    k_gain = covariance() * g.transpose() * s_ldlt.solve(Eigen::MatrixXd::Identity(m, m));
    Eigen::VectorXd dx = prior - x;
    for (Eigen::Index q = 2; q < dim; q += 3) dx[q] = normalizeAngle(dx[q]);
    Eigen::VectorXd next = prior + k_gain * (nu - g * dx);
    Eigen::VectorXd step = next - x;
    for (Eigen::Index q = 2; q < dim; q += 3) step[q] = normalizeAngle(step[q]);
    x = stack(unstack(next));  // normalise the yaws
    res.iterations = it + 1;
    res.last_step = step.lpNorm<Eigen::Infinity>();
    if (res.last_step < options_.tolerance) break;
  }
  // (20) with G at the final estimate.
  linearise(unstack(x), &nu, &g);
  auto p = state();
  const Eigen::MatrixXd s = g * p * g.transpose() + r;
  k_gain = p * g.transpose() * s.ldlt().solve(Eigen::MatrixXd::Identity(m, m));
  p -= k_gain * (g * p);                   // K (G P): O(N² m), not (K G) P: O(N³)
  p = (0.5 * (p + p.transpose())).eval();  // eval: p appears on both sides
  motions_ = unstack(x);
  res.chi2_after = nu.dot(r.ldlt().solve(nu));
  return res;
}

}  // namespace core
}  // namespace uw_multislam
