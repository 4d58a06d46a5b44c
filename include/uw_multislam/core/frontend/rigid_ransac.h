// Motion between two images from matched seabed points (paper 000 §5, Algorithm 1 and (3)):
// RANSAC around the closed-form least-squares 2-D rigid fit (Lu & Milios), and a covariance
// for the motion from the residuals and the inlier geometry.
//
// Convention: the motion X_B^A is the pose of image B in the frame of image A, so a seabed
// point seen at b (metres, B's image axes) is at a = X_B^A ⊕ b in A's. (Algorithm 1 writes
// X ⊕ f_A - f_B; we fit the same relation with the roles that make X the pose of B in A, the
// quantity (1) and (2) chain.)
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <string>
#include <vector>

#include "uw_multislam/core/geometry/se2.h"

namespace uw_multislam {
namespace core {

/// Least-squares T minimising sum ||T ⊕ b_i - a_i||^2 over the given index list (all if
/// empty). False when fewer than 2 points or they coincide.
bool fitRigid2D(const std::vector<Eigen::Vector2d>& a, const std::vector<Eigen::Vector2d>& b,
                const std::vector<int>& indices, Pose2* out);

/// The same with a free scale s: minimises sum ||s R b_i + t - a_i||^2 (Umeyama in 2-D). The
/// pose (t, yaw) is where B's origin (its principal point on the seabed) lies in A, whatever s.
bool fitSimilarity2D(const std::vector<Eigen::Vector2d>& a, const std::vector<Eigen::Vector2d>& b,
                     const std::vector<int>& indices, Pose2* out, double* scale);

struct RansacOptions {
  /// ε_corr: a correspondence is an inlier when its residual is below this many pixels
  /// (converted to metres with the frame's scale altitude / f). Generous on purpose: on a real
  /// seabed with relief the parallax between two views reaches several pixels (0.2 m of
  /// relief seen from 2.5 m with a 0.4 m baseline shifts ~10 px at f = 1000 px), and a planar
  /// model must accept it. 10 px beat 2.5 and 6 px on the ACFR sequences (README benchmark).
  double inlier_threshold_px = 10.0;
  /// N_min: fewer inliers than this is a failure.
  int min_inliers = 20;
  /// Iterations from the inlier ratio w (Fischler & Bolles): K = log(1 - p) / log(1 - w^2),
  /// clamped to [min_iterations, max_iterations].
  double confidence = 0.999;
  int min_iterations = 20;
  int max_iterations = 2000;
  /// Least-squares re-fits on the inlier set after the consensus search.
  int refine_iterations = 3;
  /// Floor of the residual standard deviation used in the covariance, pixels: the fit is never
  /// trusted beyond the image's sub-pixel accuracy, even when residuals happen to be tiny.
  double min_noise_px = 0.3;
  /// Displacement error the inliers share, pixels: relief parallax, lens distortion, an altitude
  /// that puts the overlap at the wrong scale move neighbouring points alike, so unlike the
  /// independent noise above it does not average out over the inliers. It enters the covariance
  /// as (correlated_noise_px · metres_per_px)² · n (Jᵀ J)⁻¹ (n inliers), the inverse of one
  /// inlier's mean information: it does not fall with the count but grows as the inliers bunch
  /// together (a strip of overlap: a large yaw variance). 0: the independent noise alone.
  double correlated_noise_px = 0.0;
  /// Seed of the sampler: equal inputs give equal results.
  std::uint64_t seed = 7;
  /// Fit a scale correction s along with the motion (similarity instead of rigid). The
  /// altimeter measures the range straight down, but the overlap between two frames lies
  /// elsewhere on a seabed that is not flat, so the two altitude-scaled point sets disagree in
  /// scale by a few per cent. A rigid fit turns that into a translation error proportional to
  /// the distance of the overlap from the image centre; with s free the translation is that of
  /// the principal point, which the scale does not move. s is reported; the motion stays rigid.
  bool estimate_scale = true;
  /// With estimate_scale: a fit whose |s - 1| exceeds this is a failure (a wrong match or a
  /// wrong altitude, not relief).
  double max_scale_change = 0.25;

  std::string validate() const;
};

struct RansacResult {
  bool success = false;
  std::string failure;  // why it failed, for logs
  Pose2 motion;         // X_B^A
  /// Covariance of (x, y, yaw): σ² (Jᵀ J)⁻¹ with J the 2n x p Jacobian of the inlier residuals
  /// with respect to the p = 3 motion parameters (4 with the scale, then marginalised) and
  /// σ² = max(Σ r² / (2n - p), (min_noise_px · metres_per_px)²), plus the shared displacement
  /// error (RansacOptions::correlated_noise_px). It grows with the residuals (poor matches) and
  /// when the inliers are few or bunched together.
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Identity();
  std::vector<int> inliers;  // indices into the correspondence lists
  double rms_residual_m = 0.0;
  double scale = 1.0;  // the fitted scale correction (1 for the rigid model)
  int iterations = 0;
  int hypotheses_gated = 0;  // 2-point hypotheses refused by the prior
};

/// A prior on the motion (the vehicle's nav, core/frontend/nav_prior.h): a 2-point hypothesis
/// whose squared Mahalanobis distance from `motion` exceeds `gate` is not scored. The distance
/// uses `covariance` plus the hypothesis's own noise, diag(t^2, t^2, (t / d)^2) with t the inlier
/// threshold in metres and d the sample's point distance (a 2-point fit is only that good).
struct MotionPrior {
  Pose2 motion;
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
  double gate = 0.0;
};

/// Algorithm 1 on correspondences a[i] <-> b[i] (metres). `metres_per_px` turns the pixel
/// thresholds into metres (altitude / focal length).
/// `prior` (optional) gates the hypotheses; without it the result is as it always was.
RansacResult estimateRigidRansac(const std::vector<Eigen::Vector2d>& a, const std::vector<Eigen::Vector2d>& b,
                                 double metres_per_px, const RansacOptions& options,
                                 const MotionPrior* prior = nullptr);

}  // namespace core
}  // namespace uw_multislam
