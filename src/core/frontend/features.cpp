#include "uw_multislam/core/frontend/features.h"

#include <algorithm>
#include <sstream>
#include <stdexcept>

#include <opencv2/imgproc.hpp>
#ifdef UWMS_OPENCV_SIFT_XFEATURES2D
#include <opencv2/xfeatures2d.hpp>
#endif

#include "uw_multislam/core/frontend/camera_model.h"
#include "uw_multislam/core/frontend/vlfeat_sift.h"

namespace uw_multislam {
namespace core {

std::string featureTypeName(FeatureType t) { return t == FeatureType::kOrb ? "orb" : "sift"; }

bool parseFeatureType(const std::string& name, FeatureType* out) {
  if (name == "sift")
    *out = FeatureType::kSift;
  else if (name == "orb")
    *out = FeatureType::kOrb;
  else
    return false;
  return true;
}

int descriptorBytes(FeatureType t) { return t == FeatureType::kOrb ? 32 : 128; }

bool binaryDescriptors(const cv::Mat& d) { return d.cols == descriptorBytes(FeatureType::kOrb) && d.type() == CV_8U; }

FeatureType descriptorType(const cv::Mat& d) {
  if (binaryDescriptors(d)) return FeatureType::kOrb;
  if (d.cols == descriptorBytes(FeatureType::kSift) && (d.type() == CV_32F || d.type() == CV_8U))
    return FeatureType::kSift;
  throw std::invalid_argument(
      "features: descriptors must be 128 columns (SIFT, CV_32F or CV_8U) or 32 columns of "
      "CV_8U (ORB), not " +
      std::to_string(d.cols) + " columns of type " + std::to_string(d.type()));
}

cv::Mat extractorDescriptors(const cv::Mat& stored) {
  // No feature (a featureless frame, features never read): empty, of the kind it says if any.
  if (stored.empty() && !binaryDescriptors(stored)) return cv::Mat(0, descriptorBytes(FeatureType::kSift), CV_32F);
  if (descriptorType(stored) == FeatureType::kOrb) return stored;
  if (stored.type() == CV_32F) return stored;
  cv::Mat f;
  stored.convertTo(f, CV_32F);
  return f;
}

std::string siftBackendName(SiftBackend b) { return b == SiftBackend::kVlfeat ? "vlfeat" : "opencv"; }

bool parseSiftBackend(const std::string& name, SiftBackend* out) {
  if (name == "opencv")
    *out = SiftBackend::kOpenCv;
  else if (name == "vlfeat")
    *out = SiftBackend::kVlfeat;
  else if (name == "auto")
    *out = defaultSiftBackend();
  else
    return false;
  return true;
}

namespace {

/// OpenCV's SIFT as this build has it (cmake/uwms_platform.cmake).
cv::Ptr<cv::Feature2D> createOpenCvSift(const FeatureOptions& o, int candidates) {
#if defined(UWMS_OPENCV_SIFT_FEATURES2D)
  return cv::SIFT::create(candidates, o.octave_layers, o.contrast_threshold, o.edge_threshold, o.sigma);
#elif defined(UWMS_OPENCV_SIFT_XFEATURES2D)
  return cv::xfeatures2d::SIFT::create(candidates, o.octave_layers, o.contrast_threshold, o.edge_threshold, o.sigma);
#else
  (void)o;
  (void)candidates;
  throw std::invalid_argument("features: " + siftBackendUnavailable(SiftBackend::kOpenCv));
#endif
}

}  // namespace

std::string siftBackendUnavailable(SiftBackend b) {
  if (b == SiftBackend::kVlfeat) return vlfeatSiftUnavailable();
#if defined(UWMS_OPENCV_SIFT_FEATURES2D)
  return std::string();
#elif defined(UWMS_OPENCV_SIFT_XFEATURES2D)
  // opencv_contrib before 4.3 builds xfeatures2d's SIFT only with OPENCV_ENABLE_NONFREE, and
  // throws when it is created otherwise (Ubuntu 20.04's libopencv-contrib-dev): ask it once.
  static const std::string why = [] {
    try {
      cv::xfeatures2d::SIFT::create();
      return std::string();
    } catch (const cv::Exception& e) {
      return "OpenCV " CV_VERSION "'s cv::xfeatures2d::SIFT refuses to run (" + std::string(e.err) + "); use vlfeat";
    }
  }();
  return why;
#else
  return "this build's OpenCV (" CV_VERSION
         ") has no SIFT (cv::SIFT is in features2d from 4.4 on, "
         "cv::xfeatures2d::SIFT in opencv_contrib; built with UWMS_FORCE_SIFT_BACKEND=vlfeat?): use vlfeat";
#endif
}

SiftBackend defaultSiftBackend() {
  return siftBackendUnavailable(SiftBackend::kOpenCv).empty() ? SiftBackend::kOpenCv : SiftBackend::kVlfeat;
}

std::string FeatureOptions::validate() const {
  std::ostringstream os;
  if (num_features < 8 || num_features > 20000) {
    os << "num_features " << num_features << " must be in [8, 20000]";
  } else if (grid_rows < 1 || grid_cols < 1 || grid_rows > num_features || grid_cols > num_features ||
             static_cast<long long>(grid_rows) * grid_cols > num_features) {
    os << "grid_rows " << grid_rows << " x grid_cols " << grid_cols << " must be 1..num_features (" << num_features
       << ") cells, each at least 1";
  } else if (!(candidate_factor >= 1.0 && candidate_factor <= 20.0)) {
    os << "candidate_factor " << candidate_factor << " must be in [1, 20]";
  } else if (!(contrast_threshold > 0.0 && contrast_threshold < 1.0)) {
    os << "contrast_threshold " << contrast_threshold << " must be in (0, 1)";
  } else if (!(edge_threshold > 1.0 && edge_threshold <= 1000.0)) {
    // Bounds beyond any SIFT setting (Lowe: edge 10, sigma 1.6, 3 layers): a sigma of 1000 built
    // Gaussian kernels for minutes, 100000 layers took 12 GB, 1e308 as edge threshold found nothing.
    os << "edge_threshold " << edge_threshold << " must be in (1, 1000]";
  } else if (!(sigma > 0.0 && sigma <= 10.0)) {
    os << "sigma " << sigma << " must be in (0, 10]";
  } else if (octave_layers < 1 || octave_layers > 10) {
    os << "octave_layers " << octave_layers << " must be in [1, 10]";
  } else if (border_px < 0 || border_px > 1000) {
    os << "border_px " << border_px << " must be in [0, 1000]";
  } else if (first_octave != -1 && first_octave != 0) {
    os << "first_octave " << first_octave << " must be -1 (OpenCV's doubled image) or 0 (no doubling)";
  } else if (type == FeatureType::kOrb && first_octave != -1) {
    os << "first_octave is a SIFT setting: leave it at -1 with type orb";
  } else if (orb_fast_threshold < 1 || orb_fast_threshold > 255) {
    os << "orb_fast_threshold " << orb_fast_threshold << " must be in [1, 255]";
  } else if (orb_levels < 1 || orb_levels > 16 || !(orb_scale_factor > 1.0 && orb_scale_factor <= 2.0)) {
    os << "orb_levels must be in [1, 16] and orb_scale_factor in (1, 2]";
  } else if (type == FeatureType::kSift && !siftBackendUnavailable(sift_backend).empty()) {
    os << "sift_backend " << siftBackendName(sift_backend) << ": " << siftBackendUnavailable(sift_backend);
  }
  return os.str();
}

FeatureExtractor::FeatureExtractor(const FeatureOptions& options) : options_(options) {
  const std::string bad = options.validate();
  if (!bad.empty()) throw std::invalid_argument("features: " + bad);
  const int candidates = static_cast<int>(options.num_features * options.candidate_factor);
  if (options.type == FeatureType::kOrb) {
    // Harris-ranked FAST corners with rotated BRIEF, OpenCV's defaults but the FAST threshold
    // and the pyramid (FeatureOptions). Its patch (31 px) keeps corners that far from the border.
    detector_ = cv::ORB::create(candidates, static_cast<float>(options.orb_scale_factor), options.orb_levels, 31, 0, 2,
                                cv::ORB::HARRIS_SCORE, 31, options.orb_fast_threshold);
  } else if (options.sift_backend == SiftBackend::kVlfeat) {
    detector_ = createVlfeatSift(options, candidates);
  } else {
    detector_ = createOpenCvSift(options, candidates);
  }
}

std::vector<int> FeatureExtractor::bucket(const std::vector<cv::KeyPoint>& candidates, cv::Size size) const {
  const auto stronger = [&](int a, int b) {
    const cv::KeyPoint &ka = candidates[a], &kb = candidates[b];
    if (ka.response != kb.response) return ka.response > kb.response;
    if (ka.pt.y != kb.pt.y) return ka.pt.y < kb.pt.y;  // deterministic order on ties
    return ka.pt.x < kb.pt.x;
  };
  std::vector<int> order(candidates.size());
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = static_cast<int>(i);
  std::sort(order.begin(), order.end(), stronger);
  const int cells = options_.grid_rows * options_.grid_cols;
  const int quota = std::max(1, options_.num_features / cells);
  std::vector<int> used(cells, 0);
  std::vector<int> kept, rest;
  for (int i : order) {
    const cv::KeyPoint& k = candidates[i];
    const int r = std::min(options_.grid_rows - 1, static_cast<int>(k.pt.y * options_.grid_rows / size.height));
    const int c = std::min(options_.grid_cols - 1, static_cast<int>(k.pt.x * options_.grid_cols / size.width));
    int& n = used[r * options_.grid_cols + c];
    (n < quota ? kept : rest).push_back(i);
    n += n < quota;
  }
  for (int i : rest) {
    if (static_cast<int>(kept.size()) >= options_.num_features) break;
    kept.push_back(i);
  }
  if (static_cast<int>(kept.size()) > options_.num_features) kept.resize(options_.num_features);
  std::sort(kept.begin(), kept.end(), stronger);
  return kept;
}

FrameFeatures FeatureExtractor::extract(const cv::Mat& grey) const {
  if (grey.empty() || grey.type() != CV_8UC1) {
    throw std::invalid_argument("features: expected a non-empty 8-bit grey image");
  }
  FrameFeatures f;
  f.image_size = grey.size();
  // One pass over the scale space for candidates and their descriptors (a separate compute()
  // would build the pyramid again, which costs as much as the detection).
  std::vector<cv::KeyPoint> candidates;
  cv::Mat descriptors;
  // VLFeat's SIFT starts its scale space at first_octave itself.
  if (options_.type == FeatureType::kSift && options_.sift_backend == SiftBackend::kOpenCv &&
      options_.first_octave == 0 && grey.cols >= 32 && grey.rows >= 32) {
    // No doubling (first_octave in features.h): OpenCV's octave -1 of the halved image is at
    // the full image's resolution. A half-image pixel i covers full pixels 2i, 2i + 1, and
    // SIFT's doubled coordinates put i at 2i: full = 2 x half.
    cv::Mat half;
    cv::resize(grey, half, cv::Size(grey.cols / 2, grey.rows / 2), 0, 0, cv::INTER_AREA);
    detector_->detectAndCompute(half, cv::noArray(), candidates, descriptors);
    for (cv::KeyPoint& k : candidates) {
      k.pt *= 2.0f;
      k.size *= 2.0f;
      // OpenCV packs octave (low byte, signed) and layer: one octave up in the full image.
      const int octave = static_cast<signed char>(k.octave & 255) + 1;
      k.octave = (k.octave & ~255) | (octave & 255);
    }
  } else {
    detector_->detectAndCompute(grey, cv::noArray(), candidates, descriptors);
  }
  const float b = static_cast<float>(options_.border_px);
  std::vector<cv::KeyPoint> inside;
  std::vector<int> rows;
  for (std::size_t i = 0; i < candidates.size(); ++i) {
    const cv::KeyPoint& k = candidates[i];
    if (k.pt.x < b || k.pt.y < b || k.pt.x > grey.cols - 1 - b || k.pt.y > grey.rows - 1 - b) continue;
    inside.push_back(k);
    rows.push_back(static_cast<int>(i));
  }
  const std::vector<int> kept = bucket(inside, grey.size());
  f.keypoints.reserve(kept.size());
  const int width = descriptorBytes(options_.type);
  f.descriptors.create(static_cast<int>(kept.size()), width, options_.type == FeatureType::kOrb ? CV_8U : CV_32F);
  for (std::size_t i = 0; i < kept.size(); ++i) {
    f.keypoints.push_back(inside[kept[i]]);
    descriptors.row(rows[kept[i]]).copyTo(f.descriptors.row(static_cast<int>(i)));
  }
  return f;
}

Eigen::Vector2d pixelToMetres(const cv::Point2f& px, const CameraIntrinsics& c, double altitude_m) {
  const cv::Point2f p = c.distorted() ? undistortPixels({px}, c).front() : px;
  return Eigen::Vector2d((p.x - c.cx) * altitude_m / c.fx, (p.y - c.cy) * altitude_m / c.fy);
}

std::vector<Eigen::Vector2d> applyAltitude(const std::vector<cv::KeyPoint>& keypoints, const CameraIntrinsics& c,
                                           double altitude_m) {
  std::vector<cv::Point2f> px;
  px.reserve(keypoints.size());
  for (const auto& k : keypoints) px.push_back(k.pt);
  const CameraIntrinsics pinhole = c.pinhole();
  std::vector<Eigen::Vector2d> out;
  out.reserve(keypoints.size());
  for (const auto& p : undistortPixels(px, c)) out.push_back(pixelToMetres(p, pinhole, altitude_m));
  return out;
}

}  // namespace core
}  // namespace uw_multislam
