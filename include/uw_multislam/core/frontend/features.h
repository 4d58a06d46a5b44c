// SIFT features for odometry and loop detection (paper 000 §5): a fixed number n per image,
// the strongest by response but spread over the image by bucketing, in a fixed order
// (descending response), so that matching and the HALOC hashes (§7) behave the same on every
// frame. ORB (binary) features are an option beside SIFT for clear water: the same n, the
// same bucketing and order; matched by Hamming distance and hashed through a fixed embedding.
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <opencv2/features2d.hpp>

#include <string>
#include <vector>

#include "uw_multislam/core/frontend/dataset.h"

namespace uw_multislam {
namespace core {

/// The feature kind. kSift: OpenCV SIFT, 128 values per feature (CV_32F in memory, the values
/// are whole numbers 0..255 and are stored as bytes). kOrb: OpenCV ORB, 256 bits per feature
/// (32 bytes, CV_8U), matched by Hamming distance. A store and a loop detector hold one kind:
/// the hashes and matches of the two kinds are not comparable.
enum class FeatureType { kSift, kOrb };
std::string featureTypeName(FeatureType t);
bool parseFeatureType(const std::string& name, FeatureType* out);
/// Bytes per feature of a kind's descriptor as stored and sent (128 SIFT, 32 ORB).
int descriptorBytes(FeatureType t);
/// Whether a descriptor matrix has ORB's shape: 32 columns (256 bits) of CV_8U, any rows.
bool binaryDescriptors(const cv::Mat& descriptors);
/// The kind of a descriptor matrix (extractor's, stored or received): 32 columns of CV_8U are
/// ORB, 128 columns (CV_32F or CV_8U) SIFT. Throws std::invalid_argument otherwise.
FeatureType descriptorType(const cv::Mat& descriptors);
/// Descriptors as the extractor gives them, from their stored bytes (n x descriptorBytes CV_8U):
/// SIFT widened to CV_32F, ORB as they are (shared, not copied). An empty matrix gives an empty
/// one (0 x 32 CV_8U stays ORB, anything else 0 x 128 CV_32F). The one place the stored form
/// turns back into the matched form.
cv::Mat extractorDescriptors(const cv::Mat& stored);

/// Which implementation computes SIFT (odometry.features.sift_backend). kOpenCv: OpenCV's
/// (cv::SIFT of features2d from OpenCV 4.4 on, else cv::xfeatures2d::SIFT of opencv_contrib).
/// kVlfeat: VLFeat's (core/frontend/vlfeat_sift.h), for an OpenCV without SIFT (Ubuntu 20.04's
/// 4.2). Both give the same kind of feature: 128 whole numbers 0..255 in the same bin order, for
/// the same points (measured: a point both find has descriptors 9x closer than two different
/// points, and views match across backends as often as within one, doc/benchmarks/platforms.md).
/// So a store, a loop detector or a peer vehicle may mix them; only the type is held to one.
enum class SiftBackend { kOpenCv, kVlfeat };
std::string siftBackendName(SiftBackend b);
/// "opencv", "vlfeat", or "auto": defaultSiftBackend().
bool parseSiftBackend(const std::string& name, SiftBackend* out);
/// Why this build (and its OpenCV at run time) cannot run `b`, or empty when it can.
std::string siftBackendUnavailable(SiftBackend b);
/// OpenCV's SIFT where it runs, else VLFeat's.
SiftBackend defaultSiftBackend();

struct FeatureOptions {
  /// Which features: SIFT (default: the only one that holds in turbid water) or ORB (clear water).
  FeatureType type = FeatureType::kSift;
  /// Which SIFT (type sift only): OpenCV's where this build has it, else VLFeat's.
  SiftBackend sift_backend = defaultSiftBackend();
  /// ORB only: FAST's threshold (OpenCV's default 20 finds too few corners on dull seabed: the
  /// demo's dim second session lost tracking with 10).
  int orb_fast_threshold = 5;
  /// ORB only: pyramid levels and scale step (OpenCV's 8 and 1.2; 5 x 1.4 spans the same scales
  /// in fewer levels and gave the lowest acfr drift of the README's sweep).
  int orb_levels = 5;
  double orb_scale_factor = 1.4;
  /// n: features kept per image.
  int num_features = 500;
  /// Bucketing grid: each of rows x cols cells keeps up to n / cells of its strongest features;
  /// places left by cells with too few features go to the strongest of the rest.
  int grid_rows = 4;
  int grid_cols = 4;
  /// SIFT (or ORB) keeps this many times n of its strongest candidates (with descriptors) for bucketing
  /// to choose from: more spreads features better, each 0.5 costs about 4 ms at 320x240.
  double candidate_factor = 1.5;
  /// OpenCV SIFT's contrast threshold (lower finds more features on dull seabed).
  double contrast_threshold = 0.02;
  double edge_threshold = 10.0;
  double sigma = 1.6;
  int octave_layers = 3;
  /// Features closer than this to the image border are dropped (their descriptors are clipped).
  int border_px = 8;
  /// First octave of the scale space (VLFeat's name; VLFeat's SIFT takes it as it is, the text below
  /// is about OpenCV's): -1 = OpenCV's SIFT as it is, on the image
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
  cv::Mat descriptors;                  // keypoints.size() x 128 CV_32F (SIFT) or x 32 CV_8U (ORB)
  cv::Size image_size;

  std::size_t size() const { return keypoints.size(); }
  bool empty() const { return keypoints.empty(); }
};

/// Extracts features from a grey 8-bit image. Reuses one SIFT (or ORB) detector; not thread-safe
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
  cv::Ptr<cv::Feature2D> detector_;
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
