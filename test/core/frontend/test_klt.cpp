// Tracking between keyframes (KLT) and SIFT without the x2 upsampling, on frames rendered
// from the procedural seabed with a known motion.
#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include <cmath>

#include "../../common/rendered_seabed.h"
#include "uw_multislam/core/frontend/features.h"
#include "uw_multislam/core/frontend/klt_tracker.h"
#include "uw_multislam/core/frontend/odometry.h"

namespace uw_multislam {
namespace core {
namespace {

using KltTest = testing_util::RenderedSeabedTest;

OdometryOptions kltOn() {
  OdometryOptions o;
  o.klt.enabled = true;
  return o;
}

OdometryOptions siftOnly() {
  OdometryOptions o;
  o.klt.enabled = false;
  return o;
}

// A gentle lawnmower leg with a turn: 0.12 m steps, small yaw changes.
Pose2 missionPose(int k) {
  return Pose2(1.8 + 0.12 * k, 3.0 + 0.4 * std::sin(k * 0.15), 0.15 * std::sin(k * 0.2));
}

TEST_F(KltTest, MotionFromTracksMatchesTheGroundTruthWithoutExtraction) {
  const Pose2 p0(3.0, 3.0, 0.2);
  Odometry odo(camera_, kltOn());
  ASSERT_EQ(odo.process({0, 0.0, 2.0, render(p0, 2.0)}).status, FrameStatus::kFirstKeyframe);
  const Pose2 steps[] = {Pose2(3.08, 3.03, 0.22), Pose2(3.16, 3.05, 0.25), Pose2(3.25, 3.08, 0.27)};
  const double alts[] = {2.1, 2.2, 2.3};  // altitude changes: the metres need both altitudes
  for (int k = 0; k < 3; ++k) {
    const OdometryUpdate u = odo.process({k + 1, 1.0 + k, alts[k], render(steps[k], alts[k])});
    ASSERT_EQ(u.status, FrameStatus::kTracked) << u.reason;
    EXPECT_TRUE(u.klt);
    EXPECT_EQ(u.features, 0);  // no SIFT on this frame
    EXPECT_GE(u.tracks, 100);
    EXPECT_GE(u.inliers, 100);
    const Pose2 truth = between(p0, steps[k]);
    EXPECT_TRUE(approxEqual(u.pose, truth, 0.01, 0.005)) << "frame " << k + 1 << ": " << u.pose << " vs " << truth;
    EXPECT_NEAR(u.scale, 1.0, 0.02);
    EXPECT_GT(u.overlap, 0.5);
    EXPECT_TRUE(checkCovariance(u.covariance).empty()) << u.covariance;
    EXPECT_GT(u.covariance(0, 0), 0.0);
  }
  EXPECT_EQ(odo.stats().klt_tracked, 3);
  EXPECT_EQ(odo.stats().klt_extracted, 0);
  EXPECT_EQ(odo.times().get("features").calls, 1);  // the first keyframe only
}

TEST_F(KltTest, ADegradedTrackFallsBackToExtraction) {
  Odometry odo(camera_, kltOn());
  odo.process({0, 0.0, 2.0, render(Pose2(2.0, 2.0, 0.0), 2.0)});
  const OdometryUpdate tracked = odo.process({1, 1.0, 2.0, render(Pose2(2.1, 2.0, 0.0), 2.0)});
  ASSERT_TRUE(tracked.klt) << tracked.reason;
  // A blank frame: no track survives, the frame goes the full way (SIFT, matching, fallback).
  const OdometryUpdate blank = odo.process({2, 2.0, 2.0, cv::Mat(240, 320, CV_8UC3, cv::Scalar(90, 90, 90))});
  EXPECT_FALSE(blank.klt);
  EXPECT_EQ(odo.stats().klt_degraded, 1);
  // The tracked frame 1 (no features of its own) was promoted: its features were extracted then.
  EXPECT_EQ(odo.stats().promotions, 1);
  EXPECT_EQ(odo.keyframes()[1].frame_index, 1);
  EXPECT_EQ(odo.newKeyframes().front().features.size(), 500u);
  EXPECT_EQ(blank.status, FrameStatus::kFallback);
  // Seabed elsewhere: the tracks do not give the motion, the full way does not match either
  // (fallback keyframe, the reused motion: bridge_frames 0). No tracks start at a fallback keyframe
  // (on a blank frame they would sit on noise): the next frame goes the full way; tracks start again
  // at the next measured keyframe.
  OdometryOptions reuse = kltOn();
  reuse.fallback.bridge_frames = 0;
  Odometry far(camera_, reuse);
  far.process({0, 0.0, 2.0, render(Pose2(2.0, 2.0, 0.0), 2.0)});
  const OdometryUpdate elsewhere = far.process({1, 1.0, 2.0, render(Pose2(6.0, 4.5, 1.0), 2.0)});
  EXPECT_FALSE(elsewhere.klt);
  EXPECT_EQ(elsewhere.status, FrameStatus::kFallback);
  EXPECT_EQ(far.stats().klt_extracted, 1);
  const OdometryUpdate next = far.process({2, 2.0, 2.0, render(Pose2(6.05, 4.5, 1.0), 2.0)});
  EXPECT_FALSE(next.klt);
  EXPECT_EQ(next.status, FrameStatus::kTracked) << next.reason;
  bool measured_keyframe = false, klt_again = false;
  for (int k = 3; k < 15 && !klt_again; ++k) {
    const OdometryUpdate u = far.process({k, 1.0 * k, 2.0, render(Pose2(6.05 - 0.15 * (k - 2), 4.5, 1.0), 2.0)});
    ASSERT_NE(u.status, FrameStatus::kFallback) << "frame " << k << ": " << u.reason;
    if (measured_keyframe) klt_again = u.klt;
    measured_keyframe = measured_keyframe || u.status == FrameStatus::kKeyframe;
    if (!measured_keyframe) {
      EXPECT_FALSE(u.klt) << "frame " << k;
    }
  }
  EXPECT_TRUE(klt_again);
}

TEST_F(KltTest, TakesTheSameKeyframesAsExtractionOnAMission) {
  // The keyframe rule on KLT's motion: the same keyframes as SIFT on every frame, each within
  // one frame, and the trajectory within 1 % of the path.
  Odometry sift(camera_, siftOnly()), klt(camera_, kltOn());
  const int n = 60;
  for (int k = 0; k < n; ++k) {
    const cv::Mat img = render(missionPose(k), 2.0);
    ASSERT_NE(sift.process({k, 0.5 * k, 2.0, img}).status, FrameStatus::kSkipped);
    ASSERT_NE(klt.process({k, 0.5 * k, 2.0, img}).status, FrameStatus::kSkipped);
  }
  ASSERT_EQ(klt.keyframes().size(), sift.keyframes().size());
  for (std::size_t i = 0; i < sift.keyframes().size(); ++i) {
    EXPECT_LE(std::abs(klt.keyframes()[i].frame_index - sift.keyframes()[i].frame_index), 1) << "keyframe " << i;
  }
  EXPECT_EQ(klt.stats().fallbacks, 0);
  EXPECT_GT(klt.stats().klt_tracked, n / 2);
  EXPECT_LT(klt.times().get("features").calls, sift.times().get("features").calls / 2);
  const int last = klt.keyframes().back().frame_index;
  const Pose2 truth = between(missionPose(0), missionPose(last));
  const Pose2 end = klt.trajectory().absolutePoses().back();
  EXPECT_LT((end.translation() - truth.translation()).norm(), 0.01 * 0.12 * last + 0.01) << end << " vs " << truth;
}

TEST(Klt, BadOptionsAreRefusedByName) {
  KltOptions o;
  EXPECT_EQ(o.validate(), "");
  o.window_px = 20;
  EXPECT_NE(o.validate().find("window_px"), std::string::npos);
  EXPECT_THROW(KltTracker{o}, std::invalid_argument);
  OdometryOptions odo;
  odo.klt.min_tracks = 1;
  EXPECT_EQ(odo.validate().rfind("klt: min_tracks", 0), 0u) << odo.validate();
}

// Without the doubled octave SIFT finds about a fifth of the keypoints: a 320 x 240 frame of the
// test seabed has fewer than n = 500, a 640 x 480 one (the size the option is for) enough.
const CameraIntrinsics kVga{640, 480, 600.0, 600.0, 319.5, 239.5};

TEST_F(KltTest, SiftWithoutUpsamplingFindsTheSameMotion) {
  // first_octave 0 (OpenCV SIFT on the halved image, keypoints x2): the keypoints must be in the
  // full image's pixels, so the motion is the truth as with today's SIFT.
  const auto render = [](const Pose2& p, double alt) { return world().render(p, alt, kVga); };
  OdometryOptions o = siftOnly();
  o.features.first_octave = 0;
  o.keyframes.min_overlap = 0.99;
  const Pose2 p0(3.0, 3.0, 0.2), p1(3.45, 3.12, 0.32);
  Odometry odo(kVga, o);
  ASSERT_EQ(odo.process({0, 0.0, 2.0, render(p0, 2.0)}).status, FrameStatus::kFirstKeyframe);
  const OdometryUpdate u = odo.process({1, 1.0, 2.4, render(p1, 2.4)});
  ASSERT_EQ(u.status, FrameStatus::kKeyframe) << u.reason;
  EXPECT_EQ(u.features, 500);
  EXPECT_GT(u.inliers, 50);
  const Pose2 m = odo.trajectory().motion(1).mean;
  EXPECT_TRUE(approxEqual(m, between(p0, p1), 0.01, 0.005)) << m << " vs " << between(p0, p1);
  FeatureOptions bad;
  bad.first_octave = 1;
  EXPECT_NE(bad.validate().find("first_octave"), std::string::npos);
}

TEST_F(KltTest, SiftWithoutUpsamplingKeepsTheFeatureContract) {
  // n features, 128 CV_32F columns on OpenCV's scale (integers up to 255, what the loop store's
  // 8-bit copy and the hash expect), inside the border, the same keypoint sizes' order of magnitude.
  FeatureOptions up, flat;
  flat.first_octave = 0;
  const cv::Mat img = [&] {
    cv::Mat g;
    cv::cvtColor(world().render(Pose2(3.0, 3.0, 0.0), 2.0, kVga), g, cv::COLOR_BGR2GRAY);
    return g;
  }();
  const FrameFeatures a = FeatureExtractor(up).extract(img), b = FeatureExtractor(flat).extract(img);
  ASSERT_EQ(b.size(), 500u);
  EXPECT_EQ(b.descriptors.type(), CV_32F);
  EXPECT_EQ(b.descriptors.cols, 128);
  double lo, hi;
  cv::minMaxLoc(b.descriptors, &lo, &hi);
  EXPECT_GE(lo, 0.0);
  EXPECT_LE(hi, 255.0);
  EXPECT_GT(hi, 100.0);
  for (const auto& k : b.keypoints) {
    ASSERT_GE(k.pt.x, 8.0f);
    ASSERT_LE(k.pt.x, 640 - 9.0f);
    ASSERT_GE(k.pt.y, 8.0f);
    ASSERT_LE(k.pt.y, 480 - 9.0f);
  }
  // Many keypoints at the same places as today's (within 1 px): the coordinates are the full image's.
  int same = 0;
  for (const auto& k : b.keypoints) {
    for (const auto& l : a.keypoints) {
      if (cv::norm(k.pt - l.pt) < 1.0) {
        ++same;
        break;
      }
    }
  }
  EXPECT_GT(same, 100);
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
