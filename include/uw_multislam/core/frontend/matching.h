// Descriptor matching between two images: nearest neighbour with Lowe's ratio test and a
// mutual (cross) check, from one distance matrix (SIFT: a single matrix product; ORB: Hamming
// distances, squaredHammingTable).
#pragma once

#include <opencv2/core.hpp>

#include <string>
#include <vector>

namespace uw_multislam {
namespace core {

struct MatchOptions {
  /// Lowe's ratio: best / second-best distance must be below this.
  double ratio = 0.8;
  /// The same test on Hamming distances (ORB): whole bit counts, the second best close to the
  /// best more often than in SIFT's L2; 0.9 kept the most true matches in the README's sweep.
  double binary_ratio = 0.9;
  /// Keep a match only if it is also the best match in the other direction.
  bool mutual = true;

  std::string validate() const;
};

struct FeatureMatch {
  int a;           // row in the first descriptor matrix
  int b;           // row in the second
  float distance;  // L2 descriptor distance (SIFT) or Hamming distance in bits (ORB)
};

/// Squared Hamming distances (CV_32F, a.rows x b.rows) between rows of two ORB descriptor
/// matrices (32 columns of CV_8U each); throws std::invalid_argument otherwise.
void squaredHammingTable(const cv::Mat& a, const cv::Mat& b, cv::Mat* out);

/// Matches descriptor rows of one kind: CV_32F of the same width (L2), or 32 columns of CV_8U
/// (ORB, Hamming). Empty input gives no matches; two kinds throw std::invalid_argument.
std::vector<FeatureMatch> matchDescriptors(const cv::Mat& a, const cv::Mat& b, const MatchOptions& options);

}  // namespace core
}  // namespace uw_multislam
