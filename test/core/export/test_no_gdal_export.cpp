// The export files of a build without GDAL (GDAL is optional: CMakeLists.txt compiles this test with
// the export sources and without UWMS_HAVE_GDAL, whatever the build has): the mosaic's GeoTIFF is
// refused with the reason, every other file is written, and the PNG (assembled in memory, written by
// OpenCV) holds the image where it belongs.
#include <gtest/gtest.h>

#include <filesystem>
#include <string>
#include <vector>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "uw_multislam/core/export/mosaic.h"
#include "uw_multislam/core/export/survey_export.h"
#include "uw_multislam/core/export/track_files.h"

namespace uw_multislam {
namespace core {
namespace {

#ifdef UWMS_HAVE_GDAL
#error "test_no_gdal_export.cpp is the build without GDAL: compile it without UWMS_HAVE_GDAL"
#endif

class NoGdalExport : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = std::filesystem::temp_directory_path() /
           ("uwms_no_gdal_" + std::to_string(::testing::UnitTest::GetInstance()->random_seed()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    std::filesystem::remove_all(dir_);
    std::filesystem::create_directories(dir_);
    // One keyframe at the map's origin, its image a random texture stored losslessly (PNG: the
    // store's thumbnails decode with cv::imdecode whatever the format).
    image_.create(camera_.height, camera_.width, CV_8U);
    cv::RNG rng(3);
    rng.fill(image_, cv::RNG::UNIFORM, 0, 255);
    cv::GaussianBlur(image_, image_, cv::Size(0, 0), 2.0);
    cv::normalize(image_, image_, 0, 255, cv::NORM_MINMAX);
    ExportKeyframe k;
    k.session = 1;
    k.altitude_m = 2.0;
    k.image_size = image_.size();
    cv::imencode(".png", image_, k.thumbnail);
    track_.label = "session_1";
    track_.name = "a";
    track_.map = 1;
    track_.sessions = {1};
    track_.keyframes = {k};
    survey_.sessions = {track_};
    survey_.cameras = {{1, camera_}};
    options_.mosaic_options.blend = MosaicBlend::kNone;
    options_.mosaic_options.exposure = false;
    options_.mosaic_options.resolution_m = 2.0 / camera_.fx;  // one image pixel per raster pixel
    options_.mosaic_options.tile_px = 64;                     // 20 tiles or more: each placed where it belongs
    options_.origin = &origin_;
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }

  std::filesystem::path dir_;
  const CameraIntrinsics camera_{320, 240, 300.0, 300.0, 159.5, 119.5};
  cv::Mat image_;
  ExportTrack track_;
  SurveyExport survey_;
  GeoOrigin origin_{43.1, 5.9, 30.0};
  TrackFilesOptions options_;
};

TEST_F(NoGdalExport, TheGeoTiffIsRefusedWithTheReasonAndEveryOtherFileIsWritten) {
  EXPECT_NE(geotiffUnavailable().find("GeoTIFF export needs GDAL"), std::string::npos) << geotiffUnavailable();
  const TrackFiles written = writeTrackFiles(track_, survey_, MosaicImages(), dir_.string(), options_);
  EXPECT_EQ(written.no_geotiff, geotiffUnavailable());
  EXPECT_TRUE(written.mosaic);
  EXPECT_TRUE(written.no_mosaic.empty());
  std::vector<std::string> names;
  for (const std::string& f : written.files) {
    EXPECT_TRUE(std::filesystem::is_regular_file(f)) << f;
    EXPECT_GT(std::filesystem::file_size(f), 0u) << f;
    names.push_back(std::filesystem::path(f).filename().string());
  }
  EXPECT_EQ(names, (std::vector<std::string>{"session_1.tum", "session_1.kitti", "session_1.csv", "session_1.g2o",
                                             "session_1.geojson", "session_1.png", "session_1.pgw"}));
  EXPECT_FALSE(std::filesystem::exists(dir_ / "session_1.tif"));
  // Nothing else left behind (no temporary file).
  int entries = 0;
  for (const auto& e : std::filesystem::directory_iterator(dir_)) entries += e.is_regular_file();
  EXPECT_EQ(entries, 7);

  // The PNG: RGBA, the image where the keyframe is (identity scale: one image pixel per raster
  // pixel), opaque there; the raster is the footprint's box, so a pixel at most of border.
  const cv::Mat png = cv::imread((dir_ / "session_1.png").string(), cv::IMREAD_UNCHANGED);
  ASSERT_EQ(png.type(), CV_8UC4);
  EXPECT_EQ(png.cols, written.mosaic_result.width);
  EXPECT_EQ(png.rows, written.mosaic_result.height);
  EXPECT_NEAR(png.cols, camera_.width, 1);
  EXPECT_NEAR(png.rows, camera_.height, 1);
  std::vector<cv::Mat> ch;
  cv::split(png, ch);
  const cv::Rect inner(2, 2, camera_.width - 4, camera_.height - 4);
  EXPECT_EQ(cv::countNonZero(ch[3](inner) == 255), inner.area());
  // The grey image in all three channels, at the offset of at most one pixel the raster's
  // rounding allows: the best offset's mean difference is that of a resampling, a few levels.
  double best = 1e9;
  for (int dy = -1; dy <= 1; ++dy)
    for (int dx = -1; dx <= 1; ++dx) {
      const cv::Rect src(inner.x + dx, inner.y + dy, inner.width, inner.height);
      if ((src & cv::Rect(0, 0, png.cols, png.rows)) != src) continue;
      double sum = 0.0;
      for (int c = 0; c < 3; ++c) sum += cv::norm(ch[c](src), image_(inner), cv::NORM_L1) / inner.area();
      best = std::min(best, sum / 3.0);
    }
  EXPECT_LT(best, 3.0);
}

TEST_F(NoGdalExport, AMosaicAskedForItsGeoTiffDirectlyIsRefusedBeforeAnythingIsWritten) {
  const std::string png = (dir_ / "m.png").string(), tif = (dir_ / "m.tif").string();
  try {
    writeMosaic(track_, survey_, MosaicImages(), options_.mosaic_options, png, &origin_, tif);
    FAIL() << "a GeoTIFF was not refused";
  } catch (const ExportError& e) {
    EXPECT_EQ(std::string(e.what()), tif + ": " + geotiffUnavailable());
  }
  EXPECT_TRUE(std::filesystem::is_empty(dir_));
  // Without an origin the same mosaic is drawn.
  const MosaicResult r = writeMosaic(track_, survey_, MosaicImages(), options_.mosaic_options, png, nullptr, tif);
  EXPECT_EQ(r.tiles, ((r.width + 63) / 64) * ((r.height + 63) / 64));
  EXPECT_TRUE(std::filesystem::is_regular_file(png));
  EXPECT_FALSE(std::filesystem::exists(tif));
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
