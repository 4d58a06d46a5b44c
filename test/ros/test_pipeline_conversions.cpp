// Keyframe, Loop and KeyframeHash messages <-> core types (no master needed).
#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "../common/rendered_seabed.h"
#include "uw_multislam/core/frontend/features.h"
#include "uw_multislam/core/frontend/odometry.h"
#include "uw_multislam/core/loops/haloc.h"
#include "uw_multislam/ros/backend_conversions.h"
#include "uw_multislam/ros/pipeline_conversions.h"

namespace uw_multislam {
namespace {

using core::Pose2;
using core::UncertainPose2;
namespace rc = ros_conversions;

class PipelineConversions : public testing_util::RenderedSeabedTest {
 protected:
  rc::KeyframeData someKeyframe() const {
    const core::FeatureExtractor extractor{core::FeatureOptions()};
    cv::Mat grey;
    cv::cvtColor(render(Pose2(4.0, 3.0, 0.3), 2.0), grey, cv::COLOR_BGR2GRAY);
    rc::KeyframeData k;
    k.session = 2;
    k.keyframe = 7;
    k.frame_index = 31;
    k.altitude_m = 2.0;
    k.camera = camera_;
    k.features = extractor.extract(grey);
    Eigen::Matrix3d c;
    c << 4e-4, 1e-5, 2e-6, 1e-5, 9e-4, -3e-6, 2e-6, -3e-6, 1e-4;
    k.motion = UncertainPose2(Pose2(0.4, -0.1, 0.05), c);
    k.odometry_pose = Pose2(3.0, 1.0, -2.0);
    k.quality = rc::KeyframeQuality::kMatched;
    k.matches = 300;
    k.inliers = 250;
    k.overlap = 0.45;
    k.scale = 1.01;
    return k;
  }
  static std_msgs::Header header() {
    std_msgs::Header h;
    h.stamp = ros::Time(1700000123, 456);
    h.frame_id = "camera";
    return h;
  }
};

TEST_F(PipelineConversions, KeyframeRoundTripIsLossless) {
  const rc::KeyframeData k = someKeyframe();
  ASSERT_GT(k.features.size(), 300u);
  const uw_multislam::Keyframe m = rc::toKeyframeMsg(k, header());
  EXPECT_EQ(m.header.stamp, header().stamp);
  EXPECT_EQ(m.session, 2);
  EXPECT_EQ(m.keyframe, 7);
  EXPECT_EQ(m.frame_index, 31);
  EXPECT_EQ(m.status, uw_multislam::Keyframe::MATCHED);
  EXPECT_EQ(m.descriptor_size, 128u);
  EXPECT_EQ(m.descriptors.size(), k.features.size() * 128);
  EXPECT_DOUBLE_EQ(m.motion_covariance[1], 1e-5);   // row-major (x, y)
  EXPECT_DOUBLE_EQ(m.motion_covariance[7], -3e-6);  // (yaw, y)

  rc::KeyframeData back;
  std::string why;
  ASSERT_TRUE(rc::fromMsg(m, &back, &why)) << why;
  EXPECT_EQ(back.session, 2);
  EXPECT_EQ(back.keyframe, 7);
  EXPECT_EQ(back.frame_index, 31);
  EXPECT_EQ(back.quality, rc::KeyframeQuality::kMatched);
  EXPECT_EQ(back.inliers, 250);
  EXPECT_DOUBLE_EQ(back.camera.fx, camera_.fx);
  EXPECT_EQ(back.features.image_size, cv::Size(camera_.width, camera_.height));
  ASSERT_EQ(back.features.size(), k.features.size());
  for (std::size_t i = 0; i < k.features.size(); ++i) {
    EXPECT_EQ(back.features.keypoints[i].pt, k.features.keypoints[i].pt);
  }
  // SIFT's descriptor values are integers in 0..255: 8 bits lose nothing.
  ASSERT_EQ(back.features.descriptors.type(), CV_32F);
  EXPECT_EQ(cv::norm(back.features.descriptors, k.features.descriptors, cv::NORM_INF), 0.0);
  EXPECT_TRUE(back.motion.covariance.isApprox(k.motion.covariance));
  EXPECT_TRUE(core::approxEqual(back.motion.mean, k.motion.mean, 1e-12, 1e-12));
  EXPECT_TRUE(core::approxEqual(back.odometry_pose, k.odometry_pose, 1e-12, 1e-12));

  // The loop detector's hash of the received features is the sender's.
  const core::ImageHasher hasher(core::HashMode::kSortedDct, 500, 20231122);
  EXPECT_LT((hasher.hash(back.features.descriptors) - hasher.hash(k.features.descriptors)).cwiseAbs().maxCoeff(), 1e-6);
}

TEST_F(PipelineConversions, TheNavPlacementTravelsWithKeyframeZeroAndABadOneIsRefused) {
  rc::KeyframeData k = someKeyframe();
  // None: -1 ids and a zero covariance; what an older sender leaves (all zero) is none too.
  uw_multislam::Keyframe m = rc::toKeyframeMsg(k, header());
  EXPECT_EQ(m.placement_session, -1);
  EXPECT_EQ(m.placement_keyframe, -1);
  rc::KeyframeData back;
  std::string why;
  ASSERT_TRUE(rc::fromMsg(m, &back, &why)) << why;
  EXPECT_FALSE(back.nav_placement.has_value());
  m.placement_session = m.placement_keyframe = 0;
  ASSERT_TRUE(rc::fromMsg(m, &back, &why)) << why;
  EXPECT_FALSE(back.nav_placement.has_value());
  // Given: session, keyframe, pose and covariance as sent, and on into the back-end's input.
  Eigen::Matrix3d c;
  c << 0.04, 0.001, 0.0, 0.001, 0.05, 0.0, 0.0, 0.0, 1e-4;
  k.nav_placement = core::NavPlacementInput{1, 12, UncertainPose2(Pose2(2.5, -0.75, 3.0), c)};
  m = rc::toKeyframeMsg(k, header());
  EXPECT_EQ(m.placement_session, 1);
  EXPECT_EQ(m.placement_keyframe, 12);
  EXPECT_DOUBLE_EQ(m.placement_covariance[4], 0.05);
  ASSERT_TRUE(rc::fromMsg(m, &back, &why)) << why;
  ASSERT_TRUE(back.nav_placement.has_value());
  EXPECT_EQ(back.nav_placement->session, 1);
  EXPECT_EQ(back.nav_placement->keyframe, 12);
  EXPECT_TRUE(core::approxEqual(back.nav_placement->z.mean, Pose2(2.5, -0.75, 3.0), 1e-12, 1e-12));
  EXPECT_TRUE(back.nav_placement->z.covariance.isApprox(c));
  const core::KeyframeInput in = rc::toKeyframeInput(back, 1.0);
  ASSERT_TRUE(in.nav_placement.has_value());
  EXPECT_EQ(in.nav_placement->keyframe, 12);
  EXPECT_FALSE(in.nav_placement->visual);
  // A visual bridge stays one across the message (stored as a loop, not a nav placement).
  k.nav_placement->visual = true;
  m = rc::toKeyframeMsg(k, header());
  EXPECT_TRUE(m.placement_visual);
  ASSERT_TRUE(rc::fromMsg(m, &back, &why)) << why;
  ASSERT_TRUE(back.nav_placement.has_value());
  EXPECT_TRUE(back.nav_placement->visual);
  // Refused, naming what: no keyframe named, a covariance not positive definite, a non-finite pose.
  uw_multislam::Keyframe bad = m;
  bad.placement_keyframe = -1;
  EXPECT_FALSE(rc::fromMsg(bad, &back, &why));
  EXPECT_NE(why.find("placement names no keyframe"), std::string::npos) << why;
  bad = m;
  bad.placement_covariance[8] = -1.0;
  EXPECT_FALSE(rc::fromMsg(bad, &back, &why));
  EXPECT_NE(why.find("placement covariance"), std::string::npos) << why;
  bad = m;
  bad.placement.x = std::nan("");
  EXPECT_FALSE(rc::fromMsg(bad, &back, &why));
  EXPECT_NE(why.find("non-finite placement"), std::string::npos) << why;
}

TEST_F(PipelineConversions, AnOrbKeyframeTravelsAsItsBitsAndOwnsThemOnArrival) {
  rc::KeyframeData k = someKeyframe();
  core::FeatureOptions orb;
  orb.type = core::FeatureType::kOrb;
  cv::Mat grey;
  cv::cvtColor(render(Pose2(4.0, 3.0, 0.3), 2.0), grey, cv::COLOR_BGR2GRAY);
  k.features = core::FeatureExtractor(orb).extract(grey);
  ASSERT_GT(k.features.size(), 300u);
  uw_multislam::Keyframe m = rc::toKeyframeMsg(k, header());
  EXPECT_EQ(m.descriptor_size, 32u);
  EXPECT_EQ(m.descriptors.size(), k.features.size() * 32);
  rc::KeyframeData back;
  std::string why;
  ASSERT_TRUE(rc::fromMsg(m, &back, &why)) << why;
  ASSERT_EQ(back.features.descriptors.type(), CV_8U);
  ASSERT_EQ(back.features.descriptors.cols, 32);
  std::fill(m.descriptors.begin(), m.descriptors.end(), 0);  // the message's bytes are not the keyframe's
  EXPECT_EQ(cv::norm(back.features.descriptors, k.features.descriptors, cv::NORM_HAMMING), 0.0);
  // No feature: the kind still travels.
  k.features.keypoints.clear();
  k.features.descriptors = cv::Mat(0, 32, CV_8U);
  m = rc::toKeyframeMsg(k, header());
  EXPECT_EQ(m.descriptor_size, 32u);
  ASSERT_TRUE(rc::fromMsg(m, &back, &why)) << why;
  EXPECT_EQ(back.features.descriptors.cols, 32);
  EXPECT_EQ(back.features.descriptors.type(), CV_8U);
}

TEST_F(PipelineConversions, BadKeyframeMessagesAreRefusedWithAReason) {
  const uw_multislam::Keyframe good = rc::toKeyframeMsg(someKeyframe(), header());
  rc::KeyframeData out;
  std::string why;
  auto refused = [&](uw_multislam::Keyframe m, const std::string& expected) {
    why.clear();
    EXPECT_FALSE(rc::fromMsg(m, &out, &why)) << expected;
    EXPECT_NE(why.find(expected), std::string::npos) << "reason: " << why;
  };
  auto m = good;
  m.v_px.pop_back();
  refused(m, "same length");
  m = good;
  m.descriptors.resize(m.descriptors.size() - 1);
  refused(m, "descriptors");
  m = good;
  m.descriptor_size = 64;
  refused(m, "descriptor_size");
  m = good;
  m.fx = 0.0;
  refused(m, "camera");
  m = good;
  m.altitude_m = std::numeric_limits<double>::quiet_NaN();
  refused(m, "altitude");
  m = good;
  m.motion_covariance[0] = -1.0;
  refused(m, "covariance");
  m = good;
  m.status = 9;
  refused(m, "status");
  m = good;
  m.u_px[3] = std::numeric_limits<float>::infinity();
  refused(m, "feature position");
  m = good;
  m.keyframe = -1;
  refused(m, "negative");
  m = good;
  m.session = std::numeric_limits<int>::max();  // would make the session ids wrap
  refused(m, "session id past the largest, 1000000");
  m.session = 1000001;
  refused(m, "session id past the largest");
  m.session = 1000000;
  EXPECT_TRUE(rc::fromMsg(m, &out, &why)) << why;
  m = good;
  m.hash.assign(core::HalocProjections::kHashSize - 1, 0.1f);
  refused(m, "hash must have 384 values");
  m.hash.assign(core::HalocProjections::kHashSize + 1, 0.1f);
  refused(m, "hash must have 384 values");
  m.hash.assign(core::HalocProjections::kHashSize, 0.1f);
  m.hash[17] = std::numeric_limits<float>::quiet_NaN();
  refused(m, "non-finite hash");
  EXPECT_TRUE(rc::fromMsg(good, &out, &why)) << why;
}

TEST_F(PipelineConversions, UnloadSessionNoticeIsKeyframeMinusOneWithoutFeaturesAndNoKeyframeIsOne) {
  const uw_multislam::Keyframe notice = rc::unloadSessionMsg(7);
  EXPECT_TRUE(rc::isUnloadSessionMsg(notice));
  EXPECT_EQ(notice.session, 7);
  rc::KeyframeData out;
  std::string why;
  EXPECT_FALSE(rc::fromMsg(notice, &out, &why)) << "a notice is no keyframe";
  uw_multislam::Keyframe k = rc::toKeyframeMsg(someKeyframe(), header());
  EXPECT_FALSE(rc::isUnloadSessionMsg(k));
  k.keyframe = -1;  // a corrupt keyframe with features is not taken for a notice
  EXPECT_FALSE(rc::isUnloadSessionMsg(k));
}

TEST_F(PipelineConversions, KeyframeHashTravelsWithTheKeyframe) {
  rc::KeyframeData k = someKeyframe();
  const core::ImageHasher hasher(core::HashMode::kSortedDct, 500, 20231122);
  k.hash = hasher.hash(k.features.descriptors);
  ASSERT_EQ(k.hash.size(), core::HalocProjections::kHashSize);
  const uw_multislam::Keyframe m = rc::toKeyframeMsg(k, header());
  ASSERT_EQ(m.hash.size(), static_cast<std::size_t>(core::HalocProjections::kHashSize));
  EXPECT_EQ(m.hash[100], k.hash[100]);
  rc::KeyframeData back;
  std::string why;
  ASSERT_TRUE(rc::fromMsg(m, &back, &why)) << why;
  ASSERT_EQ(back.hash.size(), core::HalocProjections::kHashSize);
  EXPECT_EQ((back.hash - k.hash).cwiseAbs().maxCoeff(), 0.0f);  // float32 both ways: exact

  // A sender that does not hash (an older one): no hash, accepted.
  k.hash.resize(0);
  const uw_multislam::Keyframe old = rc::toKeyframeMsg(k, header());
  EXPECT_TRUE(old.hash.empty());
  ASSERT_TRUE(rc::fromMsg(old, &back, &why)) << why;
  EXPECT_EQ(back.hash.size(), 0);
}

// Hash exchange between vehicles: a keyframe crosses as its hash, motion,
// pose, camera and altitude, without features or image, and comes back out checked as a Keyframe.
TEST_F(PipelineConversions, AFleetHashCarriesTheKeyframeWithoutItsFeaturesAndIsCheckedAsOne) {
  rc::KeyframeData k = someKeyframe();
  const core::ImageHasher hasher(core::HashMode::kSortedDct, 500, 77);
  k.hash = hasher.hash(k.features.descriptors);
  k.thumbnail = {1, 2, 3};
  const uw_multislam::KeyframeHash m =
      rc::toFleetHashMsg(k, "auv_b", core::HashMode::kSortedDct, 77, 500, core::FeatureType::kSift, header());
  EXPECT_EQ(m.vehicle, "auv_b");
  EXPECT_FALSE(m.session_ended);
  EXPECT_EQ(m.values.size(), 384u);
  EXPECT_EQ(m.projection_seed, 77u);
  EXPECT_EQ(m.num_features, 500);
  // Under 1.8 kB on the wire (1536 of them the hash) against the keyframe's tens of kB.
  const std::uint32_t bytes = ros::serialization::serializationLength(m);
  const std::uint32_t full = ros::serialization::serializationLength(rc::toKeyframeMsg(k, header()));
  EXPECT_LT(bytes, 1800u);
  EXPECT_GT(full, 20u * bytes);

  rc::KeyframeData back;
  rc::KeyframeHashData settings;
  std::string why;
  ASSERT_TRUE(rc::fromFleetHashMsg(m, &back, &settings, &why)) << why;
  EXPECT_EQ(settings.projection_seed, 77u);
  EXPECT_EQ(settings.mode, core::HashMode::kSortedDct);
  EXPECT_EQ(back.session, 2);
  EXPECT_EQ(back.keyframe, 7);
  EXPECT_EQ(back.frame_index, 31);
  EXPECT_DOUBLE_EQ(back.altitude_m, 2.0);
  EXPECT_DOUBLE_EQ(back.camera.cx, camera_.cx);
  EXPECT_EQ(back.camera.height, camera_.height);
  EXPECT_TRUE(back.features.keypoints.empty());
  EXPECT_TRUE(back.thumbnail.empty());
  EXPECT_TRUE(back.hash.isApprox(k.hash));
  EXPECT_DOUBLE_EQ(back.motion.mean.y(), -0.1);
  EXPECT_DOUBLE_EQ(back.motion.covariance(1, 2), -3e-6);
  EXPECT_DOUBLE_EQ(back.odometry_pose.yaw(), -2.0);

  // Refused with the reason: a notice, a broken motion, a short hash, a missing camera.
  EXPECT_FALSE(rc::fromFleetHashMsg(rc::fleetSessionEndedMsg("auv_b", 2, ros::Time(5)), &back, &settings, &why));
  uw_multislam::KeyframeHash bad = m;
  bad.motion_covariance[0] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(rc::fromFleetHashMsg(bad, &back, &settings, &why));
  EXPECT_NE(why.find("covariance"), std::string::npos) << why;
  bad = m;
  bad.values.resize(100);
  EXPECT_FALSE(rc::fromFleetHashMsg(bad, &back, &settings, &why));
  bad = m;
  bad.fx = 0;
  EXPECT_FALSE(rc::fromFleetHashMsg(bad, &back, &settings, &why));
  EXPECT_NE(why.find("camera"), std::string::npos) << why;
  const uw_multislam::KeyframeHash ended = rc::fleetSessionEndedMsg("auv_b", 2, ros::Time(5));
  EXPECT_TRUE(ended.session_ended);
  EXPECT_EQ(ended.keyframe, -1);
  EXPECT_TRUE(ended.values.empty());

  // As 8-bit codes (~fleet/hash_codes): a third of the bytes, and a hash the loop detector's
  // store cannot tell from the original.
  const uw_multislam::KeyframeHash c =
      rc::toFleetHashMsg(k, "auv_b", core::HashMode::kSortedDct, 77, 500, core::FeatureType::kSift, header(), true);
  EXPECT_TRUE(c.values.empty());
  EXPECT_EQ(c.codes.size(), 384u);
  EXPECT_FLOAT_EQ(c.code_range, core::hashCodeRange(core::HashMode::kSortedDct));
  const std::uint32_t code_bytes = ros::serialization::serializationLength(c);
  EXPECT_EQ(code_bytes, bytes - 1536 + 384);  // the values' 1536 bytes become 384
  ASSERT_TRUE(rc::fromFleetHashMsg(c, &back, &settings, &why)) << why;
  const core::HashStore store(c.code_range);
  EXPECT_FLOAT_EQ(store.distance(back.hash, k.hash), 0.0f);
  EXPECT_DOUBLE_EQ(back.motion.mean.x(), 0.4);
  bad = c;
  bad.codes.resize(383);
  EXPECT_FALSE(rc::fromFleetHashMsg(bad, &back, &settings, &why));
  bad = c;
  bad.code_range = 0;
  EXPECT_FALSE(rc::fromFleetHashMsg(bad, &back, &settings, &why));
  EXPECT_NE(why.find("code_range"), std::string::npos) << why;
}

TEST_F(PipelineConversions, KeyframeThumbnailTravelsWithTheKeyframeAndIsBounded) {
  rc::KeyframeData k = someKeyframe();
  k.thumbnail = {0xff, 0xd8, 0xff, 0x01, 0x02, 0xff, 0xd9};
  uw_multislam::Keyframe m = rc::toKeyframeMsg(k, header());
  EXPECT_EQ(m.thumbnail, k.thumbnail);
  rc::KeyframeData back;
  std::string why;
  ASSERT_TRUE(rc::fromMsg(m, &back, &why)) << why;
  EXPECT_EQ(back.thumbnail, k.thumbnail);
  EXPECT_EQ(rc::toKeyframeInput(back, 1.0).thumbnail, k.thumbnail);  // on to the store and the live mosaic
  m.thumbnail.assign((4u << 20) + 1, 0);
  EXPECT_FALSE(rc::fromMsg(m, &back, &why));
  EXPECT_NE(why.find("more than 4 MB"), std::string::npos) << why;
  m.thumbnail.clear();  // an older sender, or a promoted keyframe: none
  ASSERT_TRUE(rc::fromMsg(m, &back, &why)) << why;
  EXPECT_TRUE(back.thumbnail.empty());
}

TEST_F(PipelineConversions, KeyframeDataFromARunningOdometry) {
  core::Odometry odometry(camera_, core::OdometryOptions());
  core::OdometryUpdate u = odometry.process({0, 0.0, 2.0, render(Pose2(4.0, 3.0, 0.0), 2.0)});
  ASSERT_EQ(odometry.newKeyframes().size(), 1u);
  rc::KeyframeData first = rc::keyframeData(core::streamKeyframe(odometry, odometry.newKeyframes()[0], 3, nullptr));
  EXPECT_EQ(first.session, 3);
  EXPECT_EQ(first.keyframe, 0);
  EXPECT_EQ(first.quality, rc::KeyframeQuality::kFirst);
  EXPECT_TRUE(first.motion.covariance.isZero());
  EXPECT_EQ(rc::toKeyframeMsg(first, header()).status, uw_multislam::Keyframe::FIRST);

  // Far enough for the overlap rule: the second frame is a matched keyframe.
  u = odometry.process({1, 1.0, 2.0, render(Pose2(5.3, 3.0, 0.0), 2.0)});
  ASSERT_EQ(odometry.newKeyframes().size(), 1u) << core::statusName(u.status) << " " << u.reason;
  const rc::KeyframeData second =
      rc::keyframeData(core::streamKeyframe(odometry, odometry.newKeyframes()[0], 3, nullptr));
  EXPECT_EQ(second.keyframe, 1);
  EXPECT_EQ(second.frame_index, 1);
  EXPECT_EQ(second.quality, rc::KeyframeQuality::kMatched);
  EXPECT_EQ(second.inliers, u.inliers);
  EXPECT_GT(second.inliers, 20);
  EXPECT_NEAR(second.motion.mean.x(), 1.3, 0.05);
  EXPECT_GT(second.motion.covariance(0, 0), 0.0);
  EXPECT_TRUE(core::approxEqual(second.odometry_pose, odometry.trajectory().absolutePose(1)));
}

TEST_F(PipelineConversions, APromotedKeyframeCarriesItsOwnMatchFromWhenItWasTracked) {
  // Frame 1 is tracked (0.9 m on, over half the 2.1 m footprint still shared with keyframe 0);
  // frame 2 (2.3 m on) shares nothing with keyframe 0, so frame 1 is promoted and frame 2 matched
  // to it. The promoted keyframe's message reported 0 matches and inliers before.
  core::Odometry odometry(camera_, core::OdometryOptions());
  odometry.process({0, 0.0, 2.0, render(Pose2(4.0, 3.0, 0.0), 2.0)});
  const core::OdometryUpdate tracked = odometry.process({1, 1.0, 2.0, render(Pose2(4.9, 3.0, 0.0), 2.0)});
  ASSERT_EQ(tracked.status, core::FrameStatus::kTracked) << tracked.reason;
  ASSERT_GT(tracked.inliers, 20);
  const core::OdometryUpdate u = odometry.process({2, 2.0, 2.0, render(Pose2(6.3, 3.0, 0.0), 2.0)});
  ASSERT_EQ(odometry.stats().promotions, 1) << core::statusName(u.status) << " " << u.reason;
  ASSERT_EQ(odometry.newKeyframes().size(), 2u);
  const rc::KeyframeData promoted =
      rc::keyframeData(core::streamKeyframe(odometry, odometry.newKeyframes()[0], 0, nullptr));
  EXPECT_EQ(promoted.frame_index, 1);
  EXPECT_EQ(promoted.quality, rc::KeyframeQuality::kMatched);
  EXPECT_EQ(promoted.matches, tracked.matches);
  EXPECT_EQ(promoted.inliers, tracked.inliers);
  EXPECT_DOUBLE_EQ(promoted.overlap, tracked.overlap);
  EXPECT_DOUBLE_EQ(promoted.scale, tracked.scale);
  const rc::KeyframeData current =
      rc::keyframeData(core::streamKeyframe(odometry, odometry.newKeyframes()[1], 0, nullptr));
  EXPECT_EQ(current.frame_index, 2);
  EXPECT_EQ(current.inliers, u.inliers);
  EXPECT_EQ(odometry.keyframes().at(2).match.inliers, u.inliers);  // the core keeps it too
  EXPECT_EQ(odometry.keyframes().at(1).match.inliers, tracked.inliers);
}

TEST(PipelineConversionsLoop, RoundTripAndRefusals) {
  core::Loop l;
  l.kind = core::Loop::Kind::kGlobal;
  l.session_a = 0;
  l.keyframe_a = 12;
  l.frame_a = 40;
  l.session_b = 1;
  l.keyframe_b = 3;
  l.frame_b = 9;
  Eigen::Matrix3d c = Eigen::Matrix3d::Identity() * 1e-3;
  c(0, 2) = c(2, 0) = 2e-4;
  l.z = UncertainPose2(Pose2(0.2, -0.3, 1.0), c);
  l.inliers = 77;
  l.hash_l1 = 12.5f;
  std_msgs::Header h;
  h.stamp = ros::Time(5, 0);
  const uw_multislam::Loop m = rc::toLoopMsg(l, h);
  EXPECT_EQ(m.kind, uw_multislam::Loop::GLOBAL);
  EXPECT_DOUBLE_EQ(m.covariance[2], 2e-4);
  EXPECT_DOUBLE_EQ(m.pose.theta, 1.0);
  core::Loop back;
  ASSERT_TRUE(rc::fromMsg(m, &back));
  EXPECT_EQ(back.kind, core::Loop::Kind::kGlobal);
  EXPECT_EQ(back.keyframe_a, 12);
  EXPECT_EQ(back.frame_b, 9);
  EXPECT_EQ(back.inliers, 77);
  EXPECT_FLOAT_EQ(back.hash_l1, 12.5f);
  EXPECT_TRUE(back.z.covariance.isApprox(c));
  EXPECT_TRUE(core::approxEqual(back.z.mean, l.z.mean));

  l.kind = core::Loop::Kind::kLocal;
  EXPECT_EQ(rc::toLoopMsg(l, h).kind, uw_multislam::Loop::LOCAL);

  std::string why;
  auto bad = m;
  bad.kind = 5;
  EXPECT_FALSE(rc::fromMsg(bad, &back, &why));
  EXPECT_NE(why.find("kind"), std::string::npos);
  bad = m;
  bad.covariance[1] = 0.5;  // not symmetric
  EXPECT_FALSE(rc::fromMsg(bad, &back, &why));
  EXPECT_NE(why.find("covariance"), std::string::npos);
  bad = m;
  bad.pose.x = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(rc::fromMsg(bad, &back, &why));
  for (int session : {std::numeric_limits<int>::max(), 1000001}) {
    bad = m;
    bad.session_b = session;
    why.clear();
    EXPECT_FALSE(rc::fromMsg(bad, &back, &why)) << session;
    EXPECT_NE(why.find("past the largest"), std::string::npos) << why;
  }
}

TEST(PipelineConversionsHash, RoundTripAndRefusals) {
  rc::KeyframeHashData h;
  h.session = 1;
  h.keyframe = 4;
  h.frame_index = 17;
  h.mode = core::HashMode::kHaloc;
  h.projection_seed = 0xFFFFFFFFFFull + 3;  // needs the 64 bits
  h.num_features = 500;
  h.values = Eigen::VectorXf::LinSpaced(core::HalocProjections::kHashSize, -0.3f, 0.3f);
  const uw_multislam::KeyframeHash m = rc::toKeyframeHashMsg(h, std_msgs::Header());
  EXPECT_EQ(m.hash_mode, uw_multislam::KeyframeHash::HALOC);
  EXPECT_EQ(m.values.size(), 384u);
  rc::KeyframeHashData back;
  ASSERT_TRUE(rc::fromMsg(m, &back));
  EXPECT_EQ(back.mode, core::HashMode::kHaloc);
  EXPECT_EQ(back.projection_seed, h.projection_seed);
  EXPECT_EQ(back.frame_index, 17);
  EXPECT_EQ(back.values, h.values);
  EXPECT_EQ(m.features, "sift");
  EXPECT_EQ(back.features, core::FeatureType::kSift);
  // The descriptors' kind travels: ORB's hashes are not comparable with SIFT's.
  h.features = core::FeatureType::kOrb;
  ASSERT_TRUE(rc::fromMsg(rc::toKeyframeHashMsg(h, std_msgs::Header()), &back));
  EXPECT_EQ(back.features, core::FeatureType::kOrb);
  h.features = core::FeatureType::kSift;
  auto older = m;  // a sender from before the field: SIFT
  older.features.clear();
  ASSERT_TRUE(rc::fromMsg(older, &back));
  EXPECT_EQ(back.features, core::FeatureType::kSift);
  older.features = "akaze";
  std::string unknown;
  EXPECT_FALSE(rc::fromMsg(older, &back, &unknown));
  EXPECT_NE(unknown.find("unknown features 'akaze'"), std::string::npos) << unknown;
  h.mode = core::HashMode::kSortedDct;
  EXPECT_EQ(rc::toKeyframeHashMsg(h, std_msgs::Header()).hash_mode, uw_multislam::KeyframeHash::SORTED_DCT);

  std::string why;
  auto bad = m;
  bad.values.pop_back();
  EXPECT_FALSE(rc::fromMsg(bad, &back, &why));
  EXPECT_NE(why.find("384"), std::string::npos);
  bad = m;
  bad.hash_mode = 7;
  EXPECT_FALSE(rc::fromMsg(bad, &back, &why));
  bad = m;
  bad.values[0] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_FALSE(rc::fromMsg(bad, &back, &why));
}

}  // namespace
}  // namespace uw_multislam
