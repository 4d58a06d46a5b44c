// The odometry's second, denser registration of a frame pair, tried only where the normal one
// (n SIFT features, ratio 0.8) failed: a pause, a slower camera or a turn leaves consecutive frames
// overlapping by a third to a half, where n = 500 features at the normal contrast threshold give
// too few correspondences on low-contrast seabed. It follows the registration that made the real
// survey's pseudo ground truth (shared data, skerki_survey/README.md): flat-field normalisation
// (the image divided by its Gaussian blur, sigma ~40 px: the vehicle's lights and vignetting
// removed, so that a low contrast threshold finds texture everywhere rather than in the bright
// centre), SIFT with a low contrast threshold and many features, RootSIFT descriptors (Arandjelovic
// & Zisserman 2012: the Hellinger kernel, square roots of the L1-normalised descriptor), mutual
// nearest neighbours with a loose ratio, then the odometry's own RANSAC.
//
// More features and a looser ratio also give more chance consensus, so a count alone is not a
// test: a motion is accepted when its inliers are as many and as spread as the overlap that motion
// itself predicts allows (denseAccepts): at least min_inliers, at least inliers_per_overlap times
// the predicted overlap fraction, and their convex hull covering at least min_hull_fraction of the
// predicted overlap region. A chance consensus claims some motion; its few inliers then neither
// fill the overlap it claims nor reach the count a real overlap of that size gives.
#pragma once

#include <opencv2/core.hpp>

#include <string>

#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/frontend/features.h"
#include "uw_multislam/core/frontend/matching.h"
#include "uw_multislam/core/frontend/rigid_ransac.h"

namespace uw_multislam {
namespace core {

struct DenseMatchOptions {
  bool enabled = true;
  /// Sigma of the Gaussian blur the image is divided by (flat-field normalisation), pixels.
  double flat_field_sigma_px = 40.0;
  /// SIFT of the dense pass: its contrast threshold and the features kept (strongest, bucketed as
  /// the normal ones). Matching costs features^2 (3000: a 36 MB distance table, ~0.1 s).
  double contrast_threshold = 0.01;
  int num_features = 3000;
  /// Lowe's ratio of the mutual nearest-neighbour matching.
  double ratio = 0.9;
  /// The acceptance rule (denseAccepts).
  int min_inliers = 12;
  double inliers_per_overlap = 40.0;
  double min_hull_fraction = 0.2;

  std::string validate() const;
};

/// The image divided by its Gaussian blur (sigma flat_field_sigma_px), its 0.5 to 99.5 percentiles
/// stretched to 0..255 (saturated beyond): 8-bit
/// grey of the input's size. `grey`: 8-bit, one channel. The blur is computed at 1/8 of the size
/// (a sigma of 40 px leaves nothing above that frequency) and scaled back: 20x cheaper than at
/// full size for the same result to a grey level.
cv::Mat flatField(const cv::Mat& grey, double sigma_px);

/// Dense features of a grey 8-bit image (the raw camera image, not the enhanced one): flat field,
/// SIFT, RootSIFT descriptors, keypoints undistorted with `camera`. Not thread-safe (one per thread).
class DenseExtractor {
 public:
  DenseExtractor(const DenseMatchOptions& options, const FeatureOptions& base);
  FrameFeatures extract(const cv::Mat& grey, const CameraIntrinsics& camera) const;

 private:
  DenseMatchOptions options_;
  FeatureExtractor extractor_;
};

/// Whether a dense motion's inliers support it (header): empty when accepted, else why not.
/// `hull_area_px2`: the convex hull of the inliers in the new frame's (undistorted) pixels;
/// `overlap`: the footprint overlap the motion predicts, a fraction of the new frame's image.
std::string denseAccepts(int inliers, double hull_area_px2, double overlap, const CameraIntrinsics& camera,
                         const DenseMatchOptions& options);

/// Area of the convex hull of the given points (pixels^2); 0 for fewer than 3.
double convexHullArea(const std::vector<cv::Point2f>& points);

}  // namespace core
}  // namespace uw_multislam
