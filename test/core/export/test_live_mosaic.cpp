// The live mosaic's drawing (core/export/live_mosaic.h) and the export service's folder check
// (core/export/export_root.h).
#include <gtest/gtest.h>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <cmath>
#include <filesystem>
#include <memory>

#include "../../common/fixtures.h"
#include "../../common/scoped_temp_dir.h"
#include "uw_multislam/core/export/export_root.h"
#include "uw_multislam/core/export/live_mosaic.h"

namespace uw_multislam {
namespace core {
namespace {

constexpr double kAltitude = 1.6;

CameraIntrinsics camera() { return testing_util::pinholeCamera(240, 180, 220.0, 119.5, 89.5); }

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

// The centroid (column, row) of the pixels near `bgr`.
cv::Point2d centroid(const cv::Mat& bgr, const cv::Scalar& colour) {
  double sx = 0.0, sy = 0.0;
  int n = 0;
  for (int r = 0; r < bgr.rows; ++r)
    for (int c = 0; c < bgr.cols; ++c)
      if (near(bgr.at<cv::Vec3b>(r, c), colour)) sx += c, sy += r, ++n;
  EXPECT_GT(n, 100);
  return n > 0 ? cv::Point2d(sx / n, sy / n) : cv::Point2d(-1, -1);
}

TEST(LiveMosaic, WithADatumNorthIsUpAndEastToTheRight) {
  LiveMosaicOptions o;
  o.resolution_m = 0.01;
  // Keyframe 1 is 3 m along the first keyframe's x axis (image columns, z-up x).
  LiveMosaicSnapshot s;
  s.map = 0;
  s.keyframes = {keyframe(0, Pose2(0.0, 0.0, 0.0), kGreen, kGreen), keyframe(1, Pose2(3.0, 0.0, 0.0), kBlue, kBlue)};
  // Without a datum, and with that axis heading east (90 deg): keyframe 1 right of keyframe 0.
  for (const MapFrame& f : {MapFrame(), MapFrame::enuAtHeading(90.0)}) {
    LiveMosaicSnapshot t = s;
    turnLiveMosaic(&t, f);
    const LiveMosaicImage m = drawLiveMosaic(t, o);
    const cv::Point2d g = centroid(m.bgr, kGreen), b = centroid(m.bgr, kBlue);
    EXPECT_NEAR(b.x - g.x, 300.0, 5.0);
    EXPECT_NEAR(b.y - g.y, 0.0, 5.0);
  }
  // Heading north: keyframe 1 straight above; heading 225 (south-west): below and to the left, 3 m / sqrt(2) each.
  LiveMosaicSnapshot north = s;
  turnLiveMosaic(&north, MapFrame::enuAtHeading(0.0));
  LiveMosaicImage m = drawLiveMosaic(north, o);
  cv::Point2d g = centroid(m.bgr, kGreen), b = centroid(m.bgr, kBlue);
  EXPECT_NEAR(b.x - g.x, 0.0, 5.0);
  EXPECT_NEAR(b.y - g.y, -300.0, 5.0);
  LiveMosaicSnapshot south_west = s;
  turnLiveMosaic(&south_west, MapFrame::enuAtHeading(225.0));
  m = drawLiveMosaic(south_west, o);
  g = centroid(m.bgr, kGreen), b = centroid(m.bgr, kBlue);
  EXPECT_NEAR(b.x - g.x, -300.0 / std::sqrt(2.0), 5.0);
  EXPECT_NEAR(b.y - g.y, 300.0 / std::sqrt(2.0), 5.0);
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

// Memory: an image finer than the mosaic is kept at the mosaic's resolution,
// and the mosaic drawn from the kept images is the one drawn from the full images.
TEST(LiveMosaic, ImagesAreKeptAtTheMosaicsResolutionAndDrawTheSameMosaic) {
  const double res = 0.05;  // full images: 1.6 / 220 = 0.0073 m per pixel
  LiveMosaicImages full, kept(res);
  const Pose2 poses[] = {Pose2(0.0, 0.0, 0.0), Pose2(0.8, 0.3, 0.4), Pose2(0.2, 0.9, -1.2)};
  cv::RNG rng(3);
  for (int k = 0; k < 3; ++k) {
    // Seabed-like texture at a few centimetres: noise smoothed over 4 pixels (3 cm).
    cv::Mat noise(180, 240, CV_32F), img;
    rng.fill(noise, cv::RNG::UNIFORM, 0.0, 255.0);
    cv::GaussianBlur(noise, noise, cv::Size(0, 0), 4.0);
    cv::normalize(noise, noise, 0, 255, cv::NORM_MINMAX);
    noise.convertTo(img, CV_8U);
    std::vector<std::uint8_t> bytes;
    cv::imencode(".jpg", img, bytes, {cv::IMWRITE_JPEG_QUALITY, 95});
    full.add(0, k, kAltitude, camera(), bytes);
    kept.add(0, k, kAltitude, camera(), bytes);
  }
  const cv::Mat small = cv::imdecode(*kept.find(0, 0)->jpeg, cv::IMREAD_UNCHANGED);
  const double f = 2.0 * kAltitude / 220.0 / res;  // the full image's ground pixel over half the resolution
  EXPECT_EQ(small.cols, static_cast<int>(std::lround(240 * f)));
  EXPECT_EQ(small.rows, static_cast<int>(std::lround(180 * f)));
  EXPECT_LT(kept.bytes() * 5, full.bytes());
  // The reference is independent of both: the full images drawn 10 times finer (no image is
  // downsampled there), then averaged over each 10 x 10 block (INTER_AREA), where the block is
  // covered. Drawn from the full images at the mosaic's resolution, the same within the same
  // bound: the drawing averages them down first (warpAffine alone samples without averaging: a
  // coarsened mosaic aliased, 17.4 grey levels off with a texture sd of 21).
  auto grey = [](const cv::Mat& bgr) {
    cv::Mat g;
    cv::cvtColor(bgr, g, cv::COLOR_BGR2GRAY);
    return g;
  };
  for (int max_side : {1024, 20}) {  // at the resolution, and coarsened to fit
    LiveMosaicOptions o;
    o.resolution_m = res;
    o.max_side_px = max_side;
    LiveMosaicSnapshot a, b;
    a.map = b.map = 0;
    for (int k = 0; k < 3; ++k) {
      LiveMosaicKeyframe kf = keyframe(k, poses[k], kWhite, kWhite);
      kf.jpeg = full.find(0, k)->jpeg;
      a.keyframes.push_back(kf);
      kf.jpeg = kept.find(0, k)->jpeg;
      b.keyframes.push_back(kf);
    }
    const LiveMosaicImage direct = drawLiveMosaic(a, o), mine = drawLiveMosaic(b, o);
    ASSERT_EQ(direct.bgr.size(), mine.bgr.size());
    EXPECT_EQ(mine.drawn, 3);
    LiveMosaicOptions fine_o;
    fine_o.resolution_m = mine.resolution_m / 10.0;
    fine_o.max_side_px = 8192;
    const LiveMosaicImage fine = drawLiveMosaic(a, fine_o);
    ASSERT_NEAR(fine.x0, mine.x0, 1e-12);
    ASSERT_NEAR(fine.ytop, mine.ytop, 1e-12);
    const cv::Size blocks(std::min(fine.bgr.cols / 10, mine.bgr.cols), std::min(fine.bgr.rows / 10, mine.bgr.rows));
    const cv::Rect fine_roi(0, 0, blocks.width * 10, blocks.height * 10), roi(cv::Point(0, 0), blocks);
    cv::Mat reference, covered;
    const cv::Mat fine_grey = grey(fine.bgr)(fine_roi);
    cv::resize(fine_grey, reference, blocks, 0, 0, cv::INTER_AREA);
    cv::resize(cv::Mat(fine_grey > 0), covered, blocks, 0, 0, cv::INTER_AREA);
    const cv::Mat inside = covered == 255;
    ASSERT_GT(cv::countNonZero(inside), 50) << max_side;
    cv::Mat d_mine, d_direct;
    cv::absdiff(grey(mine.bgr)(roi), reference, d_mine);
    cv::absdiff(grey(direct.bgr)(roi), reference, d_direct);
    cv::Scalar mean, sd;
    cv::meanStdDev(reference, mean, sd, inside);
    const double e_mine = cv::mean(d_mine, inside)[0], e_direct = cv::mean(d_direct, inside)[0];
    EXPECT_GT(sd[0], 5.0) << max_side;  // texture left to compare at this resolution
    // Measured: 0.06-0.20 sd (kept at 2 pixels per mosaic pixel); kept at 1: 0.17-0.38, at 0.5: 0.47-0.62.
    EXPECT_LT(e_mine, 0.25 * sd[0]) << "max side " << max_side << ": mean difference " << e_mine << ", texture sd "
                                    << sd[0] << " (full images drawn directly: " << e_direct << ")";
    EXPECT_LT(e_direct, 0.25 * sd[0]) << "max side " << max_side << ": full images: mean difference " << e_direct;
  }
  // Without a resolution, or without a usable camera, an image is kept as given.
  LiveMosaicImages as_given;
  as_given.add(0, 0, kAltitude, camera(), *full.find(0, 0)->jpeg);
  EXPECT_EQ(as_given.bytes(), full.find(0, 0)->jpeg->size());
  kept.add(1, 0, kAltitude, CameraIntrinsics(), *full.find(0, 0)->jpeg);
  EXPECT_EQ(kept.find(1, 0)->jpeg->size(), full.find(0, 0)->jpeg->size());
  kept.add(1, 1, kAltitude, camera(), std::vector<std::uint8_t>(100, 7));  // not an image
  EXPECT_EQ(kept.find(1, 1)->jpeg->size(), 100u);
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
