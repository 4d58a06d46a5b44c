// The LRU cache of stored keyframes' features (loops/feature_cache.h): the byte budget is never
// exceeded, the least recently used entry goes first, a failed read leaves the cache as it was.
#include <gtest/gtest.h>

#include <map>
#include <random>
#include <stdexcept>
#include <utility>
#include <vector>

#include "uw_multislam/core/loops/feature_cache.h"

namespace uw_multislam {
namespace core {
namespace {

// n features whose first descriptor value names the keyframe (to check what comes back).
FrameFeatures fake(int session, int keyframe, int n) {
  FrameFeatures f;
  for (int i = 0; i < n; ++i) f.keypoints.emplace_back(cv::Point2f(i, 2.0f * i), 1.0f);
  f.descriptors = cv::Mat(n, 128, CV_8U, cv::Scalar(0));
  if (n > 0) f.descriptors.at<std::uint8_t>(0, 0) = static_cast<std::uint8_t>(10 * session + keyframe);
  f.image_size = cv::Size(320, 240);
  return f;
}

struct CountingLoader {
  std::vector<std::pair<int, int>> reads;
  FrameFeatures operator()(int s, int k) {
    reads.emplace_back(s, k);
    if (k < 0)
      throw std::runtime_error("keyframe " + std::to_string(k) + " of session " + std::to_string(s) +
                               " is not in the store");
    return fake(s, k, 100);
  }
};

TEST(FeatureCache, ErasingASessionDropsOnlyItsEntriesAndTheirBytes) {
  CountingLoader loader;
  const std::size_t one = FeatureCache::bytesOf(fake(0, 0, 100));
  FeatureCache cache(20 * one, [&](int s, int k) { return loader(s, k); });
  for (int s = 0; s < 3; ++s)
    for (int k = 0; k < 4; ++k) cache.get(s, k);
  ASSERT_EQ(cache.size(), 12u);
  EXPECT_EQ(cache.eraseSession(1), 4);
  EXPECT_EQ(cache.eraseSession(1), 0);
  EXPECT_EQ(cache.size(), 8u);
  EXPECT_EQ(cache.bytes(), 8 * one);
  for (int k = 0; k < 4; ++k) {
    EXPECT_FALSE(cache.contains(1, k));
    EXPECT_TRUE(cache.contains(0, k) && cache.contains(2, k));
  }
  const std::size_t reads = loader.reads.size();
  EXPECT_EQ(cache.get(1, 2)->descriptors.at<std::uint8_t>(0, 0), 12);  // read again from the loader
  EXPECT_EQ(loader.reads.size(), reads + 1);
}

TEST(FeatureCache, KeepsTheMostRecentlyUsedWithinTheBudget) {
  CountingLoader loader;
  const std::size_t one = FeatureCache::bytesOf(fake(0, 0, 100));
  FeatureCache cache(3 * one, [&](int s, int k) { return loader(s, k); });
  for (int k = 0; k < 3; ++k) EXPECT_EQ(cache.get(0, k)->descriptors.at<std::uint8_t>(0, 0), k);
  EXPECT_EQ(cache.size(), 3u);
  EXPECT_EQ(cache.bytes(), 3 * one);
  // Use 0 again: 1 is now the least recently used, and goes when 3 comes.
  EXPECT_EQ(cache.get(0, 0)->descriptors.at<std::uint8_t>(0, 0), 0);
  EXPECT_EQ(loader.reads.size(), 3u);  // a hit reads nothing
  cache.get(0, 3);
  EXPECT_TRUE(cache.contains(0, 0));
  EXPECT_FALSE(cache.contains(0, 1));
  EXPECT_TRUE(cache.contains(0, 2));
  EXPECT_TRUE(cache.contains(0, 3));
  EXPECT_LE(cache.bytes(), cache.budget());
  EXPECT_EQ(cache.stats().hits, 1);
  EXPECT_EQ(cache.stats().misses, 4);
  EXPECT_EQ(cache.stats().evictions, 1);
  // Then 2 is the oldest: 1 read again evicts it.
  EXPECT_EQ(cache.get(0, 1)->descriptors.at<std::uint8_t>(0, 0), 1);
  EXPECT_FALSE(cache.contains(0, 2));
  EXPECT_EQ(loader.reads.back(), std::make_pair(0, 1));
  // Sessions are part of the key.
  EXPECT_EQ(cache.get(2, 1)->descriptors.at<std::uint8_t>(0, 0), 21);
}

TEST(FeatureCache, TheBudgetHoldsForAnyMixOfSizesAndAnEntryLargerThanItIsNotKept) {
  std::map<std::pair<int, int>, int> sizes;
  FeatureCache cache(40000, [&](int s, int k) { return fake(s, k, sizes[{s, k}]); });
  std::mt19937 rng(3);
  for (int i = 0; i < 500; ++i) {
    const int s = static_cast<int>(rng() % 3), k = static_cast<int>(rng() % 20);
    const std::pair<int, int> key(s, k);
    if (!sizes.count(key)) sizes[key] = static_cast<int>(rng() % 150);
    const auto f = cache.get(s, k);
    EXPECT_EQ(static_cast<int>(f->keypoints.size()), sizes[key]);
    EXPECT_LE(cache.bytes(), cache.budget()) << "after " << i << " reads";
  }
  EXPECT_GT(cache.stats().evictions, 0);
  EXPECT_GT(cache.stats().hits, 0);
  FeatureCache none(0, [&](int s, int k) { return fake(s, k, 10); });
  EXPECT_EQ(none.get(0, 0)->keypoints.size(), 10u);  // handed out...
  EXPECT_EQ(none.size(), 0u);                        // ...not kept
  EXPECT_EQ(none.bytes(), 0u);
}

TEST(FeatureCache, AFailedReadIsReportedAndChangesNothing) {
  CountingLoader loader;
  FeatureCache cache(1 << 20, [&](int s, int k) { return loader(s, k); });
  cache.get(0, 1);
  const std::size_t bytes = cache.bytes();
  try {
    cache.get(4, -3);
    FAIL() << "no exception";
  } catch (const std::runtime_error& e) {
    EXPECT_STREQ(e.what(), "keyframe -3 of session 4 is not in the store");
  }
  EXPECT_EQ(cache.size(), 1u);
  EXPECT_EQ(cache.bytes(), bytes);
  EXPECT_EQ(cache.stats().failures, 1);
  EXPECT_FALSE(cache.contains(4, -3));
  EXPECT_THROW(FeatureCache(10, FeatureCache::Loader()), std::invalid_argument);
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
