// A seabed "world" for the survey generator: a colour raster with its metres per pixel and the
// pixel of the world origin. World axes follow the raster: x along its columns, y along its
// rows, so a world pose uses the same conventions as the ground truth of the dataset folders.
//
// Two sources: a built-in procedural seabed (seedable: sand with grain and ripples, rocks,
// pebbles and shells, seagrass patches, featureless sand areas, at several scales), or a
// georeferenced mosaic image (e.g. a survey photomosaic, mosaic.jpg with its mosaic.txt), whose
// black areas outside the imaged seabed are marked invalid so that no frame ever shows them.
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include <cstdint>
#include <string>

#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/geometry/se2.h"

namespace uw_multislam {
namespace core {

struct ProceduralSeabedOptions {
  double width_m = 30.0;
  double height_m = 20.0;
  double metres_per_px = 0.008;
  std::uint64_t seed = 1;
  /// Fraction of the area (0..0.8) covered by nearly featureless smooth sand.
  double featureless_fraction = 0.12;
  /// Fraction of the area (0..0.8) covered by seagrass patches.
  double seagrass_fraction = 0.25;
  /// Rocks per square metre (on average; they cluster).
  double rock_density_per_m2 = 0.35;
  /// Pebbles and shells per square metre.
  double pebble_density_per_m2 = 6.0;

  /// Empty when usable, else a sentence naming the bad value.
  std::string validate() const;
};

class SeabedWorld {
 public:
  /// Generates the procedural seabed; the world origin is the raster's top-left corner.
  static SeabedWorld procedural(const ProceduralSeabedOptions& options);
  /// Loads a mosaic and its text file ("m_per_px V" and "origin_px U V" lines). Pixels whose
  /// three channels are all below `black_level` (and a margin around them) are invalid.
  /// Throws DatasetError naming the file on a bad mosaic.
  static SeabedWorld fromMosaic(const std::string& image_path, const std::string& georef_path, int black_level = 8);
  /// From any raster (used by tests): `valid` may be empty (all valid) or CV_8U of the same size.
  SeabedWorld(cv::Mat bgr, double metres_per_px, const Eigen::Vector2d& origin_px, cv::Mat valid = cv::Mat());

  const cv::Mat& image() const { return image_; }
  double metresPerPixel() const { return metres_per_px_; }
  const Eigen::Vector2d& originPx() const { return origin_px_; }
  double widthM() const { return image_.cols * metres_per_px_; }
  double heightM() const { return image_.rows * metres_per_px_; }

  /// Raster pixel (continuous, pixel centres at integers) of a world point, and back.
  Eigen::Vector2d worldToPixel(const Eigen::Vector2d& world_m) const;
  Eigen::Vector2d pixelToWorld(const Eigen::Vector2d& px) const;

  /// The 2x3 affine map from camera pixels to raster pixels for a camera whose principal point
  /// looks down at `pose` (world frame) from `altitude_m` (pinhole, fronto-parallel seabed).
  cv::Matx23d cameraToRaster(const Pose2& pose, double altitude_m, const CameraIntrinsics& camera) const;

  /// Renders the view (BGR, camera size) with anti-aliasing (supersampled when a camera pixel
  /// covers more than one raster pixel). Pixels outside the raster are black.
  cv::Mat render(const Pose2& pose, double altitude_m, const CameraIntrinsics& camera) const;

  /// True when every pixel of the view lies on valid seabed.
  bool viewIsValid(const Pose2& pose, double altitude_m, const CameraIntrinsics& camera) const;

 private:
  cv::Mat image_;  // CV_8UC3
  cv::Mat valid_;  // CV_8U, 255 = valid seabed
  double metres_per_px_ = 0.01;
  Eigen::Vector2d origin_px_ = Eigen::Vector2d::Zero();
};

}  // namespace core
}  // namespace uw_multislam
