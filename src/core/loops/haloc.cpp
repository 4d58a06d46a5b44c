#include "uw_multislam/core/loops/haloc.h"

#include <algorithm>
#include <cinttypes>
#include <cmath>
#include <cstdio>
#include <limits>
#include <random>
#include <sstream>
#include <stdexcept>

#if defined(__SSE2__)
#include <emmintrin.h>
#elif defined(__ARM_NEON)
#include <arm_neon.h>
#endif

#include "uw_multislam/core/frontend/features.h"

namespace uw_multislam {
namespace core {

namespace {

// Uniform (0, 1) from mt19937_64's raw output and Box-Muller: the same numbers on every
// platform (std::normal_distribution is implementation-defined).
class PortableGaussian {
 public:
  explicit PortableGaussian(std::uint64_t seed) : rng_(seed) {}
  double operator()() { return std::sqrt(-2.0 * std::log(uniform())) * std::cos(2.0 * M_PI * uniform()); }

 private:
  double uniform() { return (static_cast<double>(rng_() >> 11) + 0.5) * (1.0 / 9007199254740992.0); }
  std::mt19937_64 rng_;
};

// Descriptor rows as unit vectors (zero rows stay zero), 128 values each. A SIFT row is taken as
// it is. An ORB row (256 bits) is embedded first: value 4k + p is the sum of bits 2p
// and 2p + 1 of byte k (0, 1 or 2), so that descriptors a few bits apart stay close in L2 (each
// differing bit moves one value by 1) and the hash (and its 8-bit codes) keeps its 384 values.
// Not centred (values 0..2, mean 1, so unrelated rows are far from orthogonal): centring them
// (-1..1) was tried over bench_feature_kinds.sh's twelve missions and found no more loop pairs
// (43 of 104 global against 44) with maps farther from the truth (59 against 48 mm).
// Hand-written: HALOC is defined on real vectors and OpenCV has no embedding of binary strings.
Eigen::MatrixXf unitRows(const cv::Mat& descriptors, int max_rows) {
  const int rows = std::min(descriptors.rows, max_rows);
  const bool binary = descriptorType(descriptors) == FeatureType::kOrb;
  Eigen::MatrixXf m(rows, HalocProjections::kDescriptorSize);
  for (int j = 0; j < rows; ++j) {
    if (binary) {
      const std::uint8_t* bits = descriptors.ptr<std::uint8_t>(j);
      for (int i = 0; i < HalocProjections::kDescriptorSize; ++i) {
        const int byte = bits[i / 4] >> (2 * (i % 4));
        m(j, i) = static_cast<float>((byte & 1) + ((byte >> 1) & 1));
      }
    } else {
      for (int i = 0; i < HalocProjections::kDescriptorSize; ++i) {
        m(j, i) = descriptors.type() == CV_32F ? descriptors.at<float>(j, i) : descriptors.at<std::uint8_t>(j, i);
      }
    }
    const float norm = m.row(j).norm();
    if (norm > 0.0f) m.row(j) /= norm;
  }
  return m;
}

void checkDescriptors(const cv::Mat& descriptors) {
  try {
    descriptorType(descriptors);
  } catch (const std::invalid_argument&) {
    throw std::invalid_argument(
        "HALOC: descriptors must be 128 columns of CV_32F or CV_8U (SIFT) or 32 of CV_8U (ORB)");
  }
}

void checkOrthonormal(const Eigen::MatrixXd& u) {
  if (u.rows() != HalocProjections::kDirections || u.cols() < 3) {
    throw std::invalid_argument("HALOC projections must be 3 x n with n >= 3");
  }
  const Eigen::MatrixXd g = u * u.transpose();
  if (!g.isApprox(Eigen::Matrix3d::Identity(), 1e-9) || !u.allFinite()) {
    throw std::invalid_argument("HALOC projection vectors are not orthonormal");
  }
}

}  // namespace

HalocProjections::HalocProjections(int n, std::uint64_t seed) : seed_(seed) {
  if (n < 3 || n > 100000) throw std::invalid_argument("HALOC: n must be in [3, 100000]");
  // Every vehicle derives the same vectors from the seed (PortableGaussian).
  PortableGaussian gauss(seed);
  Eigen::MatrixXd g(n, kDirections);
  for (int c = 0; c < kDirections; ++c) {
    for (int r = 0; r < n; ++r) g(r, c) = gauss();
  }
  // Modified Gram-Schmidt, twice for full double precision: three random orthonormal directions.
  for (int pass = 0; pass < 2; ++pass) {
    for (int c = 0; c < kDirections; ++c) {
      for (int p = 0; p < c; ++p) g.col(c) -= g.col(p).dot(g.col(c)) * g.col(p);
      g.col(c).normalize();
    }
  }
  u_ = g.transpose();
  uf_ = u_.cast<float>();
}

HalocProjections::HalocProjections(const Eigen::MatrixXd& vectors, std::uint64_t seed) : u_(vectors), seed_(seed) {
  checkOrthonormal(u_);
  uf_ = u_.cast<float>();
}

Eigen::VectorXf HalocProjections::hash(const cv::Mat& descriptors) const {
  Eigen::VectorXf h = Eigen::VectorXf::Zero(kHashSize);
  if (descriptors.empty()) return h;
  checkDescriptors(descriptors);
  const Eigen::MatrixXf d = unitRows(descriptors, n());
  for (int l = 0; l < kDirections; ++l) {
    h.segment(l * kDescriptorSize, kDescriptorSize) = d.transpose() * uf_.row(l).head(d.rows()).transpose();
  }
  return h;
}

std::string HalocProjections::toText() const {
  std::ostringstream os;
  os << "haloc_projections v1 n " << n() << " seed " << seed_ << "\n";
  char buf[64];
  for (int l = 0; l < kDirections; ++l) {
    for (int j = 0; j < n(); ++j) {
      std::snprintf(buf, sizeof(buf), "%a", u_(l, j));
      os << buf << (j + 1 < n() ? " " : "\n");
    }
  }
  return os.str();
}

HalocProjections HalocProjections::fromText(const std::string& text) {
  std::istringstream is(text);
  std::string magic, version, nkey, skey;
  int n = 0;
  std::uint64_t seed = 0;
  if (!(is >> magic >> version >> nkey >> n >> skey >> seed) || magic != "haloc_projections" || version != "v1" ||
      nkey != "n" || skey != "seed" || n < 3 || n > 100000) {
    throw std::invalid_argument("HALOC projections: bad header (expected 'haloc_projections v1 n N seed S')");
  }
  Eigen::MatrixXd u(kDirections, n);
  for (int l = 0; l < kDirections; ++l) {
    for (int j = 0; j < n; ++j) {
      std::string tok;
      if (!(is >> tok)) throw std::invalid_argument("HALOC projections: truncated");
      char* end = nullptr;
      u(l, j) = std::strtod(tok.c_str(), &end);
      if (*end != '\0') throw std::invalid_argument("HALOC projections: bad number '" + tok + "'");
    }
  }
  return HalocProjections(u, seed);
}

std::string hashModeName(HashMode m) { return m == HashMode::kHaloc ? "haloc" : "sorted_dct"; }

bool parseHashMode(const std::string& name, HashMode* out) {
  if (name == "haloc") {
    *out = HashMode::kHaloc;
  } else if (name == "sorted_dct") {
    *out = HashMode::kSortedDct;
  } else {
    return false;
  }
  return true;
}

bool HashSettings::compatible(const HashSettings& a, const HashSettings& b, std::string* why) {
  auto text = [](const HashSettings& h) {
    return "hash_mode " + hashModeName(h.mode) + ", projection_seed " + std::to_string(h.seed) +
           ", n = " + std::to_string(h.num_features) + ", " + featureTypeName(h.features) + " features";
  };
  if (a.mode == b.mode && a.seed == b.seed && a.num_features == b.num_features && a.features == b.features) return true;
  if (why) *why = "hashes made with " + text(a) + " cannot be compared with hashes made with " + text(b);
  return false;
}

ImageHasher::ImageHasher(HashMode mode, int n, std::uint64_t seed) : mode_(mode), haloc_(n, seed) {
  PortableGaussian gauss(seed ^ 0x5DEECE66DULL);  // another stream than the HALOC vectors'
  key_.resize(HalocProjections::kDescriptorSize);
  for (int i = 0; i < key_.size(); ++i) key_[i] = static_cast<float>(gauss());
  key_.normalize();
}

Eigen::VectorXf ImageHasher::hash(const cv::Mat& descriptors) const {
  if (mode_ == HashMode::kHaloc) return haloc_.hash(descriptors);
  Eigen::VectorXf h = Eigen::VectorXf::Zero(HalocProjections::kHashSize);
  if (descriptors.empty()) return h;
  checkDescriptors(descriptors);
  const Eigen::MatrixXf d = unitRows(descriptors, haloc_.n());
  const int rows = static_cast<int>(d.rows());
  // Rows in the order of their content key r·d (ties by index, for a total order).
  const Eigen::VectorXf keys = d * key_;
  std::vector<int> order(rows);
  for (int j = 0; j < rows; ++j) order[j] = j;
  std::sort(order.begin(), order.end(), [&](int a, int b) { return keys[a] != keys[b] ? keys[a] < keys[b] : a < b; });
  // DCT-II basis vectors 0, 1, 2 over the rows: orthonormal, smooth in the rank. The hash is
  // then divided by sqrt(rows), so that the first block is the mean unit descriptor (values in
  // [0, ~0.3]) and every value stays inside the store's quantisation range.
  for (int r = 0; r < rows; ++r) {
    for (int l = 0; l < HalocProjections::kDirections; ++l) {
      const double w = std::sqrt((l == 0 ? 1.0 : 2.0) / rows) * std::cos(M_PI * l * (r + 0.5) / rows) / std::sqrt(rows);
      h.segment(l * HalocProjections::kDescriptorSize, HalocProjections::kDescriptorSize) +=
          static_cast<float>(w) * d.row(order[r]).transpose();
    }
  }
  return h;
}

std::uint32_t sumAbsDiff(const std::uint8_t* a, const std::uint8_t* b, int n) {
  std::uint32_t total = 0;
  int i = 0;
#if defined(__SSE2__)
  __m128i acc = _mm_setzero_si128();
  for (; i + 16 <= n; i += 16) {
    const __m128i va = _mm_loadu_si128(reinterpret_cast<const __m128i*>(a + i));
    const __m128i vb = _mm_loadu_si128(reinterpret_cast<const __m128i*>(b + i));
    acc = _mm_add_epi64(acc, _mm_sad_epu8(va, vb));
  }
  total = static_cast<std::uint32_t>(_mm_cvtsi128_si32(acc) + _mm_cvtsi128_si32(_mm_srli_si128(acc, 8)));
#elif defined(__ARM_NEON)
  uint32x4_t acc = vdupq_n_u32(0);
  for (; i + 16 <= n; i += 16) {
    const uint8x16_t d = vabdq_u8(vld1q_u8(a + i), vld1q_u8(b + i));
    acc = vpadalq_u16(acc, vpaddlq_u8(d));
  }
  total = vgetq_lane_u32(acc, 0) + vgetq_lane_u32(acc, 1) + vgetq_lane_u32(acc, 2) + vgetq_lane_u32(acc, 3);
#endif
  for (; i < n; ++i) total += static_cast<std::uint32_t>(std::abs(int(a[i]) - int(b[i])));
  return total;
}

namespace {
float codeStep(float range) {
  if (!(range > 0.0f)) throw std::invalid_argument("hash codes: range must be positive");
  return 2.0f * range / 255.0f;
}
std::uint8_t code(float v, float range, float step) {
  return static_cast<std::uint8_t>(std::clamp(std::round((v + range) / step), 0.0f, 255.0f));
}
}  // namespace

float hashCodeRange(HashMode mode) { return mode == HashMode::kSortedDct ? 0.25f : 0.5f; }

std::vector<std::uint8_t> hashCodes(const Eigen::VectorXf& hash, float range) {
  std::vector<std::uint8_t> out(static_cast<std::size_t>(hash.size()));
  const float step = codeStep(range);
  for (Eigen::Index i = 0; i < hash.size(); ++i) out[static_cast<std::size_t>(i)] = code(hash[i], range, step);
  return out;
}

Eigen::VectorXf hashFromCodes(const std::vector<std::uint8_t>& codes, float range) {
  Eigen::VectorXf out(static_cast<Eigen::Index>(codes.size()));
  const float step = codeStep(range);
  for (std::size_t i = 0; i < codes.size(); ++i) out[static_cast<Eigen::Index>(i)] = codes[i] * step - range;
  return out;
}

HashStore::HashStore(float range) : range_(range), step_(codeStep(range)) {
  query_code_.resize(HalocProjections::kHashSize);
  best_.reserve(64);
}

void HashStore::quantise(const Eigen::VectorXf& h, std::uint8_t* out) const {
  for (int i = 0; i < HalocProjections::kHashSize; ++i) out[i] = code(h[i], range_, step_);
}

void HashStore::reserve(std::size_t n) {
  entries_.reserve(n);
  codes_.reserve(n * HalocProjections::kHashSize);
}

int HashStore::add(const HashEntry& who, const Eigen::VectorXf& hash) {
  if (hash.size() != HalocProjections::kHashSize || !hash.allFinite()) {
    throw std::invalid_argument("HashStore: a hash must hold 384 finite values");
  }
  const std::size_t at = codes_.size();
  codes_.resize(at + HalocProjections::kHashSize);
  quantise(hash, codes_.data() + at);
  entries_.push_back(who);
  return static_cast<int>(entries_.size()) - 1;
}

int HashStore::removeSession(int session) {
  std::size_t kept = 0;
  for (std::size_t e = 0; e < entries_.size(); ++e) {
    if (entries_[e].session == session) continue;
    if (kept != e) {
      entries_[kept] = entries_[e];
      std::copy_n(codes_.begin() + e * HalocProjections::kHashSize, HalocProjections::kHashSize,
                  codes_.begin() + kept * HalocProjections::kHashSize);
    }
    ++kept;
  }
  const int removed = static_cast<int>(entries_.size() - kept);
  entries_.resize(kept);
  codes_.resize(kept * HalocProjections::kHashSize);
  entries_.shrink_to_fit();
  codes_.shrink_to_fit();
  return removed;
}

void HashStore::query(const Eigen::VectorXf& hash, int exclude_session, int k, float max_l1,
                      std::vector<HashCandidate>* out) const {
  out->clear();
  if (k <= 0 || hash.size() != HalocProjections::kHashSize) return;
  quantise(hash, query_code_.data());
  const std::uint32_t limit = std::isfinite(max_l1) ? static_cast<std::uint32_t>(std::max(0.0f, max_l1 / step_))
                                                    : std::numeric_limits<std::uint32_t>::max();
  // Keep the k best in `out`, sorted, by insertion: k is small (the paper uses 5).
  std::uint32_t worst = limit;
  std::vector<std::pair<std::uint32_t, int>>& best = best_;
  best.clear();
  for (std::size_t e = 0; e < entries_.size(); ++e) {
    if (entries_[e].session == exclude_session) continue;
    const std::uint32_t d =
        sumAbsDiff(query_code_.data(), codes_.data() + e * HalocProjections::kHashSize, HalocProjections::kHashSize);
    if (d > worst) continue;
    auto pos = std::upper_bound(best.begin(), best.end(), std::make_pair(d, static_cast<int>(e)));
    best.insert(pos, {d, static_cast<int>(e)});
    if (static_cast<int>(best.size()) > k) best.pop_back();
    if (static_cast<int>(best.size()) == k) worst = std::min(limit, best.back().first);
  }
  for (const auto& b : best) out->push_back({b.second, static_cast<float>(b.first) * step_});
}

float HashStore::distance(const Eigen::VectorXf& a, const Eigen::VectorXf& b) const {
  if (a.size() != HalocProjections::kHashSize || b.size() != HalocProjections::kHashSize)
    throw std::invalid_argument("HashStore: a hash must hold 384 values");
  std::vector<std::uint8_t> qa(HalocProjections::kHashSize), qb(HalocProjections::kHashSize);
  quantise(a, qa.data());
  quantise(b, qb.data());
  return static_cast<float>(sumAbsDiff(qa.data(), qb.data(), HalocProjections::kHashSize)) * step_;
}

}  // namespace core
}  // namespace uw_multislam
