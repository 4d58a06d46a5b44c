// Feature odometry: the rigid fit, RANSAC with outliers, the covariance model, altitude scale,
// matching, and the odometry on rendered seabed frames with known motion.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include <Eigen/Dense>
#include <opencv2/imgproc.hpp>

#include <random>

#include "../../common/rendered_seabed.h"
#include "uw_multislam/core/backend/loop_consistency.h"
#include "uw_multislam/core/frontend/features.h"
#include "uw_multislam/core/frontend/matching.h"
#include "uw_multislam/core/frontend/odometry.h"
#include "uw_multislam/core/frontend/rigid_ransac.h"
#include "uw_multislam/sim/seabed_world.h"

namespace uw_multislam {
namespace core {
namespace {

// Points b in frame B and their images a = T ⊕ b + noise in frame A; the first
// `outliers` fraction replaced by random points.
struct Synthetic {
  std::vector<Eigen::Vector2d> a, b;
};
Synthetic makeCorrespondences(const Pose2& t, int n, double noise_m, double outlier_fraction, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::normal_distribution<double> g(0.0, noise_m);
  Synthetic s;
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector2d b(u(rng), 0.75 * u(rng));
    Eigen::Vector2d a = transformPoint(t, b) + Eigen::Vector2d(g(rng), g(rng));
    if (i < outlier_fraction * n) a = Eigen::Vector2d(2 * u(rng), 2 * u(rng));
    s.a.push_back(a);
    s.b.push_back(b);
  }
  return s;
}

TEST(RigidFit, ExactOnNoiseFreePoints) {
  const Pose2 t(0.3, -0.2, 0.7);
  const Synthetic s = makeCorrespondences(t, 10, 0.0, 0.0, 1);
  Pose2 fit;
  ASSERT_TRUE(fitRigid2D(s.a, s.b, {}, &fit));
  EXPECT_TRUE(approxEqual(fit, t, 1e-12, 1e-12)) << fit;
  EXPECT_FALSE(fitRigid2D(s.a, s.b, {3}, &fit));                           // one point
  EXPECT_FALSE(fitRigid2D({s.a[0], s.a[0]}, {s.b[0], s.b[0]}, {}, &fit));  // coincident points
}

TEST(Ransac, APriorGatesTheHypothesesAwayFromAStrongerWrongConsensus) {
  // Two consistent groups, as a repetitive seabed gives: 120 correspondences moving by `wrong`,
  // 80 by `truth`. Alone RANSAC takes the larger group; a nav prior near the truth (1 cm, 10 mrad)
  // gates the wrong hypotheses away and the truth wins. A prior that knows nothing changes nothing.
  const double mpp = 0.005;
  const Pose2 truth(0.30, 0.02, 0.05), wrong(0.05, -0.20, -0.10);
  Synthetic s = makeCorrespondences(wrong, 120, 0.3 * mpp, 0.0, 21);
  const Synthetic t = makeCorrespondences(truth, 80, 0.3 * mpp, 0.0, 22);
  s.a.insert(s.a.end(), t.a.begin(), t.a.end());
  s.b.insert(s.b.end(), t.b.begin(), t.b.end());
  RansacOptions o;
  o.estimate_scale = false;
  const RansacResult alone = estimateRigidRansac(s.a, s.b, mpp, o);
  ASSERT_TRUE(alone.success);
  EXPECT_TRUE(approxEqual(alone.motion, wrong, 2e-3, 2e-3)) << alone.motion;
  EXPECT_EQ(alone.hypotheses_gated, 0);
  const MotionPrior nav{Pose2(0.31, 0.01, 0.06), Eigen::Vector3d(1e-4, 1e-4, 1e-4).asDiagonal(),
                        chiSquare3Quantile(0.999)};
  const RansacResult gated = estimateRigidRansac(s.a, s.b, mpp, o, &nav);
  ASSERT_TRUE(gated.success) << gated.failure;
  EXPECT_TRUE(approxEqual(gated.motion, truth, 2e-3, 2e-3)) << gated.motion;
  EXPECT_GT(gated.hypotheses_gated, 0);
  for (int i : gated.inliers) EXPECT_GE(i, 120);
  const MotionPrior vague{Pose2(), Eigen::Matrix3d::Identity() * 1e6, chiSquare3Quantile(0.999)};
  const RansacResult same = estimateRigidRansac(s.a, s.b, mpp, o, &vague);
  EXPECT_EQ(same.inliers, alone.inliers);
  EXPECT_EQ(same.hypotheses_gated, 0);
}

TEST(Ransac, RecoversKnownMotionWithHalfOutliers) {
  const Pose2 t(0.12, 0.05, -0.3);
  const double mpp = 0.005;  // 5 mm per pixel
  const Synthetic s = makeCorrespondences(t, 200, 0.5 * mpp, 0.5, 2);
  RansacOptions o;
  const RansacResult r = estimateRigidRansac(s.a, s.b, mpp, o);
  ASSERT_TRUE(r.success) << r.failure;
  EXPECT_TRUE(approxEqual(r.motion, t, 1e-3, 1e-3)) << r.motion;
  // Every inlier is a true correspondence (index >= 100), and most true ones are found.
  for (int i : r.inliers) EXPECT_GE(i, 100);
  EXPECT_GT(r.inliers.size(), 95u);
  // The covariance is consistent with the actual error (within 4 sigma per component).
  const Eigen::Vector3d e = poseError(r.motion, t);
  for (int k = 0; k < 3; ++k) EXPECT_LT(std::abs(e[k]), 4 * std::sqrt(r.covariance(k, k)));
}

TEST(Ransac, IsDeterministicForASeed) {
  const Synthetic s = makeCorrespondences(Pose2(0.1, 0.1, 0.2), 100, 0.002, 0.4, 3);
  const RansacResult r1 = estimateRigidRansac(s.a, s.b, 0.005, RansacOptions());
  const RansacResult r2 = estimateRigidRansac(s.a, s.b, 0.005, RansacOptions());
  EXPECT_EQ(r1.inliers, r2.inliers);
  EXPECT_EQ(r1.motion.vector(), r2.motion.vector());
}

TEST(Ransac, FailsCleanlyOnNoConsensus) {
  // Pure outliers (unrelated points) and too few correspondences.
  const Synthetic s = makeCorrespondences(Pose2(), 100, 0.0, 1.0, 4);
  const RansacResult r = estimateRigidRansac(s.a, s.b, 0.005, RansacOptions());
  EXPECT_FALSE(r.success);
  EXPECT_NE(r.failure.find("inliers"), std::string::npos) << r.failure;
  const RansacResult few =
      estimateRigidRansac({s.a.begin(), s.a.begin() + 5}, {s.b.begin(), s.b.begin() + 5}, 0.005, RansacOptions());
  EXPECT_FALSE(few.success);
  EXPECT_NE(few.failure.find("only 5"), std::string::npos) << few.failure;
}

TEST(Ransac, CovarianceGrowsWhenMatchQualityDrops) {
  const Pose2 t(0.1, -0.05, 0.1);
  const double mpp = 0.005;
  RansacOptions o;
  o.inlier_threshold_px = 6.0;
  double prev_trace = 0.0;
  for (double noise_px : {0.5, 1.0, 2.0}) {
    const Synthetic s = makeCorrespondences(t, 150, noise_px * mpp, 0.2, 5);
    const RansacResult r = estimateRigidRansac(s.a, s.b, mpp, o);
    ASSERT_TRUE(r.success) << noise_px;
    // What the noise implies, computed here from the true motion and the true points (the last
    // 80 %): sigma^2 (J^T J)^-1 with sigma the noise added to each coordinate and J the Jacobian
    // of s R b + t - a in (x, y, yaw, s), the scale marginalised. The fit's sigma^2 is estimated
    // from 2m - 4 residuals (m ~ 120 inliers): chi-square, relative spread sqrt(2 / (2m - 4)) =
    // 9 %; within 3 spreads, 28 %, however the noise level compares with the previous one.
    Eigen::Matrix4d jtj = Eigen::Matrix4d::Zero();
    for (std::size_t i = 30; i < s.b.size(); ++i) {
      Eigen::Matrix<double, 2, 4> j;
      j.leftCols<2>().setIdentity();
      j.col(2) = t.rotation() * Eigen::Vector2d(-s.b[i].y(), s.b[i].x());
      j.col(3) = t.rotation() * s.b[i];
      jtj += j.transpose() * j;
    }
    const double sigma = noise_px * mpp;
    const Eigen::Matrix3d expected = sigma * sigma * jtj.inverse().topLeftCorner<3, 3>();
    EXPECT_NEAR(r.covariance.trace(), expected.trace(), 0.28 * expected.trace()) << "noise " << noise_px << " px";
    for (int k = 0; k < 3; ++k)
      EXPECT_NEAR(r.covariance(k, k), expected(k, k), 0.28 * expected(k, k)) << "noise " << noise_px << " px, " << k;
    EXPECT_GT(r.covariance.trace(), 1.5 * prev_trace) << "noise " << noise_px << " px";
    prev_trace = r.covariance.trace();
  }
  // Fewer inliers, same noise: larger covariance too.
  const Synthetic many = makeCorrespondences(t, 200, mpp, 0.0, 6);
  const Synthetic few = makeCorrespondences(t, 30, mpp, 0.0, 6);
  EXPECT_GT(estimateRigidRansac(few.a, few.b, mpp, o).covariance.trace(),
            2.0 * estimateRigidRansac(many.a, many.b, mpp, o).covariance.trace());
}

// Monte-Carlo check of the fit's covariance, independent of its formula: the same points drawn
// again and again with fresh noise, the spread of the fitted (x, y, yaw) against the sigma the
// fit predicts. Points b on a strip beside B's centre (a revisit overlapping by a third) and
// spread over a whole frame; 1 px of independent noise at 4 mm/px, 30 inliers. With N draws the
// sample standard deviation has a relative standard error of about 1 / sqrt(2 N) (1.8 % at
// 1500); 8 % is 4 of them, while leaving the scale's column out of J (on the strip beside the
// centre the x sigma halves) or dividing the residual variance by n instead of 2n - p (every sigma
// 1.37 times too large) fails it.
struct Spread {
  Eigen::Vector3d sample_sigma, predicted_sigma;
};
Spread monteCarloSpread(const std::vector<Eigen::Vector2d>& b, const Pose2& t, double mpp, double noise_px,
                        const RansacOptions& o, int draws, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> g(0.0, noise_px * mpp);
  std::vector<Eigen::Vector3d> fits;
  Eigen::Matrix3d predicted = Eigen::Matrix3d::Zero();
  for (int k = 0; k < draws; ++k) {
    std::vector<Eigen::Vector2d> a;
    for (const auto& p : b) a.push_back(transformPoint(t, p) + Eigen::Vector2d(g(rng), g(rng)));
    const RansacResult r = estimateRigidRansac(a, b, mpp, o);
    EXPECT_TRUE(r.success) << r.failure;
    if (!r.success) continue;
    EXPECT_EQ(r.inliers.size(), b.size());
    fits.push_back(poseError(r.motion, t));
    predicted += r.covariance;
  }
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& f : fits) mean += f;
  mean /= static_cast<double>(fits.size());
  Eigen::Vector3d var = Eigen::Vector3d::Zero();
  for (const auto& f : fits) var += (f - mean).cwiseAbs2();
  var /= static_cast<double>(fits.size() - 1);
  return {var.cwiseSqrt(), (predicted.diagonal() / static_cast<double>(fits.size())).cwiseSqrt()};
}

std::vector<Eigen::Vector2d> pointsIn(double x0, double x1, double y0, double y1, int n, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> ux(x0, x1), uy(y0, y1);
  std::vector<Eigen::Vector2d> b;
  for (int i = 0; i < n; ++i) b.emplace_back(ux(rng), uy(rng));
  return b;
}

TEST(Ransac, PredictedSigmaMatchesTheMonteCarloSpreadOnAStripAndAWholeFrame) {
  const double mpp = 0.004;
  const Pose2 t(0.8, 0.05, 0.06);
  const std::vector<Eigen::Vector2d> strip = pointsIn(0.55, 1.15, -0.75, 0.75, 30, 11);
  const std::vector<Eigen::Vector2d> whole = pointsIn(-1.15, 1.15, -0.75, 0.75, 30, 12);
  double strip_yaw = 0.0, whole_yaw = 0.0;
  for (bool with_scale : {true, false}) {
    RansacOptions o;
    o.estimate_scale = with_scale;
    for (const auto* b : {&strip, &whole}) {
      const Spread s = monteCarloSpread(*b, t, mpp, 1.0, o, 1500, with_scale ? 13 : 14);
      for (int k = 0; k < 3; ++k)
        EXPECT_NEAR(s.sample_sigma[k], s.predicted_sigma[k], 0.08 * s.predicted_sigma[k])
            << (b == &strip ? "strip" : "whole frame") << (with_scale ? ", similarity" : ", rigid") << ", component "
            << k;
      if (with_scale) (b == &strip ? strip_yaw : whole_yaw) = s.predicted_sigma[2];
    }
  }
  // The same count and noise on a strip (a quarter of the frame) leaves the yaw less determined.
  EXPECT_GT(strip_yaw, 1.5 * whole_yaw) << strip_yaw << " " << whole_yaw;
}

TEST(Ransac, TheSharedDisplacementErrorDoesNotAverageOverTheInliersButGrowsOnAStrip) {
  // correlated_noise_px adds (c · mpp)² n (Jᵀ J)⁻¹: with 4 times the inliers on the same strip the
  // independent part of the yaw variance falls 4 times, the shared part stays; bunched on a
  // strip it is larger than over the whole frame. 0 leaves the covariance as it was.
  const double mpp = 0.004;
  const Pose2 t(0.8, 0.05, 0.06);
  RansacOptions plain, shared;
  shared.correlated_noise_px = 2.0;
  auto yawVariance = [&](const std::vector<Eigen::Vector2d>& b, const RansacOptions& o) {
    std::vector<Eigen::Vector2d> a;
    for (const auto& p : b) a.push_back(transformPoint(t, p));  // no noise: min_noise_px's floor
    const RansacResult r = estimateRigidRansac(a, b, mpp, o);
    EXPECT_TRUE(r.success) << r.failure;
    return r.covariance(2, 2);
  };
  const auto strip30 = pointsIn(0.55, 1.15, -0.75, 0.75, 30, 11), strip120 = pointsIn(0.55, 1.15, -0.75, 0.75, 120, 15);
  const auto whole30 = pointsIn(-1.15, 1.15, -0.75, 0.75, 30, 12);
  const double shared30 = yawVariance(strip30, shared) - yawVariance(strip30, plain);
  const double shared120 = yawVariance(strip120, shared) - yawVariance(strip120, plain);
  EXPECT_GT(shared30, 0.0);
  EXPECT_NEAR(shared120, shared30, 0.25 * shared30);  // not a quarter of it
  EXPECT_NEAR(yawVariance(strip120, plain), yawVariance(strip30, plain) / 4, 0.25 * yawVariance(strip30, plain) / 4);
  EXPECT_GT(shared30, 2.0 * (yawVariance(whole30, shared) - yawVariance(whole30, plain)));
  // The shared part alone: (c · mpp)² over the inliers' mean squared distance from their centroid.
  Eigen::Vector2d c = Eigen::Vector2d::Zero();
  for (const auto& p : strip30) c += p;
  c /= 30.0;
  double spread = 0.0;
  for (const auto& p : strip30) spread += (p - c).squaredNorm() / 30.0;
  EXPECT_NEAR(shared30, std::pow(2.0 * mpp, 2) / spread, 0.02 * shared30);
}

TEST(Features, ApplyAltitudeScalesPixelsToMetres) {
  const CameraIntrinsics c{320, 240, 400.0, 500.0, 160.0, 120.0};
  EXPECT_TRUE(pixelToMetres(cv::Point2f(160, 120), c, 2.0).isZero());
  // 100 px right at 2 m with fx = 400 is 0.5 m; 50 px down with fy = 500 is 0.2 m.
  EXPECT_TRUE(pixelToMetres(cv::Point2f(260, 170), c, 2.0).isApprox(Eigen::Vector2d(0.5, 0.2)));
  EXPECT_TRUE(pixelToMetres(cv::Point2f(260, 170), c, 4.0).isApprox(Eigen::Vector2d(1.0, 0.4)));
}

cv::Mat texturedGrey(int w, int h, unsigned seed) {
  cv::Mat img(h, w, CV_8U);
  cv::RNG rng(seed);
  rng.fill(img, cv::RNG::UNIFORM, 0, 255);
  cv::GaussianBlur(img, img, cv::Size(0, 0), 2.0);
  cv::normalize(img, img, 0, 255, cv::NORM_MINMAX);
  return img;
}

TEST(Features, FixedCountSpreadOverTheImageInResponseOrder) {
  FeatureOptions o;
  o.num_features = 200;
  const FeatureExtractor ex(o);
  const FrameFeatures f = ex.extract(texturedGrey(320, 240, 1));
  ASSERT_EQ(f.size(), 200u);
  EXPECT_EQ(f.descriptors.rows, 200);
  EXPECT_EQ(f.descriptors.cols, 128);
  for (std::size_t i = 1; i < f.size(); ++i) ASSERT_GE(f.keypoints[i - 1].response, f.keypoints[i].response);
  // Bucketing: every cell of the 4 x 4 grid holds features.
  std::vector<int> cells(16, 0);
  for (const auto& k : f.keypoints)
    ++cells[static_cast<int>(k.pt.y * 4 / 240) * 4 + static_cast<int>(k.pt.x * 4 / 320)];
  for (int c : cells) EXPECT_GT(c, 0);
  // A featureless image gives few or none, without error.
  EXPECT_LT(ex.extract(cv::Mat(240, 320, CV_8U, cv::Scalar(128))).size(), 5u);
  EXPECT_THROW(ex.extract(cv::Mat()), std::invalid_argument);
  // A grid whose cell count overflows an int is refused, not divided by zero later.
  FeatureOptions huge;
  huge.grid_rows = huge.grid_cols = 65536;
  EXPECT_NE(huge.validate(), "");
  EXPECT_THROW(FeatureExtractor{huge}, std::invalid_argument);
}

TEST(Matching, RatioAndMutualCheck) {
  const FeatureExtractor ex(FeatureOptions{});
  const cv::Mat img = texturedGrey(320, 240, 2);
  const FrameFeatures a = ex.extract(img);
  cv::Mat shifted;
  cv::warpAffine(img, shifted, cv::Matx23d(1, 0, 7, 0, 1, -4), img.size(), cv::INTER_LINEAR, cv::BORDER_REFLECT);
  const FrameFeatures b = ex.extract(shifted);
  const auto m = matchDescriptors(a.descriptors, b.descriptors, MatchOptions());
  ASSERT_GT(m.size(), 100u);
  int right = 0;
  for (const auto& x : m) {
    const cv::Point2f d = b.keypoints[x.b].pt - a.keypoints[x.a].pt;
    right += std::abs(d.x - 7) < 1.0 && std::abs(d.y + 4) < 1.0;
  }
  EXPECT_GT(right, 0.95 * m.size());
  // Mutual: no feature of b is used twice.
  std::set<int> used;
  for (const auto& x : m) EXPECT_TRUE(used.insert(x.b).second);
  EXPECT_TRUE(matchDescriptors(cv::Mat(), b.descriptors, MatchOptions()).empty());
}

// Odometry over frames rendered from the procedural seabed with a known motion.
using OdometryTest = testing_util::RenderedSeabedTest;

TEST_F(OdometryTest, RecoversMotionWithAltitudeScale) {
  // Frames at different altitudes: the metric motion must come out right only if the pixels
  // are scaled by the altitudes.
  const Pose2 p0(3.0, 3.0, 0.2), p1(3.45, 3.12, 0.32);
  const Pose2 expected = between(p0, p1);
  OdometryOptions o;
  o.keyframes.min_overlap = 0.99;  // make every matched frame a keyframe
  auto run = [&](const OdometryOptions& opt, double alt0_read, double alt1_read, OdometryUpdate* second) {
    Odometry odo(camera_, opt);
    EXPECT_EQ(odo.process({0, 0.0, alt0_read, render(p0, 2.0)}).status, FrameStatus::kFirstKeyframe);
    *second = odo.process({1, 1.0, alt1_read, render(p1, 2.4)});
    EXPECT_EQ(second->status, FrameStatus::kKeyframe) << second->reason;
    return odo.trajectory().motion(1).mean;
  };
  OdometryUpdate u;
  const Pose2 good = run(o, 2.0, 2.4, &u);
  EXPECT_TRUE(approxEqual(good, expected, 0.01, 0.005)) << good << " vs " << expected;
  EXPECT_NEAR(u.scale, 1.0, 0.01);
  EXPECT_GT(u.inliers, 50);

  // A wrong altitude of the new frame only moves the fitted scale (2.4 / 2.0): the motion, in
  // the keyframe's metres, stays right.
  const Pose2 wrong_new = run(o, 2.0, 2.0, &u);
  EXPECT_TRUE(approxEqual(wrong_new, expected, 0.01, 0.005)) << wrong_new;
  EXPECT_NEAR(u.scale, 1.2, 0.02);
  // A wrong altitude of the keyframe scales the whole motion (here by 2.2 / 2.0).
  const Pose2 wrong_kf = run(o, 2.2, 2.4, &u);
  EXPECT_NEAR(wrong_kf.translation().norm(), 1.1 * expected.translation().norm(), 0.01);
  // Without the scale correction a wrong altitude of the new frame biases the motion.
  o.ransac.estimate_scale = false;
  o.ransac.inlier_threshold_px = 30;  // let the inconsistent points in
  const Pose2 rigid = run(o, 2.0, 2.0, &u);
  EXPECT_GT((rigid.translation() - expected.translation()).norm(), 0.03) << rigid;
}

TEST_F(OdometryTest, NoOverlapFallsBackCleanlyAndIsCounted) {
  OdometryOptions reuse;
  reuse.fallback.bridge_frames = 0;  // the paper's reuse at once (bridging: the next tests)
  Odometry odo(camera_, reuse);
  odo.process({0, 0.0, 2.0, render(Pose2(2.0, 2.0, 0.0), 2.0)});
  odo.process({1, 1.0, 2.0, render(Pose2(2.3, 2.0, 0.0), 2.0)});
  const OdometryUpdate u = odo.process({2, 2.0, 2.0, render(Pose2(6.0, 4.5, 1.0), 2.0)});  // elsewhere
  EXPECT_EQ(u.status, FrameStatus::kFallback);
  EXPECT_FALSE(u.reason.empty());
  EXPECT_EQ(odo.stats().fallbacks, 1);
  EXPECT_TRUE(odo.keyframes().back().fallback);
  // The reused motion is the previous step (0.3 m along x), with a large covariance.
  const UncertainPose2& m = odo.trajectory().motion(odo.trajectory().numMotions());
  EXPECT_GT(m.covariance(0, 0), 0.04 * 0.04);
  EXPECT_NEAR(odo.trajectory().absolutePoses().back().x(), 0.6, 0.03);
}

// An unmatched frame is bridged: no keyframe and no made-up motion; the next frame is matched to
// the frame before it (promoted), so the track has no kink where the reused step would have put one.
TEST_F(OdometryTest, AnUnmatchedFrameIsBridgedByItsNeighbours) {
  Odometry odo(camera_, OdometryOptions());
  odo.process({0, 0.0, 2.0, render(Pose2(2.0, 2.0, 0.0), 2.0)});
  odo.process({1, 1.0, 2.0, render(Pose2(2.3, 2.0, 0.0), 2.0)});
  const OdometryUpdate u = odo.process({2, 2.0, 2.0, render(Pose2(6.0, 4.5, 1.0), 2.0)});  // elsewhere
  EXPECT_EQ(u.status, FrameStatus::kFallback);
  EXPECT_EQ(u.keyframe_id, -1);
  EXPECT_NE(u.reason.find("bridged"), std::string::npos) << u.reason;
  EXPECT_EQ(odo.stats().fallbacks, 1);
  EXPECT_EQ(odo.stats().bridged, 1);
  EXPECT_EQ(odo.stats().promotions, 1);  // frame 1, to match frame 3 against
  EXPECT_NEAR(u.pose.x(), 0.6, 0.03);    // the prediction reported (display only)
  // The vehicle turned and slowed: a reused step (0.3 m along x) would be 0.25 m off here.
  const OdometryUpdate next = odo.process({3, 3.0, 2.0, render(Pose2(2.4, 2.15, 0.2), 2.0)});
  ASSERT_TRUE(next.status == FrameStatus::kKeyframe || next.status == FrameStatus::kTracked) << next.reason;
  EXPECT_TRUE(approxEqual(next.pose, Pose2(0.4, 0.15, 0.2), 0.01, 0.005)) << next.pose;
  for (const KeyframeInfo& k : odo.keyframes()) {
    EXPECT_FALSE(k.fallback) << "keyframe of frame " << k.frame_index;
    EXPECT_NE(k.frame_index, 2);
  }
  // The control: reusing at once (bridge_frames 0) makes frame 2 a keyframe 0.3 m on, where frame
  // 3 cannot be matched either: a second reused step, the track 0.25 m and more off.
  OdometryOptions reuse;
  reuse.fallback.bridge_frames = 0;
  Odometry paper(camera_, reuse);
  paper.process({0, 0.0, 2.0, render(Pose2(2.0, 2.0, 0.0), 2.0)});
  paper.process({1, 1.0, 2.0, render(Pose2(2.3, 2.0, 0.0), 2.0)});
  paper.process({2, 2.0, 2.0, render(Pose2(6.0, 4.5, 1.0), 2.0)});
  const OdometryUpdate guessed = paper.process({3, 3.0, 2.0, render(Pose2(2.4, 2.15, 0.2), 2.0)});
  EXPECT_EQ(guessed.status, FrameStatus::kFallback);
  EXPECT_GT((guessed.pose.translation() - Eigen::Vector2d(0.4, 0.15)).norm(), 0.25) << guessed.pose;
}

// After bridge_frames consecutive unmatched frames the previous step is reused (a session that never
// ends needs a pose to go on from): from the prediction over the bridged frames, with their steps' variance.
TEST_F(OdometryTest, BeyondTheBridgeThePreviousStepIsReused) {
  OdometryOptions o;
  o.fallback.bridge_frames = 2;
  Odometry odo(camera_, o);
  odo.process({0, 0.0, 2.0, render(Pose2(2.0, 2.0, 0.0), 2.0)});
  odo.process({1, 1.0, 2.0, render(Pose2(2.3, 2.0, 0.0), 2.0)});
  // Three places apart from the track and from one another (frames that registered with each other
  // would start the next session there, AFrameThatRegistersOnlyWithTheUnmatchedOneBefore...).
  EXPECT_EQ(odo.process({2, 2.0, 2.0, render(Pose2(6.0, 4.5, 1.0), 2.0)}).keyframe_id, -1);
  EXPECT_EQ(odo.process({3, 3.0, 2.0, render(Pose2(9.5, 2.0, -1.0), 2.0)}).keyframe_id, -1);
  const int before = static_cast<int>(odo.keyframes().size());
  const OdometryUpdate u = odo.process({4, 4.0, 2.0, render(Pose2(9.0, 6.0, 2.0), 2.0)});
  EXPECT_EQ(u.status, FrameStatus::kFallback);
  ASSERT_EQ(static_cast<int>(odo.keyframes().size()), before + 1);
  EXPECT_TRUE(odo.keyframes().back().fallback);
  EXPECT_EQ(odo.stats().bridged, 2);
  EXPECT_EQ(odo.stats().fallbacks, 3);
  EXPECT_NEAR(odo.trajectory().absolutePoses().back().x(), 0.3 + 3 * 0.3, 0.05);  // three steps past frame 1
  const UncertainPose2& m = odo.trajectory().motion(odo.trajectory().numMotions());
  const double sxy = std::max(o.fallback.min_sigma_m, o.fallback.relative_sigma * 0.3);
  EXPECT_NEAR(m.covariance(0, 0), 3 * sxy * sxy, 0.2 * sxy * sxy);
}

TEST_F(OdometryTest, BadInputIsSkippedOrRepairedAndCounted) {
  Odometry odo(camera_, OdometryOptions());
  EXPECT_EQ(odo.process({0, 0.0, 2.0, cv::Mat()}).status, FrameStatus::kSkipped);
  EXPECT_EQ(odo.process({1, 0.5, std::nan(""), render(Pose2(2, 2, 0), 2.0)}).status, FrameStatus::kSkipped);
  EXPECT_EQ(odo.process({2, 1.0, 2.0, render(Pose2(2, 2, 0), 2.0)}).status, FrameStatus::kFirstKeyframe);
  const OdometryUpdate u = odo.process({3, 1.5, -1.0, render(Pose2(2.1, 2, 0), 2.0)});  // reuses 2.0 m
  EXPECT_EQ(u.status, FrameStatus::kTracked);
  EXPECT_NEAR(u.pose.x(), 0.1, 0.01);
  cv::Mat sixteen(240, 320, CV_16U, cv::Scalar(1000));
  EXPECT_EQ(odo.process({4, 2.0, 2.0, sixteen}).status, FrameStatus::kSkipped);
  // An image of another size than camera.yaml's would be scaled wrongly: skipped, with why.
  cv::Mat half;
  cv::resize(render(Pose2(2.2, 2, 0), 2.0), half, cv::Size(160, 120));
  const OdometryUpdate wrong_size = odo.process({5, 2.5, 2.0, half});
  EXPECT_EQ(wrong_size.status, FrameStatus::kSkipped);
  EXPECT_NE(wrong_size.reason.find("160x120"), std::string::npos) << wrong_size.reason;
  EXPECT_EQ(odo.stats().skipped_image, 3);
  EXPECT_EQ(odo.stats().skipped_altitude, 1);
  EXPECT_EQ(odo.stats().altitude_reused, 1);
  EXPECT_EQ(odo.stats().frames, 6);
}

// An absurd altitude (a glitch, 1e308, a "no bottom" 9999) would scale the motion by it: above
// max_altitude_m it is treated as missing, the last valid one reused, and counted.
TEST_F(OdometryTest, AnAltitudeAboveTheMaximumIsReusedAndCounted) {
  Odometry odo(camera_, OdometryOptions());
  EXPECT_EQ(odo.process({0, 0.0, 1e308, render(Pose2(2, 2, 0), 2.0)}).status, FrameStatus::kSkipped);  // none yet
  EXPECT_EQ(odo.process({1, 0.5, 2.0, render(Pose2(2, 2, 0), 2.0)}).status, FrameStatus::kFirstKeyframe);
  for (const double glitch : {1e308, 9999.0, 200.5}) {
    const OdometryUpdate u = odo.process({2, 1.0, glitch, render(Pose2(2.1, 2, 0), 2.0)});
    EXPECT_EQ(u.status, FrameStatus::kTracked) << glitch;
    EXPECT_NEAR(u.pose.x(), 0.1, 0.01) << glitch;  // at 2.0 m; 1e308 m gave a motion of ~1e307 m
  }
  EXPECT_EQ(odo.stats().altitude_out_of_range, 4);
  EXPECT_EQ(odo.stats().altitude_reused, 3);
  // inf is not a reading at all (as NaN): reused, not counted as above the maximum.
  odo.process({3, 1.5, std::numeric_limits<double>::infinity(), render(Pose2(2.1, 2, 0), 2.0)});
  EXPECT_EQ(odo.stats().altitude_out_of_range, 4);
  EXPECT_EQ(odo.stats().altitude_reused, 4);
  EXPECT_EQ(odo.stats().skipped_altitude, 1);
  // The bound is the option (a camera 300 m up is not an AUV's, but the user may say so).
  OdometryOptions high;
  high.max_altitude_m = 400.0;
  Odometry far(camera_, high);
  far.process({0, 0.0, 300.0, render(Pose2(2, 2, 0), 2.0)});
  EXPECT_EQ(far.stats().altitude_out_of_range, 0);
  EXPECT_EQ(far.stats().skipped_altitude, 0);
  high.max_altitude_m = std::nan("");
  EXPECT_NE(high.validate().find("max_altitude_m"), std::string::npos);
}

TEST_F(OdometryTest, StraightRunDriftsLittleAndTakesKeyframesByOverlap) {
  OdometryOptions o;
  Odometry odo(camera_, o);
  const int n = 25;
  for (int k = 0; k < n; ++k) {
    const Pose2 p(1.8 + 0.15 * k, 3.0, 0.02 * std::sin(k * 0.5));
    odo.process({k, 0.5 * k, 2.0, render(p, 2.0)});
  }
  const Pose2 end = odo.trajectory().absolutePoses().back();
  const int last = odo.keyframes().back().frame_index;
  const Pose2 truth = between(Pose2(1.8, 3.0, 0.0), Pose2(1.8 + 0.15 * last, 3.0, 0.02 * std::sin(last * 0.5)));
  EXPECT_LT((end.translation() - truth.translation()).norm(), 0.01 * 0.15 * last + 0.005) << end << " vs " << truth;
  // Footprint 2.13 m wide; 0.15 m steps: a keyframe about every 1.1 m (overlap 0.5), not every frame.
  EXPECT_GE(odo.stats().keyframes, 3);
  EXPECT_LT(odo.stats().keyframes, 10);
  EXPECT_EQ(odo.stats().fallbacks, 0);
  EXPECT_GT(odo.stats().tracked, 10);
}

TEST_F(OdometryTest, EachFramesCovarianceIsTheChainsComposedToFirstOrder) {
  // Keyframes: exactly Trajectory::absolute (an independent composition of all motions from the
  // first); tracked frames: more than their keyframe's (one more motion), less than the next's
  // would be without it, and never zero after the first frame.
  Odometry odo(camera_, OdometryOptions());
  double last_keyframe_trace = 0.0;
  int tracked = 0;
  for (int k = 0; k < 20; ++k) {
    const Pose2 p(1.8 + 0.15 * k, 3.0 + 0.05 * k, 0.1 * std::sin(k * 0.4));
    const OdometryUpdate u = odo.process({k, 0.5 * k, 2.0, render(p, 2.0)});
    ASSERT_NE(u.status, FrameStatus::kSkipped) << u.reason;
    if (k == 0) {
      EXPECT_TRUE(u.covariance.isZero());
      continue;
    }
    EXPECT_TRUE(checkCovariance(u.covariance).empty()) << u.covariance;
    if (u.keyframe_id >= 0) {
      const UncertainPose2 a = odo.trajectory().absolute(static_cast<std::size_t>(u.keyframe_id));
      EXPECT_LT((u.covariance - a.covariance).cwiseAbs().maxCoeff(), 1e-12 * a.covariance.cwiseAbs().maxCoeff())
          << "keyframe " << u.keyframe_id;
      EXPECT_GT(u.covariance.trace(), last_keyframe_trace);
      last_keyframe_trace = u.covariance.trace();
    } else {
      ++tracked;
      EXPECT_GT(u.covariance.trace(), last_keyframe_trace) << "frame " << k;
    }
  }
  EXPECT_GT(tracked, 5);
  EXPECT_GE(odo.stats().keyframes, 3);
}

// Keyframes ahead (OdometryInput::keyframe_lookahead_s) on a straight run at constant velocity:
// 0.2 m steps 0.5 s apart along x, a footprint 2.13 m wide. The keyframe rule (overlap < 0.5, from
// 1.067 m on) takes every 6th frame (1.2 m, overlap 0.44; the 5th lies at 1.0 m, overlap 0.53).
struct LookaheadRun {
  std::vector<int> keyframes;  // frame indexes, the first included
  std::vector<int> early;      // ... of them, made early (OdometryUpdate::early_keyframe)
  std::vector<double> early_overlap;
  std::vector<int> klt_frames;  // frames KLT tracked (klt.enabled)
  OdometryStats stats;
};

class LookaheadTest : public OdometryTest {
 protected:
  LookaheadRun run(double lookahead_s, bool klt) const {
    OdometryOptions o;
    o.klt.enabled = klt;
    Odometry odo(camera_, o);
    LookaheadRun r;
    for (int k = 0; k <= 12; ++k) {
      OdometryInput in{k, 0.5 * k, 2.0, render(Pose2(1.8 + 0.2 * k, 3.0, 0.0), 2.0)};
      in.keyframe_lookahead_s = lookahead_s;
      const OdometryUpdate u = odo.process(in);
      EXPECT_TRUE(u.status == FrameStatus::kFirstKeyframe || u.status == FrameStatus::kKeyframe ||
                  u.status == FrameStatus::kTracked)
          << "frame " << k << ": " << u.reason;
      EXPECT_NEAR(u.pose.x(), 0.2 * k, 0.02) << "frame " << k;
      if (u.keyframe_id >= 0) r.keyframes.push_back(k);
      if (u.early_keyframe) {
        EXPECT_GE(u.keyframe_id, 0) << "frame " << k;
        r.early.push_back(k);
        r.early_overlap.push_back(u.overlap);
      }
      if (u.klt) r.klt_frames.push_back(k);
    }
    r.stats = odo.stats();
    return r;
  }
};

TEST_F(LookaheadTest, AKeyframeDueAtTheFrameThatWillWaitIsMadeOneFrameEarlierNeverLater) {
  const LookaheadRun rule = run(0.0, false);
  ASSERT_EQ(rule.keyframes, (std::vector<int>{0, 6, 12})) << "the rule's keyframes, every frame processed";
  EXPECT_TRUE(rule.early.empty()) << "no lookahead: nothing early";
  EXPECT_EQ(rule.stats.early_keyframes, 0);
  // The next frame (one interval ahead) will wait: its keyframe is made at the frame before.
  const LookaheadRun one = run(0.5, false);
  EXPECT_EQ(one.keyframes, (std::vector<int>{0, 5, 10}));
  EXPECT_EQ(one.early, (std::vector<int>{5, 10}));
  EXPECT_EQ(one.stats.early_keyframes, 2);
  EXPECT_EQ(one.stats.keyframes, 3);
  // Early: the rule did not take them (their overlap is still above min_overlap).
  for (const double overlap : one.early_overlap) {
    EXPECT_GE(overlap, OdometryOptions().keyframes.min_overlap);
    EXPECT_NEAR(overlap, 1.0 - 1.0 / (320 / 300.0 * 2.0), 0.02);  // 1.0 m of 2.13 m
  }
  // Two intervals ahead: two frames earlier.
  const LookaheadRun two = run(1.0, false);
  EXPECT_EQ(two.keyframes, (std::vector<int>{0, 4, 8, 12}));
  EXPECT_EQ(two.early, (std::vector<int>{4, 8, 12}));
  EXPECT_EQ(two.stats.early_keyframes, 3);
  // Not finite or negative: the rule as it is.
  for (const double bad : {std::nan(""), -0.5, std::numeric_limits<double>::infinity()}) {
    const LookaheadRun r = run(bad, false);
    EXPECT_EQ(r.keyframes, rule.keyframes) << bad;
    EXPECT_EQ(r.stats.early_keyframes, 0) << bad;
  }
}

// With KLT between keyframes: a frame KLT tracked whose lookahead is due goes the full way (SIFT)
// and becomes the keyframe, as a frame the rule itself takes does.
TEST_F(LookaheadTest, AKltFrameWhoseLookaheadIsDueIsExtractedAndMadeTheKeyframe) {
  const LookaheadRun rule = run(0.0, true);
  ASSERT_EQ(rule.keyframes, (std::vector<int>{0, 6, 12}));
  EXPECT_EQ(rule.klt_frames, (std::vector<int>{1, 2, 3, 4, 5, 7, 8, 9, 10, 11}));
  EXPECT_EQ(rule.stats.early_keyframes, 0);
  const LookaheadRun one = run(0.5, true);
  EXPECT_EQ(one.keyframes, (std::vector<int>{0, 5, 10}));
  EXPECT_EQ(one.early, (std::vector<int>{5, 10}));
  EXPECT_EQ(one.stats.early_keyframes, 2);
  EXPECT_EQ(one.klt_frames, (std::vector<int>{1, 2, 3, 4, 6, 7, 8, 9, 11, 12}));
  EXPECT_EQ(one.stats.klt_extracted, 2) << "frames 5 and 10: tracked, then extracted";
  EXPECT_EQ(one.stats.klt_degraded, 0);
  for (const double overlap : one.early_overlap) EXPECT_GE(overlap, OdometryOptions().keyframes.min_overlap);
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
