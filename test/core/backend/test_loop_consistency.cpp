// Pairwise loop consistency (core/backend/loop_consistency.h): the cycle's covariance and the
// chi-square test against Monte-Carlo, the maximum clique against brute force, and the sets a
// join decides on: consistent loops kept, a wrong loop dropped, loops at one place no spread.
#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <random>

#include "uw_multislam/core/backend/loop_consistency.h"

namespace uw_multislam {
namespace core {
namespace {

const Eigen::Matrix3d kMotionCov = Eigen::Vector3d(1e-4, 1e-4, 1e-5).asDiagonal();
const Eigen::Matrix3d kLoopCov = Eigen::Vector3d(4e-4, 4e-4, 1e-4).asDiagonal();
const Pose2 kLink(1.0, 0.8, 0.3);  // the current map's first keyframe in the previous map's frame

Pose2 sample(const UncertainPose2& p, std::mt19937& rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  const Eigen::Vector3d d = p.covariance.llt().matrixL() * Eigen::Vector3d(n(rng), n(rng), n(rng));
  return Pose2(p.mean.x() + d(0), p.mean.y() + d(1), p.mean.yaw() + d(2));
}

struct Scene {
  Trajectory previous, current;
  Scene() {
    for (int k = 0; k < 20; ++k) previous.append(UncertainPose2(Pose2(0.3, 0.0, 0.03), kMotionCov));
    for (int k = 0; k < 15; ++k) current.append(UncertainPose2(Pose2(0.3, 0.05, -0.02), kMotionCov));
  }
  // The true pose of current keyframe c in previous keyframe p.
  Pose2 truth(int p, int c) const {
    return between(previous.absolutePoses()[p], compose(kLink, current.absolutePoses()[c]));
  }
  CrossLoop loop(int p, int c, std::mt19937* rng, int inliers = 50) const {
    const Pose2 z = rng ? sample(UncertainPose2(truth(p, c), kLoopCov), *rng) : truth(p, c);
    return {p, c, UncertainPose2(z, kLoopCov), inliers};
  }
};

TEST(LoopConsistency, ChiSquareQuantileOfThreeDegrees) {
  EXPECT_NEAR(chiSquare3Quantile(0.99), 11.3449, 1e-4);  // tables
  EXPECT_NEAR(chiSquare3Quantile(0.95), 7.8147, 1e-4);
}

TEST(LoopConsistency, CycleCovarianceAndTestMatchMonteCarlo) {
  // Draw the chains' motions and both loops from their covariances: the cycle's sample
  // covariance matches the first-order one, and the chi-square test at 0.99 (no floors) passes
  // 99 % of true pairs.
  const Scene s;
  const int pa = 3, ca = 2, pb = 15, cb = 11;
  const UncertainPose2 first = loopCycle(s.loop(pa, ca, nullptr), s.loop(pb, cb, nullptr), s.previous, s.current);
  EXPECT_LT(first.mean.translation().norm(), 1e-12);  // exact loops close the cycle
  std::mt19937 rng(17);
  const int n = 4000;
  ConsistencyOptions o;
  o.min_sigma_m = 0.0;
  o.min_sigma_rad = 0.0;
  const double gate = chiSquare3Quantile(0.99);
  std::vector<Eigen::Vector3d> e;
  int passed = 0;
  for (int i = 0; i < n; ++i) {
    Trajectory p, c;
    for (std::size_t k = 0; k + 1 < s.previous.numKeyframes(); ++k)
      p.append(UncertainPose2(sample(s.previous.motion(k + 1), rng), kMotionCov));
    for (std::size_t k = 0; k + 1 < s.current.numKeyframes(); ++k)
      c.append(UncertainPose2(sample(s.current.motion(k + 1), rng), kMotionCov));
    const CrossLoop a = s.loop(pa, ca, &rng), b = s.loop(pb, cb, &rng);
    const Pose2 m = loopCycle(a, b, p, c).mean;
    e.emplace_back(m.x(), m.y(), normalizeAngle(m.yaw()));
    passed += cycleDistance2(a, b, p, c, o) <= gate;
  }
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& v : e) mean += v / n;
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (const auto& v : e) cov += (v - mean) * (v - mean).transpose() / (n - 1);
  // A sample variance's relative standard error is sqrt(2 / n) = 2.2 %: 10 % is 4.5 of them
  // (first order adds a little bias on top).
  for (int k = 0; k < 3; ++k)
    EXPECT_NEAR(cov(k, k), first.covariance(k, k), 0.10 * first.covariance(k, k)) << "axis " << k;
  // Binomial: 0.99 +- 3 sigma (sigma = sqrt(0.99 * 0.01 / 4000) = 0.0016), plus the first-order bias.
  EXPECT_NEAR(static_cast<double>(passed) / n, 0.99, 0.006);
}

TEST(LoopConsistency, CorrectLoopsFormOneConsistentSet) {
  const Scene s;
  std::mt19937 rng(3);
  std::vector<CrossLoop> loops;
  for (int k = 0; k < 8; ++k) loops.push_back(s.loop(2 + 2 * k, 1 + k, &rng, 40 + k));
  const ConsistentSet set = largestConsistentSet(loops, s.previous, s.current, ConsistencyOptions());
  EXPECT_EQ(set.loops, std::vector<int>({0, 1, 2, 3, 4, 5, 6, 7}));
  EXPECT_EQ(set.pairs, 28);
  EXPECT_EQ(set.consistent_pairs, 28);
  EXPECT_EQ(set.inliers, 8 * 40 + 28);
  // Spread: previous keyframes 2..16 (14 x 0.3 m along a gentle arc), current 1..8.
  EXPECT_GT(set.spread_m, 1.5);
}

TEST(LoopConsistency, AWrongLoopIsLeftOutOfTheSet) {
  const Scene s;
  std::mt19937 rng(5);
  std::vector<CrossLoop> loops;
  for (int k = 0; k < 6; ++k) loops.push_back(s.loop(2 + 3 * k, 2 * k, &rng));
  // A loop that passed RANSAC on a look-alike patch: its pose is 1 m off, with many inliers.
  CrossLoop wrong = s.loop(10, 5, nullptr, 400);
  wrong.z.mean = compose(wrong.z.mean, Pose2(1.0, -0.2, 0.1));
  loops.insert(loops.begin() + 3, wrong);
  const ConsistentSet set = largestConsistentSet(loops, s.previous, s.current, ConsistencyOptions());
  EXPECT_EQ(set.loops, std::vector<int>({0, 1, 2, 4, 5, 6}));
  // Two wrong loops that agree with each other (one false place seen twice) are still fewer than
  // the true ones: the true set wins.
  // Z_b = X_pa^pb (+) Z_a (+) X_cb^ca closes the cycle with the first wrong loop exactly.
  CrossLoop wrong2 = s.loop(11, 6, nullptr, 400);
  wrong2.z.mean =
      compose(compose(between(s.previous.absolutePoses()[11], s.previous.absolutePoses()[10]), wrong.z.mean),
              between(s.current.absolutePoses()[5], s.current.absolutePoses()[6]));
  EXPECT_LT(cycleDistance2(wrong, wrong2, s.previous, s.current, ConsistencyOptions()), 1e-9);
  loops.push_back(wrong2);
  const ConsistentSet again = largestConsistentSet(loops, s.previous, s.current, ConsistencyOptions());
  EXPECT_EQ(again.loops, std::vector<int>({0, 1, 2, 4, 5, 6}));
}

TEST(LoopConsistency, LoopsAtOnePlaceHaveNoSpread) {
  const Scene s;
  std::mt19937 rng(9);
  // The same two keyframes matched twice, and one keyframe matched to two neighbours.
  const ConsistentSet same =
      largestConsistentSet({s.loop(5, 4, &rng), s.loop(5, 4, &rng)}, s.previous, s.current, ConsistencyOptions());
  EXPECT_EQ(same.loops.size(), 2u);
  EXPECT_EQ(same.spread_m, 0.0);
  const ConsistentSet one_side =
      largestConsistentSet({s.loop(5, 4, &rng), s.loop(5, 5, &rng)}, s.previous, s.current, ConsistencyOptions());
  EXPECT_EQ(one_side.spread_m, 0.0);
}

TEST(LoopConsistency, MaximumCliqueMatchesBruteForce) {
  std::mt19937 rng(21);
  std::bernoulli_distribution edge(0.6);
  std::uniform_int_distribution<int> weight(1, 5);
  for (int g = 0; g < 40; ++g) {
    const int n = 11;
    std::vector<std::vector<bool>> adj(n, std::vector<bool>(n, false));
    std::vector<int> w(n);
    for (int i = 0; i < n; ++i) {
      w[i] = weight(rng);
      for (int j = i + 1; j < n; ++j) adj[i][j] = adj[j][i] = edge(rng);
    }
    std::size_t best_size = 0;
    int best_weight = -1;
    for (int mask = 1; mask < (1 << n); ++mask) {
      bool clique = true;
      std::size_t size = 0;
      int wsum = 0;
      for (int i = 0; i < n && clique; ++i) {
        if (!(mask >> i & 1)) continue;
        ++size;
        wsum += w[i];
        for (int j = i + 1; j < n; ++j)
          if ((mask >> j & 1) && !adj[i][j]) clique = false;
      }
      if (clique && (size > best_size || (size == best_size && wsum > best_weight)))
        best_size = size, best_weight = wsum;
    }
    const std::vector<int> c = maximumClique(adj, w);
    ASSERT_EQ(c.size(), best_size) << "graph " << g;
    int wsum = 0;
    for (std::size_t a = 0; a < c.size(); ++a) {
      wsum += w[c[a]];
      for (std::size_t b = a + 1; b < c.size(); ++b) ASSERT_TRUE(adj[c[a]][c[b]]);
    }
    EXPECT_EQ(wsum, best_weight) << "graph " << g;
  }
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
