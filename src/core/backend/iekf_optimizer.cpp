#include "uw_multislam/core/backend/iekf_optimizer.h"

#include <optional>
#include <stdexcept>

namespace uw_multislam {
namespace core {

namespace {

// X_j^i from the motions of a chain (motion k reaches keyframe k + 1), means only.
Pose2 relativeOfMotions(const std::vector<Pose2>& motions, int i, int j) {
  Pose2 x;
  for (int k = std::min(i, j); k < std::max(i, j); ++k) x = compose(x, motions[k]);
  return i <= j ? x : invert(x);
}

// A copy of the map's filter; each solve updates a copy of it with the loops as measurements.
class IekfProblem : public MapProblem {
 public:
  IekfProblem(TrajectoryIekf start, std::vector<PositionPrior> priors)
      : start_(std::move(start)), priors_(std::move(priors)) {}

  void solve(const std::vector<MapLoop>& loops) override {
    std::vector<LoopMeasurement> z;
    for (const MapLoop& l : loops) z.push_back({l.i, l.j, l.z});
    filter_ = start_;
    filter_->update(z, priors_);
  }
  void reset() override { filter_ = start_; }
  Pose2 relative(int i, int j) const override { return relativeOfMotions(current().motions(), i, j); }
  bool apply(MapEstimate* estimate) const override {
    if (!estimate->filter()) throw std::logic_error("iekf: a filter's solution applied to a map without one");
    *estimate = MapEstimate(current());
    return true;
  }

 private:
  const TrajectoryIekf& current() const { return filter_ ? *filter_ : start_; }
  const TrajectoryIekf start_;
  const std::vector<PositionPrior> priors_;
  std::optional<TrajectoryIekf> filter_;  // the solution (made in solve(): the copy is O(N^2))
};

}  // namespace

IekfOptimizer::IekfOptimizer(const IekfOptions& options, int max_keyframes, double gate_inflation,
                             PoseGraphOptimizer larger)
    : options_(options), max_keyframes_(max_keyframes), gate_inflation_(gate_inflation), larger_(std::move(larger)) {
  if (const std::string bad = options.validate(); !bad.empty()) throw std::invalid_argument("iekf: " + bad);
  if (max_keyframes < 2) throw std::invalid_argument("iekf: max_keyframes must be >= 2");
}

MapEstimate IekfOptimizer::start() const { return MapEstimate(TrajectoryIekf(options_)); }

MapEstimate IekfOptimizer::adopt(MapEstimate m) const {
  if (m.filter() || m.numMotions() + 1 > max_keyframes_) return m;
  const int n = m.numMotions();
  Eigen::MatrixXd p = Eigen::MatrixXd::Zero(3 * n, 3 * n);
  std::vector<Pose2> motions;
  for (int k = 0; k < n; ++k) {
    p.block<3, 3>(3 * k, 3 * k) = m.motionCov(k);
    motions.push_back(m.motion(k));
  }
  return MapEstimate(TrajectoryIekf(options_, std::move(motions), std::move(p)));
}

void IekfOptimizer::addMotion(MapEstimate* estimate, const UncertainPose2& motion, std::string* note) const {
  if (estimate->filter() && estimate->numMotions() + 2 > max_keyframes_) {
    *estimate = estimate->marginal();
    *note = "more than backend.max_keyframes = " + std::to_string(max_keyframes_) +
            " keyframes: optimised by the sparse back-end from now on";
  }
  estimate->append(motion);
}

MapEstimate IekfOptimizer::join(const MapEstimate& first, const UncertainPose2& link, const MapEstimate& second,
                                std::string* note) const {
  const TrajectoryIekf* p = first.filter();
  const TrajectoryIekf* c = second.filter();
  if (p && c && first.numMotions() + 1 + second.numMotions() + 1 <= max_keyframes_) {
    std::vector<Pose2> motions = p->motions();
    motions.push_back(link.mean);
    motions.insert(motions.end(), c->motions().begin(), c->motions().end());
    const Eigen::Index np = p->covariance().rows(), nc = c->covariance().rows();
    Eigen::MatrixXd cov = Eigen::MatrixXd::Zero(np + 3 + nc, np + 3 + nc);
    cov.topLeftCorner(np, np) = p->covariance();
    cov.block<3, 3>(np, np) = link.covariance;
    cov.bottomRightCorner(nc, nc) = c->covariance();
    return MapEstimate(TrajectoryIekf(options_, std::move(motions), std::move(cov)));
  }
  if (p || c)
    *note = "joined map exceeds backend.max_keyframes = " + std::to_string(max_keyframes_) +
            ": optimised by the sparse back-end from now on";
  return larger_.join(first, link, second, note);
}

UncertainPose2 IekfOptimizer::gateChain(const MapEstimate& estimate, int a, int b,
                                        const std::vector<bool>& nav_placed) const {
  // The marginal chain would ignore the motions' correlations and let wrong loops through
  // (bench_backend --outliers --optimizer iekf, doc/benchmarks/outliers.md).
  if (!estimate.filter()) return larger_.gateChain(estimate, a, b, nav_placed);
  const UncertainPose2 chain = estimate.filter()->relative(a, b);
  return UncertainPose2(chain.mean, gate_inflation_ * chain.covariance);
}

std::unique_ptr<MapProblem> IekfOptimizer::prepare(const MapEstimate& estimate, const MapGraph& graph,
                                                   std::vector<MapLoop>* loops) const {
  if (!estimate.filter()) return larger_.prepare(estimate, graph, loops);
  loops->clear();
  for (std::size_t k = 0; k < graph.loops.size(); ++k)
    if (!graph.applied[k]) loops->push_back(graph.loops[k]);
  std::vector<PositionPrior> priors;  // an update applies each once, as the loops
  for (std::size_t k = 0; k < graph.priors.size(); ++k)
    if (k >= graph.priors_applied.size() || !graph.priors_applied[k]) priors.push_back(graph.priors[k]);
  if (loops->empty() && priors.empty()) return nullptr;
  return std::make_unique<IekfProblem>(*estimate.filter(), std::move(priors));
}

}  // namespace core
}  // namespace uw_multislam
