#include "uw_multislam/core/frontend/rigid_ransac.h"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <numeric>
#include <random>
#include <sstream>

#include "uw_multislam/core/backend/loop_consistency.h"

namespace uw_multislam {
namespace core {

namespace {

// A motion with an optional scale correction: a = s R b + t.
struct Model {
  Pose2 pose;
  double scale = 1.0;
};

bool fitModel(const std::vector<Eigen::Vector2d>& a, const std::vector<Eigen::Vector2d>& b,
              const std::vector<int>& indices, bool with_scale, Model* m) {
  if (with_scale) return fitSimilarity2D(a, b, indices, &m->pose, &m->scale);
  m->scale = 1.0;
  return fitRigid2D(a, b, indices, &m->pose);
}

// Squared residuals ||s R b_i + t - a_i||² for all i.
void squaredResiduals(const Model& m, const std::vector<Eigen::Vector2d>& a, const std::vector<Eigen::Vector2d>& b,
                      std::vector<double>* out) {
  const Eigen::Matrix2d r = m.scale * m.pose.rotation();
  const Eigen::Vector2d tr = m.pose.translation();
  out->resize(a.size());
  for (std::size_t i = 0; i < a.size(); ++i) (*out)[i] = (r * b[i] + tr - a[i]).squaredNorm();
}

// Closed-form fit shared by the rigid and the similarity models: centroids, and the sums
// Σ b'·a', Σ b'×a', Σ |b'|² of the centred points.
struct Moments {
  Eigen::Vector2d ca = Eigen::Vector2d::Zero(), cb = Eigen::Vector2d::Zero();
  double dot = 0.0, cross = 0.0, spread = 0.0;
};

bool moments(const std::vector<Eigen::Vector2d>& a, const std::vector<Eigen::Vector2d>& b,
             const std::vector<int>& indices, Moments* m) {
  const std::size_t n = indices.empty() ? a.size() : indices.size();
  if (n < 2 || a.size() != b.size()) return false;
  auto at = [&](std::size_t k) { return indices.empty() ? k : static_cast<std::size_t>(indices[k]); };
  for (std::size_t k = 0; k < n; ++k) {
    m->ca += a[at(k)];
    m->cb += b[at(k)];
  }
  m->ca /= static_cast<double>(n);
  m->cb /= static_cast<double>(n);
  for (std::size_t k = 0; k < n; ++k) {
    const Eigen::Vector2d pa = a[at(k)] - m->ca, pb = b[at(k)] - m->cb;
    m->dot += pb.x() * pa.x() + pb.y() * pa.y();
    m->cross += pb.x() * pa.y() - pb.y() * pa.x();
    m->spread += pb.squaredNorm();
  }
  return m->spread > 1e-18;  // all points coinciding leave the rotation undetermined
}

std::vector<int> inliersOf(const std::vector<double>& r2, double threshold2) {
  std::vector<int> in;
  for (std::size_t i = 0; i < r2.size(); ++i) {
    if (r2[i] < threshold2) in.push_back(static_cast<int>(i));
  }
  return in;
}

// MSAC score: truncated quadratic loss, lower is better.
double msacCost(const std::vector<double>& r2, double threshold2) {
  double c = 0.0;
  for (double e : r2) c += std::min(e, threshold2);
  return c;
}

int requiredIterations(double inlier_ratio, const RansacOptions& o) {
  const double w2 = inlier_ratio * inlier_ratio;
  if (w2 >= 1.0) return o.min_iterations;
  if (w2 <= 1e-12) return o.max_iterations;
  const double k = std::log(1.0 - o.confidence) / std::log(1.0 - w2);
  return std::clamp(static_cast<int>(std::ceil(k)), o.min_iterations, o.max_iterations);
}

}  // namespace

bool fitRigid2D(const std::vector<Eigen::Vector2d>& a, const std::vector<Eigen::Vector2d>& b,
                const std::vector<int>& indices, Pose2* out) {
  Moments m;
  if (!moments(a, b, indices, &m)) return false;
  // Lu & Milios: the rotation that best aligns the centred b onto the centred a.
  const double theta = std::atan2(m.cross, m.dot);
  const Eigen::Vector2d t = m.ca - Pose2(0, 0, theta).rotation() * m.cb;
  *out = Pose2(t.x(), t.y(), theta);
  return true;
}

bool fitSimilarity2D(const std::vector<Eigen::Vector2d>& a, const std::vector<Eigen::Vector2d>& b,
                     const std::vector<int>& indices, Pose2* out, double* scale) {
  Moments m;
  if (!moments(a, b, indices, &m)) return false;
  const double theta = std::atan2(m.cross, m.dot);
  const double s = std::hypot(m.dot, m.cross) / m.spread;
  if (!(s > 0.0)) return false;
  const Eigen::Vector2d t = m.ca - s * Pose2(0, 0, theta).rotation() * m.cb;
  *out = Pose2(t.x(), t.y(), theta);
  *scale = s;
  return true;
}

std::string RansacOptions::validate() const {
  std::ostringstream os;
  if (!(inlier_threshold_px > 0 && inlier_threshold_px <= 100)) {
    // Beyond 100 px every match is an inlier of any motion: 1000 px tracked nothing.
    os << "inlier_threshold_px " << inlier_threshold_px << " must be in (0, 100]";
  } else if (min_inliers < 3) {
    os << "min_inliers must be at least 3";
  } else if (!(confidence > 0 && confidence < 1)) {
    os << "confidence must be in (0, 1)";
  } else if (min_iterations < 1 || max_iterations < min_iterations) {
    os << "need 1 <= min_iterations <= max_iterations";
  } else if (refine_iterations < 0) {
    os << "refine_iterations must be >= 0";
  } else if (!(min_noise_px >= 0 && min_noise_px <= 100)) {
    os << "min_noise_px " << min_noise_px << " must be in [0, 100]";
  } else if (!(correlated_noise_px >= 0 && correlated_noise_px <= 100)) {
    os << "correlated_noise_px " << correlated_noise_px << " must be in [0, 100]";
  } else if (!(max_scale_change > 0 && max_scale_change < 1)) {
    os << "max_scale_change must be in (0, 1)";
  }
  return os.str();
}

RansacResult estimateRigidRansac(const std::vector<Eigen::Vector2d>& a, const std::vector<Eigen::Vector2d>& b,
                                 double metres_per_px, const RansacOptions& o, const MotionPrior* prior) {
  RansacResult res;
  const int n = static_cast<int>(a.size());
  if (a.size() != b.size()) {
    res.failure = "correspondence lists differ in length";
    return res;
  }
  if (n < o.min_inliers) {
    res.failure = "only " + std::to_string(n) + " correspondences (need " + std::to_string(o.min_inliers) + ")";
    return res;
  }
  const double thr = o.inlier_threshold_px * metres_per_px, thr2 = thr * thr;
  std::mt19937_64 rng(o.seed);
  std::uniform_int_distribution<int> pick(0, n - 1);

  double best_cost = std::numeric_limits<double>::infinity();
  std::vector<int> best_inliers;
  std::vector<double> r2;
  int needed = o.max_iterations;
  int it = 0;
  for (; it < needed && it < o.max_iterations; ++it) {
    const int i = pick(rng);
    int j = pick(rng);
    if (i == j) j = (j + 1) % n;
    // A 2-point sample is degenerate when its points nearly coincide in either image.
    if ((a[i] - a[j]).norm() < 2 * thr || (b[i] - b[j]).norm() < 2 * thr) continue;
    Model t;
    if (!fitModel(a, b, {i, j}, o.estimate_scale, &t)) continue;
    if (std::abs(t.scale - 1.0) > o.max_scale_change) continue;
    if (prior) {
      const double d = std::max((b[i] - b[j]).norm(), thr);
      const Eigen::Matrix3d own = Eigen::Vector3d(thr2, thr2, thr2 / (d * d)).asDiagonal();
      ConsistencyOptions no_floor;
      no_floor.min_sigma_m = no_floor.min_sigma_rad = 0.0;
      const Pose2 e(t.pose.x() - prior->motion.x(), t.pose.y() - prior->motion.y(), t.pose.yaw() - prior->motion.yaw());
      if (mahalanobis2(e, prior->covariance + own, no_floor) > prior->gate) {
        ++res.hypotheses_gated;
        continue;
      }
    }
    squaredResiduals(t, a, b, &r2);
    const double cost = msacCost(r2, thr2);
    if (cost < best_cost) {
      best_cost = cost;
      best_inliers = inliersOf(r2, thr2);
      needed = std::max(o.min_iterations, requiredIterations(static_cast<double>(best_inliers.size()) / n, o));
    }
  }
  res.iterations = it;
  if (static_cast<int>(best_inliers.size()) < o.min_inliers) {
    res.failure = "best consensus has " + std::to_string(best_inliers.size()) + " inliers of " + std::to_string(n) +
                  " (need " + std::to_string(o.min_inliers) + ")";
    return res;
  }
  // Least-squares refinement on the consensus set, re-selecting inliers each time.
  Model t;
  std::vector<int> inliers = best_inliers;
  for (int k = 0; k <= o.refine_iterations; ++k) {
    if (!fitModel(a, b, inliers, o.estimate_scale, &t)) {
      res.failure = "degenerate inlier set";
      return res;
    }
    squaredResiduals(t, a, b, &r2);
    std::vector<int> next = inliersOf(r2, thr2);
    if (static_cast<int>(next.size()) < o.min_inliers) break;  // keep the previous set
    if (next == inliers) break;
    inliers = std::move(next);
  }
  if (!fitModel(a, b, inliers, o.estimate_scale, &t)) {
    res.failure = "degenerate inlier set";
    return res;
  }
  if (std::abs(t.scale - 1.0) > o.max_scale_change) {
    res.failure = "scale change " + std::to_string(t.scale) + " between the frames is implausible";
    return res;
  }
  squaredResiduals(t, a, b, &r2);

  // Covariance of the least-squares fit (see the header): residual r = s R b + t - a, with
  // respect to (x, y, yaw, s); the scale is marginalised by taking the (x, y, yaw) block.
  const int p = o.estimate_scale ? 4 : 3;
  Eigen::Matrix4d jtj = Eigen::Matrix4d::Zero();
  double sum_r2 = 0.0;
  const Eigen::Matrix2d rot = t.pose.rotation();
  Eigen::Matrix2d drot;  // d R / d yaw
  drot << -rot(1, 0), -rot(0, 0), rot(0, 0), -rot(1, 0);
  for (int i : inliers) {
    Eigen::Matrix<double, 2, 4> j;
    j.leftCols<2>().setIdentity();
    j.col(2) = t.scale * drot * b[i];
    j.col(3) = rot * b[i];
    jtj += j.transpose() * j;
    sum_r2 += r2[i];
  }
  const int m = static_cast<int>(inliers.size());
  const double floor = o.min_noise_px * metres_per_px;
  const double sigma2 = std::max(sum_r2 / std::max(1, 2 * m - p), floor * floor);
  const Eigen::MatrixXd info = jtj.topLeftCorner(p, p);
  const Eigen::FullPivLU<Eigen::MatrixXd> lu(info);
  if (!lu.isInvertible() || lu.rcond() < 1e-12) {
    res.failure = "inliers do not constrain the motion (degenerate geometry)";
    return res;
  }
  res.success = true;
  res.motion = t.pose;
  res.scale = t.scale;
  const double shared = o.correlated_noise_px * metres_per_px;
  res.covariance = (sigma2 + m * shared * shared) * lu.inverse().topLeftCorner<3, 3>();
  res.covariance = 0.5 * (res.covariance + res.covariance.transpose());
  res.inliers = std::move(inliers);
  res.rms_residual_m = std::sqrt(sum_r2 / m);
  return res;
}

}  // namespace core
}  // namespace uw_multislam
