// HALOC image hashes for global loop detection (paper 000 §7, equations (6)-(8)).
//
// The hash of an image is its n x m descriptor matrix D (n features in the extractor's fixed
// order, descending response; m = 128) projected on three random orthonormal vectors u_l of
// length n: h_l(i) = sum_j D(j, i) u_l(j), H = (h_0, h_1, h_2), 3m values (6)(7). Descriptors
// are L2-normalised first, so the hash does not depend on OpenCV's descriptor scale. An image
// with fewer than n features is hashed as if the missing rows were zero: its hash is defined
// and comparable, only less distinctive.
//
// The vectors come from a seed (QR of a seeded Gaussian matrix) and must be stored with the
// maps: hashes of different runs are comparable only with the same vectors. They are written
// out and read back exactly (hex floats).
//
// The store keeps hashes quantised to 8 bits in one contiguous array and compares them by L1
// distance (8) with a sum-of-absolute-differences loop: no allocation per query.
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "uw_multislam/core/frontend/features.h"

namespace uw_multislam {
namespace core {

class HalocProjections {
 public:
  static constexpr int kDirections = 3;
  static constexpr int kDescriptorSize = 128;
  static constexpr int kHashSize = kDirections * kDescriptorSize;

  /// Three orthonormal vectors of length n from `seed` (same seed, same vectors, everywhere).
  HalocProjections(int n, std::uint64_t seed);
  /// From given vectors (rows), e.g. read from a map store. Throws std::invalid_argument unless
  /// they are 3 x n and orthonormal to 1e-9.
  explicit HalocProjections(const Eigen::MatrixXd& vectors, std::uint64_t seed = 0);

  int n() const { return static_cast<int>(u_.cols()); }
  std::uint64_t seed() const { return seed_; }
  const Eigen::MatrixXd& vectors() const { return u_; }  // 3 x n

  /// H_t of (6)(7) for descriptors (rows, CV_32F or CV_8U, 128 columns; or ORB's 32 bytes,
  /// embedded in 128 values: haloc.cpp's unitRows). Rows beyond n are
  /// ignored; missing rows count as zero.
  Eigen::VectorXf hash(const cv::Mat& descriptors) const;

  /// Exact text form (hex floats) and back; fromText throws std::invalid_argument when bad.
  std::string toText() const;
  static HalocProjections fromText(const std::string& text);

 private:
  Eigen::MatrixXd u_;
  Eigen::MatrixXf uf_;
  std::uint64_t seed_ = 0;
};

/// How keyframe hashes are made.
///  - kHaloc: the paper's HALOC hash (above): rows in response order, three random orthonormal
///    vectors over the row index.
///  - kSortedDct: the same projection (6)(7) of the descriptor matrix on three orthonormal
///    vectors, but with the rows (L2-normalised descriptors) sorted by a content key — their
///    projection on a fixed random direction r in descriptor space, from the seed — and the
///    vectors the first three DCT-II basis vectors over the n_t rows (u_0 constant: the mean
///    descriptor; u_1, u_2 smooth). Two views of the same place then give nearly the same
///    sorted rows, and a few features more or less only shift them slightly, whereas the
///    response order of kHaloc changes between views and with it every weight. Measured on the
///    demo survey and flights/acfr_test4 (README): ranking overlapping above non-overlapping
///    keyframe pairs, AUC 0.91-1.0 against 0.52-0.64 for kHaloc.
enum class HashMode { kHaloc, kSortedDct };
std::string hashModeName(HashMode m);
bool parseHashMode(const std::string& name, HashMode* out);

/// What makes two keyframe hashes comparable: the mode, the seed of the projection vectors, the
/// number of features n they project, and the feature kind hashed. The session store keeps them
/// (meta table), the hash exchange between vehicles sends them with each hash.
struct HashSettings {
  HashMode mode = HashMode::kSortedDct;
  std::uint64_t seed = 0;
  int num_features = 0;
  std::string projections;  // HalocProjections::toText (the store's copy; not part of the rule)
  /// The feature kind of every keyframe (meta row `features`; a store written before it was
  /// recorded holds SIFT).
  FeatureType features = FeatureType::kSift;

  /// The one rule (the store at open, the back-end for another vehicle's hashes): hashes made
  /// with `a` and `b` can be compared when mode, seed, n and feature kind agree. The projection
  /// vectors follow from the seed, so they are not compared. false with a sentence in *why
  /// naming both sides' values (a's first).
  static bool compatible(const HashSettings& a, const HashSettings& b, std::string* why = nullptr);
};

/// The keyframe hash of either mode (kHashSize values), from one seed.
class ImageHasher {
 public:
  ImageHasher(HashMode mode, int n, std::uint64_t seed);
  Eigen::VectorXf hash(const cv::Mat& descriptors) const;
  HashMode mode() const { return mode_; }
  const HalocProjections& projections() const { return haloc_; }
  const Eigen::VectorXf& key() const { return key_; }  // r of kSortedDct (128, unit)

 private:
  HashMode mode_;
  HalocProjections haloc_;
  Eigen::VectorXf key_;
};

/// The range [-r, r] over which the loop detector's HashStore quantises the hashes of `mode` to
/// 8 bits: sorted-DCT hashes stay within about [-0.06, 0.16], HALOC's within about [-0.37, 0.37]
/// (measured on the demo and flight frames).
float hashCodeRange(HashMode mode);
/// A hash as the store's 8-bit codes over [-range, range] (what a thin link carries instead of
/// 384 floats: 384 bytes instead of 1536), and back: values that quantise to the same codes, so
/// the search over them is the search over the original (HashStore::distance is equal).
std::vector<std::uint8_t> hashCodes(const Eigen::VectorXf& hash, float range);
Eigen::VectorXf hashFromCodes(const std::vector<std::uint8_t>& codes, float range);

/// One stored hash and whose it is.
struct HashEntry {
  int session = 0;
  int keyframe = 0;  // keyframe id within the session
};

struct HashCandidate {
  int entry = 0;    // index into the store
  float l1 = 0.0f;  // L1 distance (8), in hash units
};

class HashStore {
 public:
  /// Hash values are quantised to 8 bits over [-range, range]; unit-norm SIFT descriptors give
  /// values with a standard deviation of about 0.09, so 0.5 clips nothing in practice.
  explicit HashStore(float range = 0.5f);

  /// Appends a hash (size kHashSize); returns its entry index.
  int add(const HashEntry& who, const Eigen::VectorXf& hash);
  std::size_t size() const { return entries_.size(); }
  const HashEntry& entry(int i) const { return entries_[i]; }
  void reserve(std::size_t n);
  /// Removes every entry of `session` (the others keep their order, their indexes shift down);
  /// returns how many. O(size()): an operator's unload_session, not a per-keyframe call.
  int removeSession(int session);

  /// The best `k` entries of sessions other than `exclude_session` with L1 <= max_l1 (pass
  /// infinity for no threshold), nearest first, written into `out` (cleared; its capacity is
  /// reused, so a caller that keeps `out` allocates nothing).
  void query(const Eigen::VectorXf& hash, int exclude_session, int k, float max_l1,
             std::vector<HashCandidate>* out) const;

  /// L1 distance between two hashes as the store measures it (quantised).
  float distance(const Eigen::VectorXf& a, const Eigen::VectorXf& b) const;

 private:
  void quantise(const Eigen::VectorXf& h, std::uint8_t* out) const;
  float range_;
  float step_;
  std::vector<HashEntry> entries_;
  std::vector<std::uint8_t> codes_;  // size() x kHashSize, contiguous
  // Scratch of query(): sized once, so queries allocate nothing. A store is therefore not
  // safe for concurrent queries (one per thread, or a lock).
  mutable std::vector<std::uint8_t> query_code_;
  mutable std::vector<std::pair<std::uint32_t, int>> best_;
};

/// Sum of absolute differences of two byte arrays (the hot loop of the store).
std::uint32_t sumAbsDiff(const std::uint8_t* a, const std::uint8_t* b, int n);

}  // namespace core
}  // namespace uw_multislam
