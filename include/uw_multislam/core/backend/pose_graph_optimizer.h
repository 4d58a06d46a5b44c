// The sparse optimiser of a map (map_optimizer.h): its estimate in the marginal form, re-solved as a
// whole pose graph (pose_graph.h) over the absolute poses of its keyframes, warm-started from the
// current estimate, with a robust loss on the loops. Memory O(N + loops); every loop is given to
// every solve again.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "uw_multislam/core/backend/map_optimizer.h"
#include "uw_multislam/core/backend/pose_graph.h"

namespace uw_multislam {
namespace core {

class PoseGraphOptimizer : public MapOptimizer {
 public:
  /// `gate_inflation`: the chain's covariance is multiplied by it in the entry gate
  /// (BackendOptions::intra_gate_inflation).
  PoseGraphOptimizer(const SparseOptions& options, double gate_inflation);

  const char* name() const override { return "sparse"; }
  MapEstimate start() const override { return MapEstimate(); }
  MapEstimate adopt(MapEstimate marginal) const override { return marginal; }
  void addMotion(MapEstimate* estimate, const UncertainPose2& motion, std::string* note) const override;
  MapEstimate join(const MapEstimate& first, const UncertainPose2& link, const MapEstimate& second,
                   std::string* note) const override;
  /// The motions between the two keyframes composed to first order from their marginal covariances
  /// (looser than the optimised estimate: a conservative gate), times the inflation.
  UncertainPose2 gateChain(const MapEstimate& estimate, int a, int b,
                           const std::vector<bool>& nav_placed) const override;
  std::unique_ptr<MapProblem> prepare(const MapEstimate& estimate, const MapGraph& graph,
                                      std::vector<MapLoop>* loops) const override;

 private:
  SparseOptions options_;
  double gate_inflation_;
};

}  // namespace core
}  // namespace uw_multislam
