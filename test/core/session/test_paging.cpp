// Paging: a reloaded store's keyframes keep only their hashes in RAM and their
// features are read from the store when verified. The loops found must not depend on it: the
// same pairs, inliers and measurements with a cache of about one keyframe, an unlimited cache,
// or every feature in RAM (the nodelet's path); a corrupt row skips that candidate, counted.
#include <gtest/gtest.h>

#include <sqlite3.h>

#include <deque>
#include <limits>
#include <map>
#include <set>
#include <string>
#include <vector>

#include "../../common/scoped_temp_dir.h"
#include "../../common/seabed_features.h"
#include "uw_multislam/core/frontend/odometry.h"
#include "uw_multislam/core/session/pipeline.h"
#include "uw_multislam/core/session/session_manager.h"

namespace uw_multislam {
namespace core {
namespace {

using testing_util::ScopedTempDir;

class PagingTest : public testing_util::SeabedFeaturesTest {
 protected:
  // Session 0 flies east along y = 3 into the store; session 1 (another day, dimmer, turned)
  // crosses its first half.
  void SetUp() override {
    path_ = (dir_.path() / "maps.db").string();
    SessionManager m(sessionManagerOptions(config_, path_));
    Pose2 previous;
    for (int k = 0; k < 8; ++k) {
      const Pose2 p(2.5 + 1.0 * k, 3.0, 0.0);
      KeyframeInput in;
      in.session = 0;
      in.keyframe = k;
      in.frame_index = 10 * k;
      in.stamp_s = k;
      in.altitude_m = 2.0;
      in.camera = camera_;
      in.features = features(p, 2.0);
      in.motion = UncertainPose2(between(previous, p), Eigen::Matrix3d::Identity() * 1e-4);
      in.odometry_pose = between(Pose2(2.5, 3.0, 0.0), p);
      in.hash = m.view().hasher().hash(in.features.descriptors);
      ASSERT_TRUE(m.addKeyframe(in).ok());
      previous = p;
    }
    ASSERT_TRUE(m.endSession(8.0).ok());
    for (int k = 0; k < 5; ++k) {
      world1_.push_back(Pose2(3.0 + 0.9 * k, 3.25, 1.3));
      now_.push_back(features(world1_.back(), 2.3, 0.7));
    }
  }

  enum class Mode { kInRam, kPaged };
  // Session 1 against the reloaded store; the detector's cache statistics in `cache`.
  std::vector<Loop> run(Mode mode, double cache_mb, FeatureCacheStats* cache = nullptr, LoopStats* stats = nullptr,
                        std::string* error = nullptr) {
    SlamConfig c = config_;
    c.loops.feature_cache_mb = cache_mb;
    SessionManager m(sessionManagerOptions(c, path_));
    LoopDetector d(c.loops, c.odometry.matching, c.odometry.ransac, c.odometry.features.num_features);
    std::deque<CameraIntrinsics> cameras;
    if (mode == Mode::kPaged) {
      EXPECT_EQ(loadStoredSessions(&m, &d, &cameras), 8);
    } else {  // every feature in RAM, as the loop detector nodelet gets them
      ReloadedSession r;
      EXPECT_TRUE(m.reload("0", &r).ok());
      cameras.push_back(r.camera);
      for (const StoredKeyframe& k : r.keyframes)
        d.addStoredKeyframe(r.id, k.keyframe, k.frame_index, k.altitude_m, &cameras.back(), k.features(), k.hash);
    }
    std::vector<Loop> loops;
    Trajectory t;
    for (std::size_t k = 0; k < now_.size(); ++k) {
      if (k > 0) t.append(UncertainPose2(between(world1_[k - 1], world1_[k]), Eigen::Matrix3d::Identity() * 1e-4));
      for (const Loop& l : d.addKeyframe(1, static_cast<int>(k), 100 + static_cast<int>(k), 2.3, &camera_, now_[k], t))
        loops.push_back(l);
    }
    if (cache) *cache = d.featureCache() ? d.featureCache()->stats() : FeatureCacheStats();
    if (cache && d.featureCache()) {
      EXPECT_LE(d.featureCache()->bytes(), d.featureCache()->budget());
    }
    if (stats) *stats = d.stats();
    if (error) *error = d.lastReadError();
    return loops;
  }

  static void expectSameLoops(const std::vector<Loop>& a, const std::vector<Loop>& b, const std::string& what) {
    ASSERT_EQ(a.size(), b.size()) << what;
    for (std::size_t i = 0; i < a.size(); ++i) {
      SCOPED_TRACE(what + ", loop " + std::to_string(i));
      EXPECT_EQ(a[i].kind, b[i].kind);
      EXPECT_EQ(a[i].session_a, b[i].session_a);
      EXPECT_EQ(a[i].keyframe_a, b[i].keyframe_a);
      EXPECT_EQ(a[i].session_b, b[i].session_b);
      EXPECT_EQ(a[i].keyframe_b, b[i].keyframe_b);
      EXPECT_EQ(a[i].inliers, b[i].inliers);
      EXPECT_NEAR(a[i].z.mean.x(), b[i].z.mean.x(), 1e-9);
      EXPECT_NEAR(a[i].z.mean.y(), b[i].z.mean.y(), 1e-9);
      EXPECT_NEAR(a[i].z.mean.yaw(), b[i].z.mean.yaw(), 1e-9);
      EXPECT_LE((a[i].z.covariance - b[i].z.covariance).cwiseAbs().maxCoeff(),
                1e-9 * a[i].z.covariance.cwiseAbs().maxCoeff());
    }
  }

  SlamConfig config_;
  ScopedTempDir dir_{"uwms_paging"};
  std::string path_;
  std::vector<Pose2> world1_;
  std::vector<FrameFeatures> now_;
};

TEST_F(PagingTest, AReloadedStoreFindsTheSameLoopsWithATinyCacheAsWithAnUnlimitedOneOrInRam) {
  FeatureCacheStats unlimited_cache, tiny_cache;
  const std::vector<Loop> in_ram = run(Mode::kInRam, 64);
  const std::vector<Loop> unlimited = run(Mode::kPaged, 1e5, &unlimited_cache);
  const std::vector<Loop> tiny = run(Mode::kPaged, 0.1, &tiny_cache);  // 102 kB: one keyframe (78 kB)
  int global = 0;
  for (const Loop& l : in_ram) {
    global += l.kind == Loop::Kind::kGlobal;
    if (l.kind == Loop::Kind::kGlobal) {
      EXPECT_EQ(l.session_a, 0);
    }
  }
  ASSERT_GE(global, 3) << "the scenario must close global loops to compare";
  expectSameLoops(in_ram, unlimited, "unlimited cache");
  expectSameLoops(in_ram, tiny, "tiny cache");
  // Every stored keyframe is a candidate of every new one (best_k 10 >= 8 stored): the unlimited
  // cache reads each once, the tiny one reads again what it had to evict.
  EXPECT_EQ(unlimited_cache.misses, 8);
  EXPECT_EQ(unlimited_cache.hits, 8 * 4);
  EXPECT_EQ(unlimited_cache.evictions, 0);
  EXPECT_GT(tiny_cache.misses, 8);
  EXPECT_GT(tiny_cache.evictions, 0);
}

// The live session paged out behind itself (the loop detector nodelet's ~page_live_after): a
// session that flies east and back along its own track closes local loops on its return; paging
// out every keyframe 2 behind the newest (its features then read through the loader, which gives
// what the store keeps: CV_8U descriptors) finds the same loops as keeping them all in RAM.
TEST_F(PagingTest, LiveKeyframesPagedOutBehindTheSessionFindTheSameLocalLoops) {
  std::vector<Pose2> poses;
  for (int k = 0; k < 6; ++k) poses.push_back(Pose2(2.0 + 0.8 * k, 1.0, 0.0));
  for (int k = 0; k < 6; ++k) poses.push_back(Pose2(6.2 - 0.8 * k, 1.2, M_PI));
  auto runLive = [&](int page_behind, FeatureCacheStats* cache, int* paged) {
    LoopDetector d(config_.loops, config_.odometry.matching, config_.odometry.ransac,
                   config_.odometry.features.num_features);
    std::map<int, FrameFeatures> kept;  // what the store would hold
    d.setFeatureLoader([&kept](int, int keyframe) { return kept.at(keyframe); });
    std::vector<Loop> loops;
    Trajectory t;
    *paged = 0;
    for (int k = 0; k < static_cast<int>(poses.size()); ++k) {
      if (k > 0) t.append(UncertainPose2(between(poses[k - 1], poses[k]), Eigen::Matrix3d::Identity() * 1e-4));
      const FrameFeatures f = features(poses[k], 2.0);
      FrameFeatures stored = f;
      f.descriptors.convertTo(stored.descriptors, CV_8U);
      kept[k] = stored;
      for (const Loop& l : d.addKeyframe(2, k, k, 2.0, &camera_, f, t)) loops.push_back(l);
      if (page_behind > 0 && k >= page_behind) *paged += d.pageOut(2, k - page_behind);
    }
    if (page_behind > 0) {
      EXPECT_FALSE(d.pageOut(2, 0)) << "paged out already";
    }
    EXPECT_FALSE(d.pageOut(2, 99)) << "not held";
    *cache = d.featureCache()->stats();
    return loops;
  };
  FeatureCacheStats ram_cache, paged_cache;
  int none = 0, paged = 0;
  const std::vector<Loop> in_ram = runLive(0, &ram_cache, &none);
  const std::vector<Loop> paged_out = runLive(2, &paged_cache, &paged);
  int local = 0;
  for (const Loop& l : in_ram) local += l.kind == Loop::Kind::kLocal;
  ASSERT_GE(local, 3) << "the return leg must close local loops to compare";
  expectSameLoops(in_ram, paged_out, "live keyframes paged out 2 behind");
  EXPECT_EQ(none, 0);
  EXPECT_EQ(paged, static_cast<int>(poses.size()) - 2);
  EXPECT_EQ(ram_cache.misses, 0);
  EXPECT_GT(paged_cache.misses, 0) << "the return leg's candidates were read through the loader";
}

// Hash exchange between vehicles: vehicle A's session 0 reaches vehicle B's
// loop detector as hashes only; its features are asked for (the loader: A's store) only for a
// keyframe that has candidates. Either way round (A's hashes before B's keyframes, or after them)
// B finds the loops one detector finds with every feature at hand.
TEST_F(PagingTest, AnotherVehiclesHashOnlyKeyframesFindTheLoopsBothWaysAndAreReadOnlyForCandidates) {
  std::vector<Pose2> world0;
  std::vector<FrameFeatures> theirs;
  for (int k = 0; k < 8; ++k) {
    world0.push_back(Pose2(2.5 + 1.0 * k, 3.0, 0.0));
    theirs.push_back(features(world0.back(), 2.0));
  }
  auto makeDetector = [&]() {
    return LoopDetector(config_.loops, config_.odometry.matching, config_.odometry.ransac,
                        config_.odometry.features.num_features);
  };
  auto trajectory = [](const std::vector<Pose2>& w, int upto) {
    Trajectory t;
    for (int k = 1; k <= upto; ++k)
      t.append(UncertainPose2(between(w[k - 1], w[k]), Eigen::Matrix3d::Identity() * 1e-4));
    return t;
  };
  // Reference: one detector holding both sessions' features.
  std::vector<Loop> reference;
  {
    LoopDetector d = makeDetector();
    for (int k = 0; k < 8; ++k) d.addKeyframe(0, k, k, 2.0, &camera_, theirs[k], trajectory(world0, k));
    for (int k = 0; k < 5; ++k)
      for (const Loop& l : d.addKeyframe(1, k, 100 + k, 2.3, &camera_, now_[k], trajectory(world1_, k)))
        if (l.kind == Loop::Kind::kGlobal) reference.push_back(l);
  }
  ASSERT_GE(reference.size(), 3u) << "the scenario must close global loops to compare";
  const ImageHasher hasher(config_.loops.global.hash_mode, config_.odometry.features.num_features,
                           config_.loops.global.projection_seed);
  int reads = 0;
  auto loader = [&](int session, int keyframe) {
    EXPECT_EQ(session, 0) << "only A's features are asked for";
    ++reads;
    FrameFeatures f = theirs.at(keyframe);
    theirs[keyframe].descriptors.convertTo(f.descriptors, CV_8U);  // as A's store keeps them
    return f;
  };

  // A's hashes first: nothing to search against yet, so none is read; B's keyframes then find
  // them (reading their features from A).
  {
    LoopDetector d = makeDetector();
    d.setFeatureLoader(loader);
    reads = 0;
    for (int k = 0; k < 8; ++k)
      EXPECT_TRUE(d.addForeignKeyframe(0, k, k, 2.0, &camera_, hasher.hash(theirs[k].descriptors)).empty());
    EXPECT_EQ(reads, 0);
    std::vector<Loop> found;
    for (int k = 0; k < 5; ++k)
      for (const Loop& l : d.addKeyframe(1, k, 100 + k, 2.3, &camera_, now_[k], trajectory(world1_, k)))
        if (l.kind == Loop::Kind::kGlobal) found.push_back(l);
    expectSameLoops(reference, found, "A's hashes before B's keyframes");
    EXPECT_EQ(reads, 8);  // each of A's keyframes once, then from the cache
  }
  // A's hashes after B's keyframes: A's keyframes search B's, the same pairs (a and b swapped).
  {
    LoopDetector d = makeDetector();
    d.setFeatureLoader(loader);
    for (int k = 0; k < 5; ++k) d.addKeyframe(1, k, 100 + k, 2.3, &camera_, now_[k], trajectory(world1_, k));
    reads = 0;
    std::vector<Loop> found;
    for (int k = 0; k < 8; ++k)
      for (const Loop& l : d.addForeignKeyframe(0, k, k, 2.0, &camera_, hasher.hash(theirs[k].descriptors)))
        found.push_back(l);
    EXPECT_EQ(reads, 8);
    EXPECT_EQ(d.stats().global_accepted, static_cast<int>(found.size()));
    std::set<std::pair<int, int>> pairs_ref, pairs_found;
    for (const Loop& l : reference) pairs_ref.insert({l.keyframe_a, l.keyframe_b});
    for (const Loop& l : found) {
      EXPECT_EQ(l.session_a, 1);
      EXPECT_EQ(l.session_b, 0);
      EXPECT_EQ(l.kind, Loop::Kind::kGlobal);
      pairs_found.insert({l.keyframe_b, l.keyframe_a});
    }
    EXPECT_EQ(pairs_found, pairs_ref);
    // The measurement is the same relative pose seen from the other side.
    for (const Loop& l : found)
      for (const Loop& r : reference)
        if (r.keyframe_a == l.keyframe_b && r.keyframe_b == l.keyframe_a) {
          const Pose2 back = compose(l.z.mean, r.z.mean);  // b<-a then a<-b: the identity
          EXPECT_NEAR(back.translation().norm(), 0.0, 0.01) << l.keyframe_b << "/" << l.keyframe_a;
          EXPECT_NEAR(back.yaw(), 0.0, 0.005);
        }
  }
  // With δ' (loops.global.max_l1) a keyframe of a place nobody here has seen has no candidate and
  // nothing is read for it; one over B's track is read once and closes a loop.
  {
    const HashStore metric(hashCodeRange(config_.loops.global.hash_mode));
    std::vector<Eigen::VectorXf> ours;
    for (const FrameFeatures& f : now_) ours.push_back(hasher.hash(f.descriptors));
    auto nearest = [&](const Eigen::VectorXf& h) {
      float d = std::numeric_limits<float>::max();
      for (const Eigen::VectorXf& o : ours) d = std::min(d, metric.distance(h, o));
      return d;
    };
    const Eigen::VectorXf far = hasher.hash(features(Pose2(2.5, 6.0, 2.8), 2.0).descriptors);
    const Eigen::VectorXf near = hasher.hash(theirs[2].descriptors);
    ASSERT_LT(nearest(near), nearest(far)) << "the scenario needs a place far from B's track in hash space";
    LoopOptions o = config_.loops;
    o.global.max_l1 = 0.5 * (nearest(near) + nearest(far));
    LoopDetector d(o, config_.odometry.matching, config_.odometry.ransac, config_.odometry.features.num_features);
    d.setFeatureLoader(loader);
    for (int k = 0; k < 5; ++k) d.addKeyframe(1, k, 100 + k, 2.3, &camera_, now_[k], trajectory(world1_, k));
    reads = 0;
    EXPECT_TRUE(d.addForeignKeyframe(0, 7, 7, 2.0, &camera_, far).empty());
    EXPECT_EQ(reads, 0);
    EXPECT_FALSE(d.addForeignKeyframe(0, 2, 2, 2.0, &camera_, near).empty());
    EXPECT_EQ(reads, 1);
  }
  // Without a loader there is nowhere to ask: refused.
  LoopDetector bare = makeDetector();
  EXPECT_THROW(bare.addForeignKeyframe(0, 0, 0, 2.0, &camera_, hasher.hash(theirs[0].descriptors)),
               std::invalid_argument);
}

TEST_F(PagingTest, ACorruptOrMissingKeyframeIsAClearErrorAndItsCandidateIsSkipped) {
  const std::vector<Loop> before = run(Mode::kPaged, 1e5);
  bool uses_2 = false;
  for (const Loop& l : before) uses_2 = uses_2 || (l.kind == Loop::Kind::kGlobal && l.keyframe_a == 2);
  ASSERT_TRUE(uses_2) << "the scenario must close a loop with stored keyframe 2";
  {
    SessionStore store(path_);
    ASSERT_EQ(sqlite3_exec(store.handle(), "UPDATE keyframes SET descriptors = x'0102' WHERE keyframe = 2", nullptr,
                           nullptr, nullptr),
              SQLITE_OK);
    const std::int64_t s = store.sessions().at(0).id;
    try {
      store.keyframeFeatures(s, 2);
      ADD_FAILURE() << "no error for a corrupt row";
    } catch (const StoreError& e) {
      EXPECT_NE(std::string(e.what()).find("keyframe 2 of session " + std::to_string(s) +
                                           " has blobs of the wrong size (corrupt)"),
                std::string::npos)
          << e.what();
    }
    try {
      store.keyframeFeatures(s, 99);
      ADD_FAILURE() << "no error for a missing row";
    } catch (const StoreError& e) {
      EXPECT_NE(std::string(e.what()).find("keyframe 99 of session " + std::to_string(s) + " is not in the store"),
                std::string::npos)
          << e.what();
    }
    const StoredKeyframe intact = store.keyframeFeatures(s, 3);
    EXPECT_GT(intact.points.size(), 100u);
    EXPECT_EQ(intact.descriptors.rows, static_cast<int>(intact.points.size()));
  }
  LoopStats stats;
  std::string error;
  const std::vector<Loop> after = run(Mode::kPaged, 1e5, nullptr, &stats, &error);
  std::vector<Loop> expected;
  for (const Loop& l : before)
    if (!(l.kind == Loop::Kind::kGlobal && l.keyframe_a == 2)) expected.push_back(l);
  expectSameLoops(expected, after, "keyframe 2 corrupt");
  EXPECT_EQ(stats.feature_read_failures, 5);  // a candidate of each of the 5 new keyframes
  EXPECT_NE(error.find("corrupt"), std::string::npos) << error;
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
