#include "uw_multislam/core/frontend/dense_match.h"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "uw_multislam/core/frontend/camera_model.h"

namespace uw_multislam {
namespace core {

std::string DenseMatchOptions::validate() const {
  std::ostringstream os;
  if (!(flat_field_sigma_px >= 1.0 && flat_field_sigma_px <= 1000.0)) {
    os << "flat_field_sigma_px " << flat_field_sigma_px << " must be in [1, 1000]";
  } else if (!(contrast_threshold > 0.0 && contrast_threshold < 1.0)) {
    os << "contrast_threshold " << contrast_threshold << " must be in (0, 1)";
  } else if (num_features < 16 || num_features > 20000) {
    os << "num_features " << num_features << " must be in [16, 20000]";
  } else if (!(ratio > 0.0 && ratio <= 1.0)) {
    os << "ratio " << ratio << " must be in (0, 1]";
  } else if (min_inliers < 3) {
    os << "min_inliers must be at least 3";
  } else if (!(inliers_per_overlap >= 0.0 && inliers_per_overlap <= 20000.0)) {
    os << "inliers_per_overlap " << inliers_per_overlap << " must be in [0, 20000]";
  } else if (!(min_hull_fraction >= 0.0 && min_hull_fraction <= 1.0)) {
    os << "min_hull_fraction " << min_hull_fraction << " must be in [0, 1]";
  }
  return os.str();
}

cv::Mat flatField(const cv::Mat& grey, double sigma_px) {
  if (grey.empty() || grey.type() != CV_8UC1) throw std::invalid_argument("flatField: expected 8-bit grey");
  cv::Mat g;
  grey.convertTo(g, CV_32F, 1.0, 1.0);  // +1: no division by zero on black
  const int f = 8;
  cv::Mat small, blur;
  if (grey.cols >= 4 * f && grey.rows >= 4 * f) {
    cv::resize(g, small, cv::Size(grey.cols / f, grey.rows / f), 0, 0, cv::INTER_AREA);
    cv::GaussianBlur(small, small, cv::Size(), sigma_px / f, sigma_px / f, cv::BORDER_REFLECT);
    cv::resize(small, blur, grey.size(), 0, 0, cv::INTER_LINEAR);
  } else {
    cv::GaussianBlur(g, blur, cv::Size(), sigma_px, sigma_px, cv::BORDER_REFLECT);
  }
  const cv::Mat ratio = g / blur;
  // Stretched between its 0.5 and 99.5 percentiles: a min-max stretch lets a few specular pixels
  // squash the rest (on the real survey's frames a third of the keypoints at the same threshold).
  std::vector<float> v(ratio.begin<float>(), ratio.end<float>());
  const auto at = [&v](double q) {
    auto it = v.begin() + static_cast<std::ptrdiff_t>(q * (v.size() - 1));
    std::nth_element(v.begin(), it, v.end());
    return static_cast<double>(*it);
  };
  const double lo = at(0.005), hi = at(0.995);
  cv::Mat out;
  ratio.convertTo(out, CV_8U, 255.0 / std::max(hi - lo, 1e-6), -lo * 255.0 / std::max(hi - lo, 1e-6));
  return out;
}

namespace {
FeatureOptions denseFeatureOptions(const DenseMatchOptions& d, FeatureOptions o) {
  o.type = FeatureType::kSift;
  o.num_features = d.num_features;
  o.contrast_threshold = d.contrast_threshold;
  o.candidate_factor = 1.0;  // the strongest num_features, bucketed: no spare candidates needed
  o.first_octave = -1;
  return o;
}
}  // namespace

DenseExtractor::DenseExtractor(const DenseMatchOptions& options, const FeatureOptions& base)
    : options_(options), extractor_(denseFeatureOptions(options, base)) {}

FrameFeatures DenseExtractor::extract(const cv::Mat& grey, const CameraIntrinsics& camera) const {
  FrameFeatures f = extractor_.extract(flatField(grey, options_.flat_field_sigma_px));
  undistortKeypoints(&f.keypoints, camera);
  // RootSIFT: L1-normalise each descriptor, then take square roots; L2 distances between the
  // results compare descriptors by the Hellinger kernel, which weighs the many small bins of a
  // low-contrast patch as much as its few large ones.
  for (int r = 0; r < f.descriptors.rows; ++r) {
    float* d = f.descriptors.ptr<float>(r);
    double sum = 0.0;
    for (int c = 0; c < f.descriptors.cols; ++c) sum += std::abs(d[c]);
    const double s = sum > 0 ? 1.0 / sum : 0.0;
    for (int c = 0; c < f.descriptors.cols; ++c) d[c] = static_cast<float>(std::sqrt(std::abs(d[c]) * s));
  }
  return f;
}

double convexHullArea(const std::vector<cv::Point2f>& points) {
  if (points.size() < 3) return 0.0;
  std::vector<cv::Point2f> hull;
  cv::convexHull(points, hull);
  return cv::contourArea(hull);
}

std::string denseAccepts(int inliers, double hull_area_px2, double overlap, const CameraIntrinsics& camera,
                         const DenseMatchOptions& o) {
  const double overlap_px2 = overlap * camera.width * camera.height;
  std::ostringstream os;
  os.precision(2);
  if (inliers < o.min_inliers) {
    os << inliers << " inliers, fewer than " << o.min_inliers;
  } else if (inliers < o.inliers_per_overlap * overlap) {
    os << inliers << " inliers for a predicted overlap of " << std::fixed << overlap << ", fewer than "
       << o.inliers_per_overlap * overlap;
  } else if (!(hull_area_px2 >= o.min_hull_fraction * overlap_px2) || !(overlap > 0)) {
    os << "the inliers cover " << std::fixed << (overlap_px2 > 0 ? hull_area_px2 / overlap_px2 : 0.0)
       << " of the predicted overlap, less than " << o.min_hull_fraction;
  }
  return os.str();
}

}  // namespace core
}  // namespace uw_multislam
