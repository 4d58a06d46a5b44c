// Descriptor matching between two images: nearest neighbour with Lowe's ratio test and a
// mutual (cross) check, from one distance matrix computed with a single matrix product.
#pragma once

#include <opencv2/core.hpp>

#include <string>
#include <vector>

namespace uw_multislam {
namespace core {

struct MatchOptions {
  /// Lowe's ratio: best / second-best distance must be below this.
  double ratio = 0.8;
  /// Keep a match only if it is also the best match in the other direction.
  bool mutual = true;

  std::string validate() const;
};

struct FeatureMatch {
  int a;           // row in the first descriptor matrix
  int b;           // row in the second
  float distance;  // L2 descriptor distance
};

/// Matches descriptor rows (CV_32F, same width). Empty input gives no matches.
std::vector<FeatureMatch> matchDescriptors(const cv::Mat& a, const cv::Mat& b, const MatchOptions& options);

}  // namespace core
}  // namespace uw_multislam
