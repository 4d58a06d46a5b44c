#include "uw_multislam/core/frontend/matching.h"

#include <Eigen/Core>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <sstream>
#include <stdexcept>

#include "uw_multislam/core/frontend/features.h"

namespace uw_multislam {
namespace core {

std::string MatchOptions::validate() const {
  std::ostringstream os;
  if (!(ratio > 0.0 && ratio <= 1.0))
    os << "ratio " << ratio << " must be in (0, 1]";
  else if (!(binary_ratio > 0.0 && binary_ratio <= 1.0))
    os << "binary_ratio " << binary_ratio << " must be in (0, 1]";
  return os.str();
}

namespace {

// Squared Hamming distances of every row pair of two 32-byte (256-bit) descriptor matrices.
// Hand-written: cv::batchDistance(NORM_HAMMING) calls its popcount kernel once per pair through
// a function pointer, about 10 ns a pair here: 2.70 ms per 500 x 500 match, the ORB pipeline's
// largest stage; four 64-bit popcounts inline: 0.55 ms (offline_slam's timing.csv, stage match,
// ORB on the demo, one core; the same matches). target_clones: the POPCNT instruction where the
// CPU has it (chosen at load time), the portable bit count elsewhere; aarch64 has its own (NEON
// cnt). Checked against cv::batchDistance in test_binary_features (OrbMatching.*).
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
__attribute__((target_clones("popcnt", "default")))
#endif
void hammingSquared256(const std::uint8_t* a, std::size_t a_step, int a_rows, const std::uint8_t* b,
                       std::size_t b_step, int b_rows, float* out, std::size_t out_step) {
  for (int i = 0; i < a_rows; ++i) {
    std::uint64_t x[4];
    std::memcpy(x, a + i * a_step, sizeof(x));
    float* row = reinterpret_cast<float*>(reinterpret_cast<char*>(out) + i * out_step);
    for (int j = 0; j < b_rows; ++j) {
      std::uint64_t y[4];
      std::memcpy(y, b + j * b_step, sizeof(y));
      const int d = __builtin_popcountll(x[0] ^ y[0]) + __builtin_popcountll(x[1] ^ y[1]) +
                    __builtin_popcountll(x[2] ^ y[2]) + __builtin_popcountll(x[3] ^ y[3]);
      row[j] = static_cast<float>(d * d);
    }
  }
}

}  // namespace

void squaredHammingTable(const cv::Mat& a, const cv::Mat& b, cv::Mat* out) {
  if (!binaryDescriptors(a) || !binaryDescriptors(b))
    throw std::invalid_argument("matching: Hamming distances need 32 columns of CV_8U on both sides");
  out->create(a.rows, b.rows, CV_32F);
  hammingSquared256(a.data, a.step, a.rows, b.data, b.step, b.rows, out->ptr<float>(), out->step);
}

std::vector<FeatureMatch> matchDescriptors(const cv::Mat& a, const cv::Mat& b, const MatchOptions& options) {
  std::vector<FeatureMatch> matches;
  if (a.empty() || b.empty()) return matches;
  const bool binary = binaryDescriptors(a) && binaryDescriptors(b);
  if (!binary && (a.type() != CV_32F || b.type() != CV_32F || a.cols != b.cols)) {
    throw std::invalid_argument(
        "matching: descriptors must be CV_32F with the same width, or 32 columns of CV_8U "
        "(ORB) on both sides");
  }
  // ab: squared distances, the same ratio and mutual tests for both kinds below.
  cv::Mat ab(a.rows, b.rows, CV_32F);
  if (binary) {
    squaredHammingTable(a, b, &ab);
  } else {
    // Squared distances |a|^2 + |b|^2 - 2 a b^T, from one matrix product (Eigen's GEMM is about
    // twice as fast as cv::gemm here).
    using RowMajor = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
    const cv::Mat ac = a.isContinuous() ? a : a.clone(), bc = b.isContinuous() ? b : b.clone();
    const Eigen::Map<const RowMajor> ea(ac.ptr<float>(), ac.rows, ac.cols), eb(bc.ptr<float>(), bc.rows, bc.cols);
    Eigen::Map<RowMajor> eab(ab.ptr<float>(), ab.rows, ab.cols);
    eab.noalias() = -2.0f * ea * eb.transpose();
    eab.colwise() += ea.rowwise().squaredNorm();
    eab.rowwise() += eb.rowwise().squaredNorm().transpose();
  }

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
  const double ratio = binary ? options.binary_ratio : options.ratio;
  const double ratio2 = ratio * ratio;
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
