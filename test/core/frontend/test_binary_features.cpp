// ORB (binary) features beside SIFT. Extraction, Hamming matching against
// OpenCV's own matcher, the motion between two rendered views, the hash's embedding of the bits,
// the store, and a loop detector meeting the other kind: all on frames rendered from the
// procedural seabed or on random bit strings.
#include <gtest/gtest.h>

#include <opencv2/features2d.hpp>

#include <algorithm>
#include <limits>
#include <random>
#include <set>
#include <utility>

#include "../../common/rendered_seabed.h"
#include "../../common/scoped_temp_dir.h"
#include "../../common/sql_file.h"
#include "uw_multislam/core/frontend/enhancement.h"
#include "uw_multislam/core/frontend/features.h"
#include "uw_multislam/core/frontend/matching.h"
#include "uw_multislam/core/frontend/odometry.h"
#include "uw_multislam/core/frontend/pair_motion.h"
#include "uw_multislam/core/geometry/trajectory.h"
#include "uw_multislam/core/loops/haloc.h"
#include "uw_multislam/core/loops/loop_detector.h"
#include "uw_multislam/core/session/slam_config.h"
#include "uw_multislam/core/store/session_store.h"

namespace uw_multislam {
namespace core {
namespace {

class OrbTest : public testing_util::RenderedSeabedTest {
 protected:
  // The grey image the pipeline extracts from (its default enhancement).
  cv::Mat grey(const Pose2& p, double altitude_m) const { return enhancer_.enhance(render(p, altitude_m)); }
  mutable FeatureImageEnhancer enhancer_{OdometryOptions().enhancement};  // its work buffers change
};

FeatureOptions orbOptions() {
  FeatureOptions o;
  o.type = FeatureType::kOrb;
  return o;
}

cv::Mat randomBits(int rows, std::mt19937* rng) {
  cv::Mat m(rows, 32, CV_8U);
  std::uniform_int_distribution<int> byte(0, 255);
  for (int r = 0; r < rows; ++r)
    for (int c = 0; c < 32; ++c) m.at<std::uint8_t>(r, c) = static_cast<std::uint8_t>(byte(*rng));
  return m;
}

TEST_F(OrbTest, OrbGivesNBinaryFeaturesStrongestFirstEachWithOpenCvsDescriptorOfItsKeypoint) {
  const FeatureOptions o = orbOptions();
  const cv::Mat image = grey(Pose2(3, 3, 0.1), 2.0);
  const FrameFeatures f = FeatureExtractor(o).extract(image);
  ASSERT_EQ(f.size(), 500u);
  ASSERT_EQ(f.descriptors.rows, 500);
  EXPECT_EQ(f.descriptors.cols, 32);
  EXPECT_EQ(f.descriptors.type(), CV_8U);
  EXPECT_EQ(descriptorType(f.descriptors), FeatureType::kOrb);
  EXPECT_EQ(f.image_size, image.size());
  for (std::size_t i = 1; i < f.size(); ++i) EXPECT_GE(f.keypoints[i - 1].response, f.keypoints[i].response) << i;
  // Each row is the descriptor OpenCV's ORB computes for that keypoint (rows follow the
  // keypoints through the border filter and the bucketing).
  const cv::Ptr<cv::ORB> orb = cv::ORB::create(750, static_cast<float>(o.orb_scale_factor), o.orb_levels, 31, 0, 2,
                                               cv::ORB::HARRIS_SCORE, 31, o.orb_fast_threshold);
  std::vector<cv::KeyPoint> again = f.keypoints;
  cv::Mat expected;
  orb->compute(image, again, expected);
  ASSERT_EQ(again.size(), f.keypoints.size());
  // compute() returns the keypoints grouped by pyramid level: pair them up by position and level.
  int compared = 0;
  for (std::size_t i = 0; i < again.size(); ++i) {
    for (std::size_t j = 0; j < f.keypoints.size(); ++j) {
      if (f.keypoints[j].pt != again[i].pt || f.keypoints[j].octave != again[i].octave) continue;
      EXPECT_EQ(cv::norm(expected.row(static_cast<int>(i)), f.descriptors.row(static_cast<int>(j)), cv::NORM_HAMMING),
                0.0)
          << "keypoint " << j;
      ++compared;
      break;
    }
  }
  EXPECT_EQ(compared, 500);

  FeatureOptions bad = orbOptions();
  bad.first_octave = 0;
  EXPECT_NE(bad.validate().find("first_octave"), std::string::npos);
  bad = orbOptions();
  bad.orb_fast_threshold = 0;
  EXPECT_NE(bad.validate().find("orb_fast_threshold"), std::string::npos);
  FeatureType t;
  EXPECT_TRUE(parseFeatureType(featureTypeName(FeatureType::kOrb), &t));
  EXPECT_EQ(t, FeatureType::kOrb);
  EXPECT_FALSE(parseFeatureType("akaze", &t));
}

TEST(OrbMatching, HammingTableEqualsOpenCvsBatchDistance) {
  std::mt19937 rng(5);
  const cv::Mat a = randomBits(300, &rng);
  const cv::Mat wide = randomBits(257, &rng), wider(257, 48, CV_8U);
  cv::randu(wider, 0, 256);
  wide.copyTo(wider(cv::Rect(8, 0, 32, 257)));
  const cv::Mat b = wider(cv::Rect(8, 0, 32, 257));  // rows 48 bytes apart: not continuous
  ASSERT_FALSE(b.isContinuous());
  cv::Mat mine, theirs;
  squaredHammingTable(a, b, &mine);
  cv::batchDistance(a, wide, theirs, CV_32S, cv::noArray(), cv::NORM_HAMMING);
  theirs.convertTo(theirs, CV_32F);
  ASSERT_EQ(mine.size(), theirs.size());
  EXPECT_EQ(cv::norm(mine, theirs.mul(theirs), cv::NORM_INF), 0.0);
  cv::Mat sift(3, 128, CV_32F, cv::Scalar(1));
  EXPECT_THROW(squaredHammingTable(a, sift, &mine), std::invalid_argument);
}

TEST(OrbMatching, RatioAndMutualTestsKeepWhatOpenCvsMatcherKeeps) {
  // b: 400 random strings; a: 150 of them with 0-40 bits flipped (some still match, some are
  // too far to pass the ratio test) and 100 unrelated ones.
  std::mt19937 rng(11);
  const cv::Mat b = randomBits(400, &rng);
  cv::Mat a = randomBits(250, &rng);
  std::uniform_int_distribution<int> bit(0, 255), flips(0, 40);
  for (int i = 0; i < 150; ++i) {
    b.row(2 * i + 1).copyTo(a.row(i));
    for (int f = flips(rng); f > 0; --f) {
      const int k = bit(rng);
      a.at<std::uint8_t>(i, k / 8) ^= static_cast<std::uint8_t>(1 << (k % 8));
    }
  }
  MatchOptions o;
  const std::vector<FeatureMatch> mine = matchDescriptors(a, b, o);
  // OpenCV: two nearest in b for each row of a, the nearest in a for each row of b.
  const cv::BFMatcher bf(cv::NORM_HAMMING);
  std::vector<std::vector<cv::DMatch>> ab, ba;
  bf.knnMatch(a, b, ab, 2);
  bf.knnMatch(b, a, ba, 1);
  std::set<std::pair<int, int>> expected;
  for (const auto& m : ab) {
    if (m.size() < 2 || !(m[0].distance < o.binary_ratio * m[1].distance)) continue;
    if (ba[m[0].trainIdx][0].trainIdx != m[0].queryIdx) continue;
    expected.insert({m[0].queryIdx, m[0].trainIdx});
  }
  std::set<std::pair<int, int>> got;
  for (const FeatureMatch& m : mine) {
    got.insert({m.a, m.b});
    EXPECT_EQ(m.distance, static_cast<float>(cv::norm(a.row(m.a), b.row(m.b), cv::NORM_HAMMING)));
  }
  EXPECT_EQ(got, expected);
  int related = 0;
  for (const auto& [i, j] : got) {
    if (i >= 150) continue;  // an unrelated row: kept only where OpenCV keeps it too (above)
    EXPECT_EQ(j, 2 * i + 1) << i;
    ++related;
  }
  EXPECT_GE(related, 100);  // most of the 150 related rows
  // The other kind on one side: refused, not compared.
  EXPECT_THROW(matchDescriptors(a, cv::Mat(10, 128, CV_32F, cv::Scalar(0)), o), std::invalid_argument);
}

TEST_F(OrbTest, MotionBetweenTwoRenderedViewsIsTheTruth) {
  const FeatureExtractor x(orbOptions());
  const Pose2 p0(3.0, 3.0, 0.2), p1(3.15, 3.05, 0.3);
  const FrameFeatures f0 = x.extract(grey(p0, 2.0)), f1 = x.extract(grey(p1, 2.1));
  const PairMotion m = estimatePairMotion({&f0, 2.0, &camera_}, {&f1, 2.1, &camera_}, MatchOptions(), RansacOptions());
  ASSERT_TRUE(m.ransac.success);
  EXPECT_GE(m.ransac.inliers.size(), 100u);
  const Pose2 truth = between(p0, p1);
  // 1 cm / 0.005 rad: SIFT's bound in test_klt; an ORB pixel at 2 m is 6.7 mm.
  EXPECT_TRUE(approxEqual(m.ransac.motion, truth, 0.01, 0.005)) << m.ransac.motion << " vs " << truth;
}

// The hash's view of a 256-bit string, built another way: bits unpacked into 256 values (bit b of
// byte k is value 8k + b), neighbours summed.
cv::Mat embedded(const cv::Mat& bits) {
  cv::Mat e(bits.rows, 128, CV_32F);
  for (int r = 0; r < bits.rows; ++r) {
    std::vector<int> unpacked(256);
    for (int k = 0; k < 32; ++k)
      for (int b = 0; b < 8; ++b) unpacked[8 * k + b] = (bits.at<std::uint8_t>(r, k) >> b) & 1;
    for (int i = 0; i < 128; ++i) e.at<float>(r, i) = static_cast<float>(unpacked[2 * i] + unpacked[2 * i + 1]);
  }
  return e;
}

TEST_F(OrbTest, HashesTakeEachPairOfBitsAsOneValueAndKeepTheSamePlaceNearest) {
  std::mt19937 rng(3);
  const cv::Mat bits = randomBits(500, &rng);
  for (HashMode mode : {HashMode::kSortedDct, HashMode::kHaloc}) {
    const ImageHasher h(mode, 500, 20231122);
    const Eigen::VectorXf direct = h.hash(bits), via = h.hash(embedded(bits));
    ASSERT_EQ(direct.size(), HalocProjections::kHashSize);
    EXPECT_LT((direct - via).cwiseAbs().maxCoeff(), 1e-6f) << hashModeName(mode);
    EXPECT_GT(direct.cwiseAbs().maxCoeff(), 1e-3f);
  }
  // Rendered views: the same place, shifted 2 and 4 cm, nearer than any unrelated place (the
  // default hash, as LoopTest.SamePlaceHashesCloseOtherPlacesFar for SIFT).
  const FeatureExtractor x(orbOptions());
  const ImageHasher h(HashMode::kSortedDct, 500, 20231122);
  HashStore store;
  auto hashAt = [&](const Pose2& p) { return h.hash(x.extract(grey(p, 2.0)).descriptors); };
  const Eigen::VectorXf a = hashAt(Pose2(3, 3, 0.1));
  float nearest_other = std::numeric_limits<float>::max();
  for (const Pose2& e : {Pose2(8, 5, 1.0), Pose2(9, 2.5, -2.0), Pose2(6, 6, 0.5), Pose2(2.5, 6, 2.8)})
    nearest_other = std::min(nearest_other, store.distance(a, hashAt(e)));
  for (double dx : {0.02, 0.04}) EXPECT_LT(store.distance(a, hashAt(Pose2(3 + dx, 3, 0.1))), nearest_other) << dx;
}

TEST(OrbStore, KeepsBinaryDescriptorsAndRefusesTheOtherKind) {
  testing_util::ScopedTempDir dir("uwms_orb_store");
  const std::string path = (dir.path() / "maps.db").string();
  std::mt19937 rng(9);
  std::int64_t s = -1;
  {
    SessionStore store(path);
    store.checkHashSettings({HashMode::kSortedDct, 7, 500, "x", FeatureType::kOrb});
    s = store.addSession("orb", CameraIntrinsics{320, 240, 300, 300, 159.5, 119.5}, 0.0);
    StoredKeyframe kf;
    kf.session = s;
    kf.image_size = cv::Size(320, 240);
    kf.altitude_m = 2.0;
    for (int i = 0; i < 20; ++i) kf.points.emplace_back(10.0f + i, 20.0f + i);
    kf.descriptors = randomBits(20, &rng);
    kf.hash = Eigen::VectorXf::Constant(HalocProjections::kHashSize, 0.01f);
    store.addKeyframe(kf, nullptr, nullptr);
    const StoredKeyframe back = store.keyframeFeatures(s, 0);
    ASSERT_EQ(back.descriptors.cols, 32);
    EXPECT_EQ(cv::norm(back.descriptors, kf.descriptors, cv::NORM_HAMMING), 0.0);
    const cv::Mat matched = extractorDescriptors(back.descriptors);
    EXPECT_EQ(matched.type(), CV_8U);
    EXPECT_EQ(matched.data, back.descriptors.data);  // ORB's bytes are matched as they are: no copy
    kf.keyframe = 1;
    kf.descriptors = cv::Mat(20, 64, CV_8U, cv::Scalar(0));
    EXPECT_THROW(store.addKeyframe(kf, nullptr, nullptr), StoreError);
    kf.descriptors = cv::Mat(20, 128, CV_8U, cv::Scalar(0));  // SIFT's width in a store of ORB keyframes
    try {
      store.addKeyframe(kf, nullptr, nullptr);
      FAIL() << "a SIFT keyframe stored among ORB ones";
    } catch (const StoreError& e) {
      EXPECT_NE(std::string(e.what()).find("this store's kind has 32"), std::string::npos) << e.what();
    }
    EXPECT_EQ(store.keyframes(s, false).size(), 1u);  // nothing of the refused keyframe kept
    // A featureless keyframe: read back as ORB's empty 0 x 32 (the store's kind), not SIFT's shape.
    kf.points.clear();
    kf.descriptors = cv::Mat(0, 32, CV_8U);
    store.addKeyframe(kf, nullptr, nullptr);
    const StoredKeyframe blank = store.keyframeFeatures(s, 1);
    EXPECT_EQ(blank.descriptors.rows, 0);
    EXPECT_EQ(blank.descriptors.cols, 32);
    try {
      store.checkHashSettings({HashMode::kSortedDct, 7, 500, "x", FeatureType::kSift});
      FAIL() << "SIFT accepted by a store of ORB keyframes";
    } catch (const StoreError& e) {
      EXPECT_NE(std::string(e.what()).find("orb features"), std::string::npos) << e.what();
    }
    HashSettings h;
    ASSERT_TRUE(store.hashSettings(&h));
    EXPECT_EQ(h.features, FeatureType::kOrb);
  }
  {  // Opened again, before any configuration is checked: the kind comes from the meta row.
    const StoredKeyframe blank = SessionStore(path, StoreAccess::kReadOnly).keyframeFeatures(s, 1);
    EXPECT_EQ(blank.descriptors.rows, 0);
    EXPECT_EQ(blank.descriptors.cols, 32);  // an export or merge reads an ORB store's blank as ORB's
    SessionStore writer(path);
    StoredKeyframe sift;
    sift.session = s;
    sift.keyframe = 2;
    sift.image_size = cv::Size(320, 240);
    sift.altitude_m = 2.0;
    sift.points.assign(3, cv::Point2f(5, 5));
    sift.descriptors = cv::Mat(3, 128, CV_8U, cv::Scalar(1));
    sift.hash = Eigen::VectorXf::Constant(HalocProjections::kHashSize, 0.01f);
    EXPECT_THROW(writer.addKeyframe(sift, nullptr, nullptr), StoreError);  // refused before any check
  }
  // A store written before the kind was recorded holds SIFT.
  ASSERT_TRUE(testing_util::execSql(path, "DELETE FROM meta WHERE key = 'features'"));
  SessionStore store(path);
  HashSettings h;
  ASSERT_TRUE(store.hashSettings(&h));
  EXPECT_EQ(h.features, FeatureType::kSift);
  EXPECT_THROW(store.checkHashSettings({HashMode::kSortedDct, 7, 500, "x", FeatureType::kOrb}), StoreError);
  EXPECT_NO_THROW(store.checkHashSettings({HashMode::kSortedDct, 7, 500, "x", FeatureType::kSift}));
  // SIFT bytes widen to the extractor's floats.
  const cv::Mat sift_bytes(2, 128, CV_8U, cv::Scalar(7));
  const cv::Mat widened = extractorDescriptors(sift_bytes);
  EXPECT_EQ(widened.type(), CV_32F);
  EXPECT_EQ(widened.at<float>(1, 127), 7.0f);
  EXPECT_EQ(extractorDescriptors(cv::Mat(0, 128, CV_8U)).cols, 128);
  EXPECT_THROW(descriptorType(cv::Mat(2, 64, CV_8U)), std::invalid_argument);
}

TEST_F(OrbTest, AnotherVehiclesOrbKeyframeMeetingOurSiftIsCountedNotCompared) {
  const SlamConfig config;
  LoopDetector d(config.loops, config.odometry.matching, config.odometry.ransac, 500);
  const FeatureExtractor sift(config.odometry.features), orb(orbOptions());
  Trajectory t;
  for (int k = 0; k < 3; ++k) {
    if (k > 0) t.append(UncertainPose2(Pose2(0.5, 0, 0), Eigen::Matrix3d::Identity() * 1e-4));
    d.addKeyframe(0, k, k, 2.0, &camera_, sift.extract(grey(Pose2(3 + 0.5 * k, 3, 0), 2.0)), t);
  }
  const FrameFeatures theirs = orb.extract(grey(Pose2(3.5, 3, 0), 2.0));  // the same place as keyframe 1
  d.setFeatureLoader([&](int, int) { return theirs; });
  const ImageHasher h(config.loops.global.hash_mode, 500, config.loops.global.projection_seed);
  std::vector<Loop> loops;
  ASSERT_NO_THROW(loops = d.addForeignKeyframe(5, 0, 0, 2.0, &camera_, h.hash(theirs.descriptors)));
  EXPECT_TRUE(loops.empty());
  EXPECT_EQ(d.stats().feature_read_failures, 3);  // each of our three keyframes a candidate, none compared
  EXPECT_NE(d.lastReadError().find("orb"), std::string::npos) << d.lastReadError();
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
