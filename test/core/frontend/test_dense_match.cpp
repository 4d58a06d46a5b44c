// The odometry's dense pass (core/frontend/dense_match.h): the flat field, the acceptance rule, and
// the odometry on rendered frames where the normal registration fails.
#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include <cmath>

#include "../../common/rendered_seabed.h"
#include "uw_multislam/core/frontend/dense_match.h"
#include "uw_multislam/core/frontend/odometry.h"

namespace uw_multislam {
namespace core {
namespace {

using DenseMatchTest = testing_util::RenderedSeabedTest;

TEST_F(DenseMatchTest, TheFlatFieldRemovesTheLightsFalloff) {
  cv::Mat grey;
  cv::cvtColor(render(Pose2(4.0, 4.0, 0.0), 2.0), grey, cv::COLOR_BGR2GRAY);
  // The vehicle's lights: bright on the left, a quarter as bright on the right.
  cv::Mat lit(grey.size(), CV_8U);
  for (int r = 0; r < grey.rows; ++r)
    for (int c = 0; c < grey.cols; ++c)
      lit.at<uchar>(r, c) = cv::saturate_cast<uchar>(grey.at<uchar>(r, c) * (1.0 - 0.75 * c / (grey.cols - 1.0)));
  const cv::Rect left(0, 0, grey.cols / 4, grey.rows), right(grey.cols - grey.cols / 4, 0, grey.cols / 4, grey.rows);
  const double before = cv::mean(lit(left))[0] / cv::mean(lit(right))[0];
  const cv::Mat flat = flatField(lit, 40.0);
  ASSERT_EQ(flat.type(), CV_8UC1);
  ASSERT_EQ(flat.size(), lit.size());
  const double after = cv::mean(flat(left))[0] / cv::mean(flat(right))[0];
  EXPECT_GT(before, 3.0);
  // Most of it removed (what is left: the blur's sigma is not small against so steep a falloff).
  EXPECT_LT(std::abs(after - 1.0), 0.25 * (before - 1.0)) << "before " << before << ", after " << after;
  // Texture is kept: the flattened image still varies as much, relative to its mean.
  cv::Scalar mean, sd;
  cv::meanStdDev(flat(right), mean, sd);
  EXPECT_GT(sd[0] / mean[0], 0.1);
  EXPECT_THROW(flatField(cv::Mat(), 40.0), std::invalid_argument);
}

TEST(DenseAccepts, ByTheOverlapTheMotionPredictsAndTheInliersSpread) {
  const CameraIntrinsics c{320, 240, 300.0, 300.0, 160.0, 120.0};
  DenseMatchOptions o;  // 12 inliers, 40 per unit of overlap, hull 0.2 of the overlap
  const double image = 320.0 * 240.0;
  EXPECT_EQ(denseAccepts(20, 0.3 * 0.4 * image, 0.4, c, o), "");
  EXPECT_NE(denseAccepts(11, 0.5 * 0.2 * image, 0.2, c, o), "");  // too few at all
  // A chance consensus claiming a large overlap: 20 inliers cannot be a 90 % overlap (36 needed).
  EXPECT_NE(denseAccepts(20, 0.5 * 0.9 * image, 0.9, c, o).find("predicted overlap"), std::string::npos);
  // Enough of them, bunched in a corner of the overlap they claim.
  EXPECT_NE(denseAccepts(30, 0.1 * 0.4 * image, 0.4, c, o).find("cover"), std::string::npos);
  EXPECT_NE(denseAccepts(30, 1000.0, 0.0, c, o), "");  // no overlap predicted: nothing to register
  EXPECT_DOUBLE_EQ(convexHullArea({{0, 0}, {10, 0}, {10, 10}, {0, 10}, {5, 5}}), 100.0);
  EXPECT_DOUBLE_EQ(convexHullArea({{0, 0}, {10, 0}}), 0.0);
}

TEST(DenseMatchOptions, BadValuesAreNamed) {
  DenseMatchOptions o;
  EXPECT_EQ(o.validate(), "");
  o.num_features = 5;
  EXPECT_NE(o.validate().find("num_features"), std::string::npos);
  o = DenseMatchOptions();
  o.min_hull_fraction = 1.5;
  EXPECT_NE(o.validate().find("min_hull_fraction"), std::string::npos);
  OdometryOptions odometry;
  odometry.dense.ratio = 0.0;
  EXPECT_NE(odometry.validate().find("dense: ratio"), std::string::npos);
}

// Few normal features (60 a frame) and a 1.3 m step on a 2.13 m footprint (39 % overlap): too few
// correspondences for the normal registration; the dense pass registers the pair, with the motion right.
TEST_F(DenseMatchTest, ALowOverlapPairTheNormalPassCannotRegisterIsMatchedDensely) {
  OdometryOptions o;
  o.features.num_features = 60;
  const Pose2 a(3.0, 4.0, 0.05), b(4.3, 4.1, 0.1);
  auto run = [&](const OdometryOptions& options) {
    Odometry odo(camera_, options);
    odo.process({0, 0.0, 2.0, render(a, 2.0)});
    const OdometryUpdate u = odo.process({1, 1.0, 2.0, render(b, 2.0)});
    return std::make_pair(u, odo.stats());
  };
  const auto [u, stats] = run(o);
  ASSERT_EQ(u.status, FrameStatus::kKeyframe) << u.reason;
  EXPECT_TRUE(u.dense);
  EXPECT_EQ(stats.dense_tries, 1);
  EXPECT_EQ(stats.dense_matches, 1);
  EXPECT_GE(u.inliers, 12);
  EXPECT_TRUE(approxEqual(u.pose, between(a, b), 0.02, 0.01)) << u.pose << " vs " << between(a, b);
  // The control: without the dense pass the same frame is unmatched.
  o.dense.enabled = false;
  const auto [plain, plain_stats] = run(o);
  EXPECT_EQ(plain.status, FrameStatus::kFallback);
  EXPECT_FALSE(plain.dense);
  EXPECT_EQ(plain_stats.dense_tries, 0);
}

TEST_F(DenseMatchTest, FramesThatDoNotOverlapAreRefusedByTheDensePassToo) {
  Odometry odo(camera_, OdometryOptions());
  odo.process({0, 0.0, 2.0, render(Pose2(2.0, 2.0, 0.0), 2.0)});
  const OdometryUpdate u = odo.process({1, 1.0, 2.0, render(Pose2(8.0, 5.5, 1.0), 2.0)});  // elsewhere
  EXPECT_EQ(u.status, FrameStatus::kFallback);
  EXPECT_NE(u.reason.find("dense pass"), std::string::npos) << u.reason;
  EXPECT_EQ(odo.stats().dense_tries, 1);
  EXPECT_EQ(odo.stats().dense_matches, 0);
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
