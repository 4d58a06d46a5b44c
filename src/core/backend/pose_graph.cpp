#include "uw_multislam/core/backend/pose_graph.h"

#include <ceres/ceres.h>

#include <Eigen/Dense>

#include <chrono>
#include <cmath>
#include <memory>
#include <stdexcept>

namespace uw_multislam {
namespace core {

const char* robustLossName(RobustLoss l) {
  switch (l) {
    case RobustLoss::kNone:
      return "none";
    case RobustLoss::kHuber:
      return "huber";
    case RobustLoss::kCauchy:
      return "cauchy";
  }
  return "?";
}

bool parseRobustLoss(const std::string& name, RobustLoss* out) {
  if (name == "none")
    *out = RobustLoss::kNone;
  else if (name == "huber")
    *out = RobustLoss::kHuber;
  else if (name == "cauchy")
    *out = RobustLoss::kCauchy;
  else
    return false;
  return true;
}

std::string SparseOptions::validate() const {
  if (max_iterations < 1) return "max_iterations must be >= 1";
  // Ceres stops when the cost changes by less than this fraction: 1 or more stopped before the
  // first step (the maps were left as they were, "optimised").
  if (!(function_tolerance > 0 && function_tolerance < 1)) return "function_tolerance must be in (0, 1)";
  if (!(loss_scale > 0)) return "loss_scale must be positive";
  return {};
}

namespace {

template <typename T>
T wrapAngle(const T& a) {
  using std::floor;
  const T two_pi(2.0 * M_PI);
  return a - two_pi * floor((a + T(M_PI)) / two_pi);
}

// r = W (g(X_i, X_j) − ẑ), g = ⊖X_i ⊕ X_j, yaw wrapped.
class EdgeCost {
 public:
  EdgeCost(const Pose2& z, const Eigen::Matrix3d& sqrt_info) : z_(z.vector()), w_(sqrt_info) {}

  template <typename T>
  bool operator()(const T* a, const T* b, T* residual) const {
    using std::cos;
    using std::sin;
    const T c = cos(a[2]), s = sin(a[2]);
    const T dx = b[0] - a[0], dy = b[1] - a[1];
    Eigen::Matrix<T, 3, 1> e;
    e(0) = c * dx + s * dy - T(z_(0));
    e(1) = -s * dx + c * dy - T(z_(1));
    e(2) = wrapAngle(b[2] - a[2] - T(z_(2)));
    Eigen::Map<Eigen::Matrix<T, 3, 1>> r(residual);
    r = w_.cast<T>() * e;
    return true;
  }

  static ceres::CostFunction* create(const UncertainPose2& z) {
    const Eigen::Matrix3d info = z.covariance.inverse();
    const Eigen::Matrix3d w = Eigen::LLT<Eigen::Matrix3d>(0.5 * (info + info.transpose())).matrixU();
    return new ceres::AutoDiffCostFunction<EdgeCost, 3, 3, 3>(new EdgeCost(z.mean, w));
  }

 private:
  Eigen::Vector3d z_;
  Eigen::Matrix3d w_;
};

// r = W (t − z): an absolute position prior on one pose's (x, y).
class PriorCost {
 public:
  PriorCost(const Eigen::Vector2d& z, const Eigen::Matrix2d& sqrt_info) : z_(z), w_(sqrt_info) {}

  template <typename T>
  bool operator()(const T* a, T* residual) const {
    Eigen::Matrix<T, 2, 1> e;
    e(0) = a[0] - T(z_(0));
    e(1) = a[1] - T(z_(1));
    Eigen::Map<Eigen::Matrix<T, 2, 1>> r(residual);
    r = w_.cast<T>() * e;
    return true;
  }

  static ceres::CostFunction* create(const PositionPrior& p) {
    const Eigen::Matrix2d info = p.covariance.inverse();
    const Eigen::Matrix2d w = Eigen::LLT<Eigen::Matrix2d>(0.5 * (info + info.transpose())).matrixU();
    return new ceres::AutoDiffCostFunction<PriorCost, 2, 3>(new PriorCost(p.position, w));
  }

 private:
  Eigen::Vector2d z_;
  Eigen::Matrix2d w_;
};

void checkEdges(std::size_t n, const std::vector<PoseGraphEdge>& edges, int fixed) {
  if (fixed < 0 || static_cast<std::size_t>(fixed) >= n)
    throw std::invalid_argument("pose graph: fixed pose " + std::to_string(fixed) + " out of range");
  for (const auto& e : edges) {
    if (e.from == e.to || e.from < 0 || e.to < 0 || static_cast<std::size_t>(e.from) >= n ||
        static_cast<std::size_t>(e.to) >= n) {
      throw std::invalid_argument("pose graph: edge " + std::to_string(e.from) + " -> " + std::to_string(e.to) +
                                  " is not between two of " + std::to_string(n) + " poses");
    }
    if (const std::string bad = checkUncertainPose(e.z, true); !bad.empty())
      throw std::invalid_argument("pose graph: edge " + std::to_string(e.from) + " -> " + std::to_string(e.to) + ": " +
                                  bad);
  }
}

// Builds the problem over `blocks` (x, y, yaw per pose). Loss functions are owned by the problem.
void buildProblem(ceres::Problem* problem, std::vector<Eigen::Vector3d>* blocks,
                  const std::vector<PoseGraphEdge>& edges, const SparseOptions* options, int fixed) {
  for (const auto& e : edges) {
    ceres::LossFunction* loss = nullptr;
    if (options != nullptr && e.robust) {
      // The residual is whitened, so the scale is in standard deviations; ceres takes it squared.
      const double s2 = options->loss_scale * options->loss_scale;
      if (options->robust_loss == RobustLoss::kHuber) loss = new ceres::HuberLoss(std::sqrt(s2));
      if (options->robust_loss == RobustLoss::kCauchy) loss = new ceres::CauchyLoss(std::sqrt(s2));
    }
    problem->AddResidualBlock(EdgeCost::create(e.z), loss, (*blocks)[e.from].data(), (*blocks)[e.to].data());
  }
  if (problem->HasParameterBlock((*blocks)[fixed].data())) problem->SetParameterBlockConstant((*blocks)[fixed].data());
}

ceres::SparseLinearAlgebraLibraryType sparseLibrary() {
  return ceres::IsSparseLinearAlgebraLibraryTypeAvailable(ceres::SUITE_SPARSE) ? ceres::SUITE_SPARSE
                                                                               : ceres::EIGEN_SPARSE;
}

}  // namespace

std::string checkPositionPrior(const PositionPrior& p, int n) {
  const std::string which = "position prior on keyframe " + std::to_string(p.index);
  if (p.index < 1 || p.index >= n)
    return which + ": outside [1, " + std::to_string(n - 1) + "] (keyframe 0 is the map's frame)";
  if (!p.position.allFinite() || !p.covariance.allFinite()) return which + ": not finite";
  if (std::abs(p.covariance(0, 1) - p.covariance(1, 0)) > 1e-9 * p.covariance.norm() ||
      Eigen::LLT<Eigen::Matrix2d>(p.covariance).info() != Eigen::Success)
    return which + ": covariance not symmetric positive definite";
  return "";
}

SparseResult optimisePoseGraph(std::vector<Pose2>* poses, const std::vector<PoseGraphEdge>& edges,
                               const SparseOptions& options, int fixed, const std::vector<PositionPrior>& priors) {
  const std::string bad = options.validate();
  if (!bad.empty()) throw std::invalid_argument("sparse back-end: " + bad);
  checkEdges(poses->size(), edges, fixed);
  if (!priors.empty() && fixed != 0) throw std::invalid_argument("pose graph: position priors need pose 0 fixed");
  for (const PositionPrior& p : priors)
    if (const std::string why = checkPositionPrior(p, static_cast<int>(poses->size())); !why.empty())
      throw std::invalid_argument("pose graph: " + why);
  SparseResult res;
  if (edges.empty() && priors.empty()) return res;
  const auto t0 = std::chrono::steady_clock::now();
  std::vector<Eigen::Vector3d> blocks(poses->size());
  for (std::size_t k = 0; k < poses->size(); ++k) blocks[k] = (*poses)[k].vector();
  ceres::Problem problem;
  buildProblem(&problem, &blocks, edges, &options, fixed);
  for (const PositionPrior& p : priors) problem.AddResidualBlock(PriorCost::create(p), nullptr, blocks[p.index].data());

  ceres::Solver::Options so;
  so.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
  so.sparse_linear_algebra_library_type = sparseLibrary();
  so.max_num_iterations = options.max_iterations;
  so.function_tolerance = options.function_tolerance;
  so.num_threads = 1;
  so.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(so, &problem, &summary);

  for (std::size_t k = 0; k < poses->size(); ++k) (*poses)[k] = Pose2::fromVector(blocks[k]);
  res.iterations = static_cast<int>(summary.iterations.size());
  res.initial_cost = summary.initial_cost;
  res.final_cost = summary.final_cost;
  res.converged = summary.termination_type == ceres::CONVERGENCE;
  res.solve_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return res;
}

std::vector<Eigen::Matrix3d> poseGraphMarginals(const std::vector<Pose2>& poses,
                                                const std::vector<PoseGraphEdge>& edges, const std::vector<int>& which,
                                                int fixed) {
  checkEdges(poses.size(), edges, fixed);
  std::vector<Eigen::Vector3d> blocks(poses.size());
  for (std::size_t k = 0; k < poses.size(); ++k) blocks[k] = poses[k].vector();
  ceres::Problem problem;
  buildProblem(&problem, &blocks, edges, nullptr, fixed);  // marginals of the plain Gaussian model
  std::vector<std::pair<const double*, const double*>> pairs;
  for (int k : which) {
    if (k < 0 || static_cast<std::size_t>(k) >= poses.size())
      throw std::invalid_argument("pose graph: marginal of pose " + std::to_string(k) + " out of range");
    if (k == fixed) continue;
    if (!problem.HasParameterBlock(blocks[k].data()))
      throw std::runtime_error("pose graph: pose " + std::to_string(k) + " has no edge");
    pairs.emplace_back(blocks[k].data(), blocks[k].data());
  }
  ceres::Covariance::Options co;
  co.sparse_linear_algebra_library_type = sparseLibrary();
  co.algorithm_type = ceres::SPARSE_QR;
  co.num_threads = 1;
  ceres::Covariance cov(co);
  if (!pairs.empty() && !cov.Compute(pairs, &problem))
    throw std::runtime_error("pose graph: the information matrix is singular (an unconstrained pose)");
  std::vector<Eigen::Matrix3d> out;
  for (int k : which) {
    Eigen::Matrix<double, 3, 3, Eigen::RowMajor> c = Eigen::Matrix3d::Zero();
    if (k != fixed) cov.GetCovarianceBlock(blocks[k].data(), blocks[k].data(), c.data());
    out.push_back(c);
  }
  return out;
}

}  // namespace core
}  // namespace uw_multislam
