// The features of stored keyframes, read on demand (paging): an LRU cache with a byte
// budget in front of a loader (the session store's read of one keyframe).
//
// A stored keyframe keeps only what the hash search needs in RAM (its hash, ids, altitude); its
// keypoints and descriptors (about 68 kB at n = 500) are read when it is a candidate to verify.
// The cache keeps the most recently used ones within `budget_bytes` (the descriptor and keypoint
// arrays plus a fixed per-entry overhead); an entry larger than the whole budget is handed out
// but not kept. Hand-written (a list and a hash map): none of the project's libraries offers an
// LRU cache with a byte budget (boost's lives in compute::detail, not a public interface).
//
// Not thread-safe: one caller at a time (the loop detector's worker).
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <list>
#include <memory>
#include <string>
#include <unordered_map>

#include "uw_multislam/core/frontend/features.h"

namespace uw_multislam {
namespace core {

struct FeatureCacheStats {
  long hits = 0, misses = 0, evictions = 0, failures = 0;
};

class FeatureCache {
 public:
  /// Reads one keyframe's features (descriptors CV_8U or CV_32F); throws on a missing or
  /// corrupt record (the exception reaches the caller of get()).
  using Loader = std::function<FrameFeatures(int session, int keyframe)>;

  FeatureCache(std::size_t budget_bytes, Loader loader);

  /// The keyframe's features: from the cache (then most recently used), or read with the loader
  /// and kept, evicting the least recently used entries to stay within the budget. When the
  /// loader throws, the exception passes through (counted in failures) and the cache is as before.
  std::shared_ptr<const FrameFeatures> get(int session, int keyframe);

  bool contains(int session, int keyframe) const { return index_.count(key(session, keyframe)) > 0; }
  /// Drops every cached keyframe of `session` (unload_session); returns how many.
  int eraseSession(int session);
  std::size_t bytes() const { return bytes_; }
  std::size_t budget() const { return budget_; }
  std::size_t size() const { return index_.size(); }
  const FeatureCacheStats& stats() const { return stats_; }

  /// What an entry of these features counts against the budget.
  static std::size_t bytesOf(const FrameFeatures& f);

 private:
  struct Entry {
    std::uint64_t key;
    std::shared_ptr<const FrameFeatures> features;
    std::size_t bytes;
  };
  static std::uint64_t key(int session, int keyframe) {
    return (static_cast<std::uint64_t>(static_cast<std::uint32_t>(session)) << 32) |
           static_cast<std::uint32_t>(keyframe);
  }

  std::size_t budget_;
  Loader loader_;
  std::list<Entry> lru_;  // most recently used first
  std::unordered_map<std::uint64_t, std::list<Entry>::iterator> index_;
  std::size_t bytes_ = 0;
  FeatureCacheStats stats_;
};

}  // namespace core
}  // namespace uw_multislam
