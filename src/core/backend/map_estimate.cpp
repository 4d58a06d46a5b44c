#include "uw_multislam/core/backend/map_estimate.h"

#include <stdexcept>
#include <string>

#include "uw_multislam/core/geometry/trajectory.h"

namespace uw_multislam {
namespace core {

MapEstimate::MapEstimate(std::vector<Pose2> motions, std::vector<Eigen::Matrix3d> covariances)
    : motions_(std::move(motions)), cov_(std::move(covariances)) {
  if (motions_.size() != cov_.size())
    throw std::invalid_argument("map estimate: " + std::to_string(motions_.size()) + " motions, " +
                                std::to_string(cov_.size()) + " covariances");
}

MapEstimate::MapEstimate(TrajectoryIekf filter) : filter_(std::move(filter)) {}

int MapEstimate::numMotions() const { return static_cast<int>(filter_ ? filter_->motions().size() : motions_.size()); }

Pose2 MapEstimate::motion(int k) const { return filter_ ? filter_->motions()[k] : motions_[k]; }

Eigen::Matrix3d MapEstimate::motionCov(int k) const {
  return filter_ ? Eigen::Matrix3d(filter_->covariance().block<3, 3>(3 * k, 3 * k)) : cov_[k];
}

void MapEstimate::append(const UncertainPose2& motion) {
  if (filter_) {
    filter_->addMotion(motion);
    return;
  }
  motions_.push_back(motion.mean);
  cov_.push_back(motion.covariance);
}

void MapEstimate::setMotion(int k, const Pose2& mean) {
  if (filter_) throw std::logic_error("map estimate: setMotion on the joint form");
  motions_[k] = mean;
}

MapEstimate MapEstimate::marginal() const {
  if (!filter_) return *this;
  MapEstimate m;
  m.motions_ = filter_->motions();
  for (int k = 0; k < numMotions(); ++k) m.cov_.push_back(motionCov(k));
  return m;
}

MapEstimate MapEstimate::concatenate(const MapEstimate& first, const UncertainPose2& link, const MapEstimate& second) {
  MapEstimate j;
  for (int k = 0; k < first.numMotions(); ++k) j.append(UncertainPose2(first.motion(k), first.motionCov(k)));
  j.append(link);
  for (int k = 0; k < second.numMotions(); ++k) j.append(UncertainPose2(second.motion(k), second.motionCov(k)));
  return j;
}

MapEstimate MapEstimate::slice(const std::vector<std::pair<int, int>>& ranges, int composed) const {
  // The composed range's motions as a means-only trajectory: their composition and its Jacobian.
  std::optional<Trajectory> t;
  Eigen::MatrixXd jac;
  if (composed >= 0) {
    t.emplace();
    for (int k = ranges[composed].first; k < ranges[composed].second; ++k) t->append(UncertainPose2::exact(motion(k)));
    jac = t->relativeJacobian(0, t->numKeyframes() - 1);
  }
  MapEstimate out;
  for (std::size_t r = 0; r < ranges.size(); ++r) {
    const auto [a, b] = ranges[r];
    if (static_cast<int>(r) == composed) {
      out.motions_.push_back(t->relative(0, t->numKeyframes() - 1).mean);
      if (!filter_) {
        Eigen::MatrixXd blk = Eigen::MatrixXd::Zero(3 * (b - a), 3 * (b - a));
        for (int k = a; k < b; ++k) blk.block<3, 3>(3 * (k - a), 3 * (k - a)) = cov_[k];
        out.cov_.push_back(jac * blk * jac.transpose());
      }
      continue;
    }
    for (int k = a; k < b; ++k) {
      out.motions_.push_back(motion(k));
      if (!filter_) out.cov_.push_back(cov_[k]);
    }
  }
  if (!filter_) return out;
  // Joint: the kept blocks of P, and for the composed motion J P Jᵀ with its cross terms J P.
  const auto p = filter_->covariance();
  Eigen::Index dim = 0;
  std::vector<std::pair<Eigen::Index, Eigen::Index>> src;  // (start, length) in the old state
  for (std::size_t r = 0; r < ranges.size(); ++r) {
    const auto [a, b] = ranges[r];
    src.emplace_back(3 * a, 3 * (b - a));
    dim += static_cast<int>(r) == composed ? 3 : 3 * (b - a);
  }
  Eigen::MatrixXd np = Eigen::MatrixXd::Zero(dim, dim);
  Eigen::Index ri = 0;
  for (std::size_t r = 0; r < ranges.size(); ++r) {
    const bool cr = static_cast<int>(r) == composed;
    const Eigen::Index rl = cr ? 3 : src[r].second;
    Eigen::Index ci = 0;
    for (std::size_t c = 0; c < ranges.size(); ++c) {
      const bool cc = static_cast<int>(c) == composed;
      const Eigen::Index cl = cc ? 3 : src[c].second;
      Eigen::MatrixXd b = p.block(src[r].first, src[c].first, src[r].second, src[c].second);
      if (cr) b = jac * b;
      if (cc) b = b * jac.transpose();
      np.block(ri, ci, rl, cl) = b;
      ci += cl;
    }
    ri += rl;
  }
  return MapEstimate(TrajectoryIekf(filter_->options(), std::move(out.motions_), 0.5 * (np + np.transpose())));
}

}  // namespace core
}  // namespace uw_multislam
