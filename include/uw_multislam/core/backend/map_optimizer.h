// The optimiser of one map, behind one interface (cf. cartographer's OptimizationProblemInterface,
// fuse's Optimizer given a Graph). The multi-session back-end (backend.h) owns the graph (sessions,
// odometry, links, loops, joins and splits) and is given a MapOptimizer at construction; the
// optimiser owns what is its own: the form each map's estimate takes (map_estimate.h), how a motion
// is appended to it, how two maps' estimates are joined, what a new loop is gated against, and the
// map's optimisation problem. Two implement it:
//  - IekfOptimizer (iekf_optimizer.h): the paper's intra-map IEKF (§8, (10)-(20));
//  - PoseGraphOptimizer (pose_graph_optimizer.h): the sparse pose graph solved with Ceres.
//
// A problem is taken out of the back-end (a copy), solved without the back-end's lock, and applied
// only if the map did not change meanwhile (the back-end's revisions): solve() and relative() read
// and write nothing but the problem. The residual gate around the solve (which loops are switched
// off, which refused ones are taken back) is the back-end's, the same for every optimiser: it asks
// the problem to solve with a set of loops and reads each loop's prediction in the solution.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "uw_multislam/core/backend/map_estimate.h"
#include "uw_multislam/core/backend/pose_graph.h"
#include "uw_multislam/core/geometry/uncertain_pose.h"

namespace uw_multislam {
namespace core {

/// A loop inside one map as an optimiser takes it: ẑ ~ X_j^i between the map's keyframes i and j
/// (indices along its chain), and the back-end's id of the loop.
struct MapLoop {
  int id = -1;
  int i = 0;
  int j = 0;
  UncertainPose2 z;
};

/// What an optimiser is given of one map.
struct MapGraph {
  /// Per motion of the chain, in order, its measurement: the odometry's X_k^{k-1} within a session, a
  /// link's between two (an edge from keyframe k - 1 to k, not robust).
  std::vector<PoseGraphEdge> chain;
  /// The loops inside the map that no link summarises and that are not refused, in id order.
  std::vector<MapLoop> loops;
  /// Per loop: whether an earlier problem's apply() put it in the estimate for good.
  std::vector<bool> applied;
  /// Absolute position priors on the map's keyframes (chain indices) in the map's frame
  /// (position_prior.h), solved with every problem's loops (also with none).
  std::vector<PositionPrior> priors;
  /// Per prior: whether an earlier problem's apply() put it in the estimate for good (an optimiser
  /// whose apply() returns true solves only the others, as it does with the loops).
  std::vector<bool> priors_applied;
};

/// One map's optimisation problem, a copy of what it needs.
class MapProblem {
 public:
  virtual ~MapProblem() = default;
  /// Solves from the estimate the problem was taken from, with `loops` and the problem's priors
  /// (`loops` may be empty when it has priors).
  virtual void solve(const std::vector<MapLoop>& loops) = 0;
  /// Back to the estimate the problem was taken from (no loop).
  virtual void reset() = 0;
  /// X_j^i in the current solution (means), for the map's keyframes i and j.
  virtual Pose2 relative(int i, int j) const = 0;
  /// Writes the current solution into `estimate`, the map's (unchanged since the problem was taken).
  /// true: the loops and priors of the last solve are in the estimate for good and are given to no
  /// later problem (an IEKF update applies each once); false: every later problem gets them again.
  virtual bool apply(MapEstimate* estimate) const = 0;
};

class MapOptimizer {
 public:
  virtual ~MapOptimizer() = default;
  /// BackendOptions::optimizer's word for it ("iekf", "sparse").
  virtual const char* name() const = 0;
  /// A new map's estimate: one keyframe, no motion.
  virtual MapEstimate start() const = 0;
  /// A map's estimate from its motions' marginals (a restored map), in the form this optimiser keeps.
  virtual MapEstimate adopt(MapEstimate marginal) const = 0;
  /// Appends the odometry motion X_k^{k-1} (10)(11). When the estimate changes its form, *note
  /// says why (the back-end logs it); otherwise *note is left as it is.
  virtual void addMotion(MapEstimate* estimate, const UncertainPose2& motion, std::string* note) const = 0;
  /// The estimate of two maps joined (34): first's motions, the link, second's; *note as addMotion's.
  virtual MapEstimate join(const MapEstimate& first, const UncertainPose2& link, const MapEstimate& second,
                           std::string* note) const = 0;
  /// The estimate's X_b^a between its keyframes a and b with the covariance a new loop inside the map
  /// is gated against (BackendOptions::intra_loop_gate): the chain's, inflated as this optimiser
  /// needs. `nav_placed`, per motion: a link that only the nav placed (no visual match).
  virtual UncertainPose2 gateChain(const MapEstimate& estimate, int a, int b,
                                   const std::vector<bool>& nav_placed) const = 0;
  /// The map's problem, or null when it has no loop and no prior to solve; *loops: the graph's
  /// loops it solves, in order (the priors are solved with them, also with none).
  virtual std::unique_ptr<MapProblem> prepare(const MapEstimate& estimate, const MapGraph& graph,
                                              std::vector<MapLoop>* loops) const = 0;
};

}  // namespace core
}  // namespace uw_multislam
