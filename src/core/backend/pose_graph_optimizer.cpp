#include "uw_multislam/core/backend/pose_graph_optimizer.h"

#include <algorithm>

namespace uw_multislam {
namespace core {

namespace {

// A copy of the map's pose graph at its current estimate, solved from that start each time.
class PoseGraphProblem : public MapProblem {
 public:
  PoseGraphProblem(std::vector<Pose2> start, std::vector<PoseGraphEdge> chain, std::vector<PositionPrior> priors,
                   const SparseOptions& options)
      : start_(std::move(start)),
        poses_(start_),
        chain_(std::move(chain)),
        priors_(std::move(priors)),
        options_(options) {}

  void solve(const std::vector<MapLoop>& loops) override {
    std::vector<PoseGraphEdge> edges = chain_;
    for (const MapLoop& l : loops) edges.push_back({l.i, l.j, l.z, true});
    poses_ = start_;
    optimisePoseGraph(&poses_, edges, options_, 0, priors_);
  }
  void reset() override { poses_ = start_; }
  Pose2 relative(int i, int j) const override { return between(poses_[i], poses_[j]); }
  bool apply(MapEstimate* estimate) const override {
    for (int k = 0; k < estimate->numMotions(); ++k) estimate->setMotion(k, between(poses_[k], poses_[k + 1]));
    return false;
  }

 private:
  const std::vector<Pose2> start_;
  std::vector<Pose2> poses_;
  const std::vector<PoseGraphEdge> chain_;  // odometry and links
  const std::vector<PositionPrior> priors_;
  const SparseOptions options_;
};

}  // namespace

PoseGraphOptimizer::PoseGraphOptimizer(const SparseOptions& options, double gate_inflation)
    : options_(options), gate_inflation_(gate_inflation) {}

void PoseGraphOptimizer::addMotion(MapEstimate* estimate, const UncertainPose2& motion, std::string*) const {
  estimate->append(motion);
}

MapEstimate PoseGraphOptimizer::join(const MapEstimate& first, const UncertainPose2& link, const MapEstimate& second,
                                     std::string*) const {
  return MapEstimate::concatenate(first, link, second);
}

UncertainPose2 PoseGraphOptimizer::gateChain(const MapEstimate& m, int a, int b,
                                             const std::vector<bool>& nav_placed) const {
  // A link that only the nav placed keeps its own covariance in the gate, not times the inflation:
  // the drift model's covariance is honest already (inflated, checked against a Monte-Carlo), and a
  // placement of sigma 0.8 m inflated 100 times would let a wrong loop 25 m off through and move the
  // placed piece by all of it.
  UncertainPose2 chain = UncertainPose2::exact(Pose2());
  for (int k = std::min(a, b); k < std::max(a, b); ++k)
    chain =
        compose(chain, UncertainPose2(m.motion(k), nav_placed[k] ? m.motionCov(k) / gate_inflation_ : m.motionCov(k)));
  if (a > b) chain = invert(chain);  // the pose of b in a
  return UncertainPose2(chain.mean, gate_inflation_ * chain.covariance);
}

std::unique_ptr<MapProblem> PoseGraphOptimizer::prepare(const MapEstimate& estimate, const MapGraph& graph,
                                                        std::vector<MapLoop>* loops) const {
  *loops = graph.loops;
  if (loops->empty() && graph.priors.empty()) return nullptr;
  std::vector<Pose2> poses{Pose2()};
  for (int k = 0; k < estimate.numMotions(); ++k) poses.push_back(compose(poses.back(), estimate.motion(k)));
  return std::make_unique<PoseGraphProblem>(std::move(poses), graph.chain, graph.priors, options_);
}

}  // namespace core
}  // namespace uw_multislam
