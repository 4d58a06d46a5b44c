// The paper's optimiser of a map (§8, (10)-(20); map_optimizer.h): its estimate in the joint form,
// a TrajectoryIekf (iekf.h) with the dense 3N x 3N covariance P, built by (10)(11) and updated with
// each loop once. A map larger than max_keyframes (P would be too large) is handed to a sparse
// optimiser for good: its estimate takes the marginal form (P's diagonal blocks) and that optimiser
// answers for it from then on (logged).
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "uw_multislam/core/backend/iekf.h"
#include "uw_multislam/core/backend/map_optimizer.h"
#include "uw_multislam/core/backend/pose_graph_optimizer.h"

namespace uw_multislam {
namespace core {

class IekfOptimizer : public MapOptimizer {
 public:
  /// `max_keyframes`: the largest map kept in the joint form (BackendOptions::max_keyframes);
  /// `gate_inflation`: the joint covariance's factor in the entry gate (iekf_gate_inflation);
  /// `larger`: the optimiser of larger maps. Throws std::invalid_argument on bad options.
  IekfOptimizer(const IekfOptions& options, int max_keyframes, double gate_inflation, PoseGraphOptimizer larger);

  const char* name() const override { return "iekf"; }
  MapEstimate start() const override;
  /// Joint, with a block-diagonal P (the cross-covariances are unknown), when the map fits.
  MapEstimate adopt(MapEstimate marginal) const override;
  void addMotion(MapEstimate* estimate, const UncertainPose2& motion, std::string* note) const override;
  /// Joint when both are and the joined map fits: P block-diagonal in the two maps and the link (34).
  MapEstimate join(const MapEstimate& first, const UncertainPose2& link, const MapEstimate& second,
                   std::string* note) const override;
  /// The filter's own X_b^a under its joint covariance P (TrajectoryIekf::relative), which knows
  /// what earlier loops pinned down, times the inflation.
  UncertainPose2 gateChain(const MapEstimate& estimate, int a, int b,
                           const std::vector<bool>& nav_placed) const override;
  /// The loops not applied yet, as measurements of a copy of the filter.
  std::unique_ptr<MapProblem> prepare(const MapEstimate& estimate, const MapGraph& graph,
                                      std::vector<MapLoop>* loops) const override;

 private:
  IekfOptions options_;
  int max_keyframes_;
  double gate_inflation_;
  PoseGraphOptimizer larger_;
};

}  // namespace core
}  // namespace uw_multislam
