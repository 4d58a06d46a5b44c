#include "uw_multislam/core/backend/loop_consistency.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <boost/math/distributions/chi_squared.hpp>
#include <cmath>
#include <limits>
#include <numeric>
#include <stdexcept>
#include <string>

namespace uw_multislam {
namespace core {

std::string ConsistencyOptions::validate() const {
  if (!(confidence > 0.5 && confidence < 1.0)) return "confidence must be in (0.5, 1)";
  if (!(min_sigma_m >= 0.0 && std::isfinite(min_sigma_m))) return "min_sigma_m must be >= 0";
  if (!(min_sigma_rad >= 0.0 && std::isfinite(min_sigma_rad))) return "min_sigma_rad must be >= 0";
  if (max_loops < 2 || max_loops > 2000) return "max_loops must be in [2, 2000]";
  return {};
}

UncertainPose2 loopCycle(const CrossLoop& a, const CrossLoop& b, const Trajectory& previous,
                         const Trajectory& current) {
  const UncertainPose2 along_current =
      current.relative(static_cast<std::size_t>(a.current_index), static_cast<std::size_t>(b.current_index));
  const UncertainPose2 back_in_previous =
      previous.relative(static_cast<std::size_t>(b.previous_index), static_cast<std::size_t>(a.previous_index));
  return compose(compose(compose(a.z, along_current), invert(b.z)), back_in_previous);
}

double cycleDistance2(const CrossLoop& a, const CrossLoop& b, const Trajectory& previous, const Trajectory& current,
                      const ConsistencyOptions& options) {
  const UncertainPose2 e = loopCycle(a, b, previous, current);
  return mahalanobis2(e.mean, e.covariance, options);
}

double mahalanobis2(const Pose2& error, const Eigen::Matrix3d& covariance, const ConsistencyOptions& options) {
  const Eigen::Vector3d r(error.x(), error.y(), normalizeAngle(error.yaw()));
  Eigen::Matrix3d p = covariance;
  p(0, 0) += options.min_sigma_m * options.min_sigma_m;
  p(1, 1) += options.min_sigma_m * options.min_sigma_m;
  p(2, 2) += options.min_sigma_rad * options.min_sigma_rad;
  const Eigen::LDLT<Eigen::Matrix3d> ldlt(p);
  if (ldlt.info() != Eigen::Success || !(ldlt.vectorD().array() > 0).all())
    return r.isZero() ? 0.0 : std::numeric_limits<double>::infinity();  // exact: only the identity agrees
  return r.dot(ldlt.solve(r));
}

double chiSquare3Quantile(double confidence) {
  return boost::math::quantile(boost::math::chi_squared_distribution<double>(3.0), confidence);
}

namespace {
// Bron-Kerbosch with pivoting (Tomita et al.), keeping the best clique seen: largest, then
// heaviest. The candidate graphs are small (<= max_loops vertices) and dense when loops are
// good, where pivoting keeps the recursion short.
struct CliqueSearch {
  const std::vector<std::vector<bool>>& adj;
  const std::vector<int>& w;
  std::vector<int> best;
  long best_weight = -1;

  long weight(const std::vector<int>& c) const {
    long s = 0;
    for (int v : c) s += w.empty() ? 1 : w[static_cast<std::size_t>(v)];
    return s;
  }
  void run(std::vector<int>& r, std::vector<int> p, std::vector<int> x) {
    if (r.size() + p.size() < best.size()) return;  // cannot beat the best size any more
    if (p.empty() && x.empty()) {
      const long wr = weight(r);
      if (r.size() > best.size() || (r.size() == best.size() && wr > best_weight)) {
        best = r;
        best_weight = wr;
      }
      return;
    }
    // The pivot: the vertex of P u X with the most neighbours in P.
    int pivot = -1;
    std::size_t most = 0;
    for (const std::vector<int>* set : {&p, &x})
      for (int u : *set) {
        std::size_t n = 0;
        for (int v : p) n += adj[u][v];
        if (pivot < 0 || n > most) pivot = u, most = n;
      }
    std::vector<int> todo;
    for (int v : p)
      if (!adj[pivot][v]) todo.push_back(v);
    for (int v : todo) {
      std::vector<int> np, nx;
      for (int u : p)
        if (adj[v][u]) np.push_back(u);
      for (int u : x)
        if (adj[v][u]) nx.push_back(u);
      r.push_back(v);
      run(r, np, nx);
      r.pop_back();
      p.erase(std::find(p.begin(), p.end(), v));
      x.push_back(v);
    }
  }
};
}  // namespace

std::vector<int> maximumClique(const std::vector<std::vector<bool>>& adjacent, const std::vector<int>& weights) {
  const int n = static_cast<int>(adjacent.size());
  if (!weights.empty() && static_cast<int>(weights.size()) != n)
    throw std::invalid_argument("maximumClique: one weight per vertex");
  CliqueSearch s{adjacent, weights, {}, -1};
  std::vector<int> r, p(static_cast<std::size_t>(n)), x;
  std::iota(p.begin(), p.end(), 0);
  s.run(r, p, x);
  std::sort(s.best.begin(), s.best.end());
  return s.best;
}

ConsistentSet largestConsistentSet(const std::vector<CrossLoop>& loops, const Trajectory& previous,
                                   const Trajectory& current, const ConsistencyOptions& options) {
  for (const CrossLoop& l : loops)
    if (l.previous_index < 0 || static_cast<std::size_t>(l.previous_index) >= previous.numKeyframes() ||
        l.current_index < 0 || static_cast<std::size_t>(l.current_index) >= current.numKeyframes())
      throw std::out_of_range("largestConsistentSet: a loop's keyframe is not in its map");
  // The candidates: all, or the max_loops with the most inliers.
  std::vector<int> order(loops.size());
  std::iota(order.begin(), order.end(), 0);
  if (static_cast<int>(order.size()) > options.max_loops) {
    std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return loops[a].inliers > loops[b].inliers; });
    order.resize(static_cast<std::size_t>(options.max_loops));
    std::sort(order.begin(), order.end());
  }
  const std::size_t n = order.size();
  const double gate = chiSquare3Quantile(options.confidence);
  std::vector<std::vector<bool>> adj(n, std::vector<bool>(n, false));
  std::vector<int> weights(n);
  ConsistentSet out;
  for (std::size_t i = 0; i < n; ++i) {
    weights[i] = loops[order[i]].inliers;
    for (std::size_t j = i + 1; j < n; ++j) {
      ++out.pairs;
      const bool ok = cycleDistance2(loops[order[i]], loops[order[j]], previous, current, options) <= gate;
      adj[i][j] = adj[j][i] = ok;
      out.consistent_pairs += ok;
    }
  }
  for (int k : maximumClique(adj, weights)) out.loops.push_back(order[static_cast<std::size_t>(k)]);
  std::sort(out.loops.begin(), out.loops.end());
  // The spread in each map; the smaller counts (loops from one keyframe to several are one place).
  const std::vector<Pose2>&ap = previous.absolutePoses(), &ac = current.absolutePoses();
  double sp = 0.0, sc = 0.0;
  for (int a : out.loops) {
    out.inliers += loops[a].inliers;
    for (int b : out.loops) {
      sp = std::max(sp, (ap[loops[a].previous_index].translation() - ap[loops[b].previous_index].translation()).norm());
      sc = std::max(sc, (ac[loops[a].current_index].translation() - ac[loops[b].current_index].translation()).norm());
    }
  }
  out.spread_m = std::min(sp, sc);
  out.spread_previous_m = sp;
  out.spread_current_m = sc;
  return out;
}

}  // namespace core
}  // namespace uw_multislam
