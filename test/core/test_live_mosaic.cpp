// The live mosaic's drawing (core/session/live_mosaic.h) and the export service's folder check
// (core/session/export_root.h).
#include <gtest/gtest.h>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <cmath>
#include <filesystem>
#include <memory>

#include "../common/scoped_temp_dir.h"
#include "uw_multislam/core/session/export_root.h"
#include "uw_multislam/core/session/live_mosaic.h"

namespace uw_multislam {
namespace core {
namespace {

constexpr double kAltitude = 1.6;

CameraIntrinsics camera() {
  CameraIntrinsics c;
  c.width = 240;
  c.height = 180;
  c.fx = c.fy = 220.0;
  c.cx = 119.5;
  c.cy = 89.5;
  return c;
}

// A thumbnail-sized JPEG (the whole image resized, as the store keeps it): left half `left`,
// right half `right` (BGR).
std::shared_ptr<const std::vector<std::uint8_t>> jpeg(const cv::Scalar& left, const cv::Scalar& right) {
  cv::Mat img(45, 60, CV_8UC3, right);
  img(cv::Rect(0, 0, 30, 45)).setTo(left);
  std::vector<std::uint8_t> out;
  cv::imencode(".jpg", img, out, {cv::IMWRITE_JPEG_QUALITY, 95});
  return std::make_shared<const std::vector<std::uint8_t>>(out);
}

LiveMosaicKeyframe keyframe(int k, const Pose2& pose, const cv::Scalar& left, const cv::Scalar& right) {
  LiveMosaicKeyframe kf;
  kf.session = 0;
  kf.keyframe = k;
  kf.pose = pose;
  kf.altitude_m = kAltitude;
  kf.camera = camera();
  kf.jpeg = jpeg(left, right);
  return kf;
}

const cv::Scalar kGreen(0, 200, 0), kBlue(200, 0, 0), kRed(0, 0, 200), kWhite(200, 200, 200);

bool near(const cv::Vec3b& pixel, const cv::Scalar& bgr, int tolerance = 25) {
  for (int c = 0; c < 3; ++c)
    if (std::abs(pixel[c] - static_cast<int>(bgr[c])) > tolerance) return false;
  return true;
}

// The footprint written out: a keyframe at (x, y) with yaw 0 covers x +- 120 h / fx (pixel edges
// -0.5 .. 239.5 around cx = 119.5) and y +- 90 h / fy.
TEST(LiveMosaic, ExtentIsTheKeyframesFootprintsAtTheResolution) {
  LiveMosaicSnapshot s;
  s.map = 0;
  s.keyframes = {keyframe(0, Pose2(0.0, 0.0, 0.0), kGreen, kGreen), keyframe(1, Pose2(1.5, 0.5, 0.0), kBlue, kBlue)};
  LiveMosaicOptions o;
  o.resolution_m = 0.01;
  const LiveMosaicImage m = drawLiveMosaic(s, o);
  const double half_w = 120.0 * kAltitude / 220.0, half_h = 90.0 * kAltitude / 220.0;
  EXPECT_EQ(m.bgr.cols, static_cast<int>(std::ceil((1.5 + 2 * half_w) / 0.01)));
  EXPECT_EQ(m.bgr.rows, static_cast<int>(std::ceil((0.5 + 2 * half_h) / 0.01)));
  EXPECT_NEAR(m.x0, -half_w, 1e-9);
  EXPECT_NEAR(m.ytop, -half_h, 1e-9);
  EXPECT_EQ(m.drawn, 2);
  EXPECT_EQ(m.missing, 0);
  // Each keyframe's centre shows its image; the later one is drawn over the earlier one; outside
  // both footprints it is black.
  auto at = [&](double x, double y) {
    return m.bgr.at<cv::Vec3b>(static_cast<int>((y - m.ytop) / 0.01), static_cast<int>((x - m.x0) / 0.01));
  };
  EXPECT_TRUE(near(at(-0.5, -0.3), kGreen));
  EXPECT_TRUE(near(at(1.5, 0.5), kBlue));
  EXPECT_TRUE(near(at(0.8, 0.3), kBlue));  // in both: the later one
  EXPECT_EQ(at(1.5 + half_w - 0.05, -half_h + 0.05), cv::Vec3b(0, 0, 0));
}

// The warp's orientation, against the model written out: image column u runs along the pose's
// yaw direction in image axes (x towards y).
TEST(LiveMosaic, ImageColumnsFollowTheKeyframesYaw) {
  LiveMosaicOptions o;
  o.resolution_m = 0.01;
  LiveMosaicSnapshot s;
  s.map = 0;
  s.keyframes = {keyframe(0, Pose2(0.0, 0.0, 0.0), kGreen, kBlue)};
  LiveMosaicImage m = drawLiveMosaic(s, o);
  EXPECT_TRUE(near(m.bgr.at<cv::Vec3b>(m.bgr.rows / 2, m.bgr.cols / 4), kGreen));  // left half of the image: -x
  EXPECT_TRUE(near(m.bgr.at<cv::Vec3b>(m.bgr.rows / 2, 3 * m.bgr.cols / 4), kBlue));
  s.keyframes = {keyframe(0, Pose2(0.0, 0.0, M_PI / 2), kGreen, kBlue)};
  m = drawLiveMosaic(s, o);
  EXPECT_GT(m.bgr.rows, m.bgr.cols);  // turned a quarter: the image's width now along y
  EXPECT_TRUE(near(m.bgr.at<cv::Vec3b>(m.bgr.rows / 4, m.bgr.cols / 2), kGreen));  // -u -> -y: top rows
  EXPECT_TRUE(near(m.bgr.at<cv::Vec3b>(3 * m.bgr.rows / 4, m.bgr.cols / 2), kBlue));
}

TEST(LiveMosaic, TheActiveKeyframeIsOutlined) {
  LiveMosaicOptions o;
  o.resolution_m = 0.01;
  LiveMosaicSnapshot s;
  s.map = 0;
  s.keyframes = {keyframe(0, Pose2(0.0, 0.0, 0.0), kWhite, kWhite), keyframe(1, Pose2(1.0, 0.0, 0.3), kWhite, kWhite)};
  auto red = [](const cv::Mat& bgr) {
    cv::Mat mask;
    cv::inRange(bgr, cv::Scalar(0, 0, 250), cv::Scalar(5, 5, 255), mask);
    return mask;
  };
  EXPECT_EQ(cv::countNonZero(red(drawLiveMosaic(s, o).bgr)), 0);
  s.active = 1;
  const LiveMosaicImage m = drawLiveMosaic(s, o);
  const cv::Mat outline = red(m.bgr);
  EXPECT_GT(cv::countNonZero(outline), 2 * (m.bgr.rows / 2));
  // On the active keyframe's edge: its image corner (u, v) = (-0.5, -0.5) in the raster.
  const double h = kAltitude / 220.0, c = std::cos(0.3), sn = std::sin(0.3);
  const double gx = 1.0 + c * (-120.0 * h) - sn * (-90.0 * h), gy = sn * (-120.0 * h) + c * (-90.0 * h);
  const int col = static_cast<int>(std::lround((gx - m.x0) / 0.01 - 0.5)),
            row = static_cast<int>(std::lround((gy - m.ytop) / 0.01 - 0.5));
  EXPECT_GT(cv::countNonZero(outline(cv::Rect(col - 2, row - 2, 5, 5) & cv::Rect(0, 0, m.bgr.cols, m.bgr.rows))), 0);
  // Not on keyframe 0's far corner.
  EXPECT_EQ(outline.at<uchar>(1, 1), 0);
}

TEST(LiveMosaic, ALargeMapIsDrawnCoarserToFitAndBadKeyframesAreCountedMissing) {
  LiveMosaicOptions o;
  o.resolution_m = 0.001;
  o.max_side_px = 100;
  LiveMosaicSnapshot s;
  s.map = 0;
  s.keyframes = {keyframe(0, Pose2(0.0, 0.0, 0.0), kGreen, kGreen), keyframe(1, Pose2(3.0, 0.0, 0.0), kBlue, kBlue),
                 keyframe(2, Pose2(1.0, 0.0, 0.0), kRed, kRed), keyframe(3, Pose2(2.0, 0.0, 0.0), kRed, kRed)};
  s.keyframes[2].jpeg = nullptr;     // no image carried
  s.keyframes[3].altitude_m = -1.0;  // a bad altitude
  const LiveMosaicImage m = drawLiveMosaic(s, o);
  const double width_m = 3.0 + 240.0 * kAltitude / 220.0;
  EXPECT_NEAR(m.resolution_m, width_m / 100.0, 1e-12);
  EXPECT_EQ(m.bgr.cols, 100);
  EXPECT_EQ(m.drawn, 2);
  EXPECT_EQ(m.missing, 2);
  EXPECT_TRUE(drawLiveMosaic(LiveMosaicSnapshot{}, o).bgr.empty());
  o.resolution_m = 0.0;
  EXPECT_NE(o.validate(), "");
}

TEST(LiveMosaic, ImagesOfARemovedSessionAreForgottenWithTheirBytes) {
  LiveMosaicImages images;
  CameraIntrinsics c;
  for (int s = 0; s < 3; ++s)
    for (int k = 0; k < 4; ++k) images.add(s, k, 2.0, c, std::vector<std::uint8_t>(100 * (s + 1), 7));
  ASSERT_EQ(images.bytes(), 4u * (100 + 200 + 300));
  EXPECT_EQ(images.removeSession(1), 4);
  EXPECT_EQ(images.removeSession(1), 0);
  EXPECT_EQ(images.size(), 8u);
  EXPECT_EQ(images.bytes(), 4u * (100 + 300));
  for (int k = 0; k < 4; ++k) {
    EXPECT_EQ(images.find(1, k), nullptr);
    ASSERT_NE(images.find(0, k), nullptr);
    ASSERT_NE(images.find(2, k), nullptr);
    EXPECT_EQ(images.find(2, k)->jpeg->size(), 300u);
  }
}

TEST(ExportRoot, FoldersBelowTheRootAreAcceptedAndEverythingElseRefused) {
  namespace fs = std::filesystem;
  testing_util::ScopedTempDir tmp("uwms_export_root");
  const fs::path root = tmp.path() / "root";
  fs::create_directories(root / "existing");
  fs::create_directories(tmp.path() / "outside");
  fs::create_symlink(tmp.path() / "outside", root / "link_out");
  fs::create_symlink(root / "existing", root / "link_in");
  const std::string base = fs::canonical(root).string();
  std::string out, why;
  auto ok = [&](const std::string& folder) { return resolveExportFolder(root.string(), folder, &out, &why); };
  EXPECT_TRUE(ok("dive1/products"));
  EXPECT_EQ(out, base + "/dive1/products");
  EXPECT_TRUE(ok(""));
  EXPECT_EQ(fs::path(out), fs::path(base));
  EXPECT_TRUE(ok("a/../b"));
  EXPECT_EQ(out, base + "/b");
  EXPECT_TRUE(ok((root / "existing" / "x").string()));  // absolute, inside
  EXPECT_TRUE(ok("link_in/y"));
  EXPECT_EQ(out, base + "/existing/y");
  EXPECT_FALSE(fs::exists(root / "dive1"));  // nothing created
  for (const std::string& bad :
       {std::string("../x"), std::string("a/../../x"), std::string("/etc"), (tmp.path() / "outside").string(),
        std::string("link_out"), std::string("link_out/deeper"), std::string(".."), base + "_sibling"}) {
    out.clear();
    why.clear();
    EXPECT_FALSE(ok(bad)) << bad << " -> " << out;
    EXPECT_NE(why.find("outside the export root"), std::string::npos) << why;
  }
  EXPECT_FALSE(resolveExportFolder((tmp.path() / "missing").string(), "x", &out, &why));
  EXPECT_NE(why.find("not an existing directory"), std::string::npos);
  EXPECT_FALSE(resolveExportFolder("", "x", &out, &why));
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
