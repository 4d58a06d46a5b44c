#include "uw_multislam/core/loops/feature_cache.h"

#include <stdexcept>
#include <utility>

namespace uw_multislam {
namespace core {

FeatureCache::FeatureCache(std::size_t budget_bytes, Loader loader)
    : budget_(budget_bytes), loader_(std::move(loader)) {
  if (!loader_) throw std::invalid_argument("feature cache: no loader");
}

std::size_t FeatureCache::bytesOf(const FrameFeatures& f) {
  return sizeof(Entry) + sizeof(FrameFeatures) + f.keypoints.size() * sizeof(cv::KeyPoint) +
         f.descriptors.total() * f.descriptors.elemSize();
}

std::shared_ptr<const FrameFeatures> FeatureCache::get(int session, int keyframe) {
  const std::uint64_t k = key(session, keyframe);
  const auto it = index_.find(k);
  if (it != index_.end()) {
    ++stats_.hits;
    lru_.splice(lru_.begin(), lru_, it->second);  // now the most recently used
    return it->second->features;
  }
  ++stats_.misses;
  std::shared_ptr<const FrameFeatures> f;
  try {
    f = std::make_shared<const FrameFeatures>(loader_(session, keyframe));
  } catch (...) {
    ++stats_.failures;
    throw;
  }
  const std::size_t n = bytesOf(*f);
  if (n > budget_) return f;  // handed out, not kept
  while (bytes_ + n > budget_ && !lru_.empty()) {
    bytes_ -= lru_.back().bytes;
    index_.erase(lru_.back().key);
    lru_.pop_back();
    ++stats_.evictions;
  }
  lru_.push_front({k, f, n});
  index_[k] = lru_.begin();
  bytes_ += n;
  return f;
}

int FeatureCache::eraseSession(int session) {
  int n = 0;
  for (auto it = lru_.begin(); it != lru_.end();) {
    if (static_cast<int>(static_cast<std::uint32_t>(it->key >> 32)) != session) {
      ++it;
      continue;
    }
    bytes_ -= it->bytes;
    index_.erase(it->key);
    it = lru_.erase(it);
    ++n;
  }
  return n;
}

}  // namespace core
}  // namespace uw_multislam
