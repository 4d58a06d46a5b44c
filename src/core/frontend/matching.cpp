#include "uw_multislam/core/frontend/matching.h"

#include <Eigen/Core>

#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

namespace uw_multislam {
namespace core {

std::string MatchOptions::validate() const {
  std::ostringstream os;
  if (!(ratio > 0.0 && ratio <= 1.0)) os << "ratio " << ratio << " must be in (0, 1]";
  return os.str();
}

std::vector<FeatureMatch> matchDescriptors(const cv::Mat& a, const cv::Mat& b, const MatchOptions& options) {
  std::vector<FeatureMatch> matches;
  if (a.empty() || b.empty()) return matches;
  if (a.type() != CV_32F || b.type() != CV_32F || a.cols != b.cols) {
    throw std::invalid_argument("matching: descriptors must be CV_32F with the same width");
  }
  // Squared distances |a|^2 + |b|^2 - 2 a b^T, from one matrix product (Eigen's GEMM is about
  // twice as fast as cv::gemm here).
  using RowMajor = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  const cv::Mat ac = a.isContinuous() ? a : a.clone(), bc = b.isContinuous() ? b : b.clone();
  const Eigen::Map<const RowMajor> ea(ac.ptr<float>(), ac.rows, ac.cols), eb(bc.ptr<float>(), bc.rows, bc.cols);
  cv::Mat ab(a.rows, b.rows, CV_32F);
  Eigen::Map<RowMajor> eab(ab.ptr<float>(), ab.rows, ab.cols);
  eab.noalias() = -2.0f * ea * eb.transpose();
  eab.colwise() += ea.rowwise().squaredNorm();
  eab.rowwise() += eb.rowwise().squaredNorm().transpose();

  // Best in each column (b -> a) for the mutual check.
  std::vector<int> best_in_col(ab.cols, -1);
  std::vector<float> best_col_d(ab.cols, std::numeric_limits<float>::max());
  for (int i = 0; i < ab.rows; ++i) {
    const float* r = ab.ptr<float>(i);
    for (int j = 0; j < ab.cols; ++j) {
      if (r[j] < best_col_d[j]) {
        best_col_d[j] = r[j];
        best_in_col[j] = i;
      }
    }
  }
  const double ratio2 = options.ratio * options.ratio;
  for (int i = 0; i < ab.rows; ++i) {
    const float* r = ab.ptr<float>(i);
    float d1 = std::numeric_limits<float>::max(), d2 = d1;
    int j1 = -1;
    for (int j = 0; j < ab.cols; ++j) {
      if (r[j] < d1) {
        d2 = d1;
        d1 = r[j];
        j1 = j;
      } else if (r[j] < d2) {
        d2 = r[j];
      }
    }
    if (j1 < 0) continue;
    // With a single candidate there is no second neighbour: the ratio test cannot pass.
    if (ab.cols < 2 || !(d1 < ratio2 * d2)) continue;
    if (options.mutual && best_in_col[j1] != i) continue;
    matches.push_back({i, j1, std::sqrt(std::max(0.0f, d1))});
  }
  return matches;
}

}  // namespace core
}  // namespace uw_multislam
