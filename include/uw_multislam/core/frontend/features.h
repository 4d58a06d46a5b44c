// SIFT features for odometry and loop detection (paper 000 §5): a fixed number n per image,
// the strongest by response but spread over the image by bucketing, in a fixed order
// (descending response), so that matching and the HALOC hashes (§7) behave the same on every
// frame.
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <opencv2/features2d.hpp>

#include <string>
#include <vector>

#include "uw_multislam/core/frontend/dataset.h"

namespace uw_multislam {
namespace core {

struct FeatureOptions {
  /// n: features kept per image.
  int num_features = 500;
  /// Bucketing grid: each of rows x cols cells keeps up to n / cells of its strongest features;
  /// places left by cells with too few features go to the strongest of the rest.
  int grid_rows = 4;
  int grid_cols = 4;
  /// SIFT keeps this many times n of its strongest candidates (with descriptors) for bucketing
  /// to choose from: more spreads features better, each 0.5 costs about 4 ms at 320x240.
  double candidate_factor = 1.5;
  /// OpenCV SIFT's contrast threshold (lower finds more features on dull seabed).
  double contrast_threshold = 0.02;
  double edge_threshold = 10.0;
  double sigma = 1.6;
  int octave_layers = 3;
  /// Features closer than this to the image border are dropped (their descriptors are clipped).
  int border_px = 8;
  /// First octave of the scale space (VLFeat's name): -1 = OpenCV's SIFT as it is, on the image
  /// doubled first (its firstOctave = -1 is hard-coded in OpenCV 4.6's detectAndCompute);
  /// 0 = no doubling: the scale space starts at the image's own resolution. OpenCV offers no
  /// parameter for it, so 0 runs the same OpenCV SIFT on the image halved (cv::INTER_AREA),
  /// whose doubled octave -1 is then the full-size image with the base blur sigma, and scales
  /// the keypoints back (x2). The loss, detail above half the Nyquist frequency, is what the
  /// base blur removes anyway (sigma 1.6 keeps 4 % of it). About 4x fewer pixels in the scale
  /// space; descriptors are the same 128 OpenCV SIFT values, n the same, so hashes and
  /// verification work unchanged (but are not comparable with the other setting's).
  int first_octave = -1;

  std::string validate() const;
};

/// The features of one image. Pixel coordinates are kept; metric ones are derived with the
/// frame's altitude (apply_altitude of Algorithm 1).
struct FrameFeatures {
  std::vector<cv::KeyPoint> keypoints;  // descending response
  cv::Mat descriptors;                  // keypoints.size() x 128, CV_32F
  cv::Size image_size;

  std::size_t size() const { return keypoints.size(); }
  bool empty() const { return keypoints.empty(); }
};

/// Extracts features from a grey 8-bit image. Reuses one SIFT detector; not thread-safe
/// (one extractor per thread).
class FeatureExtractor {
 public:
  explicit FeatureExtractor(const FeatureOptions& options);
  FrameFeatures extract(const cv::Mat& grey) const;
  const FeatureOptions& options() const { return options_; }

 private:
  /// Indices of the kept candidates, strongest first.
  std::vector<int> bucket(const std::vector<cv::KeyPoint>& candidates, cv::Size size) const;
  FeatureOptions options_;
  cv::Ptr<cv::SIFT> sift_;
};

/// apply_altitude (Algorithm 1): pixel (u, v) to metres on the seabed in the image axes of the
/// frame, origin under the principal point: ((u - cx) a / fx, (v - cy) a / fy), (u, v) first
/// undistorted when the camera has distortion (a raw pixel; features already undistorted go with
/// camera.pinhole()).
Eigen::Vector2d pixelToMetres(const cv::Point2f& px, const CameraIntrinsics& camera, double altitude_m);
std::vector<Eigen::Vector2d> applyAltitude(const std::vector<cv::KeyPoint>& keypoints, const CameraIntrinsics& camera,
                                           double altitude_m);

}  // namespace core
}  // namespace uw_multislam
