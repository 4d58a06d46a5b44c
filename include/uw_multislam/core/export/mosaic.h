// Photomosaics of a session or a map: every keyframe's image drawn on the seabed plane
// by its optimised pose and altitude, blended with OpenCV's stitching module, written tile by
// tile through GDAL (PNG + world file, and a GeoTIFF when the map frame is georeferenced; GDAL is
// optional: without it the PNG is assembled in memory and the GeoTIFF refused, geotiffUnavailable()).
//
// Geometry. The camera looks straight down (the package's 2-D model): the pixel (u, v) of a
// keyframe at altitude h sees the seabed point pose (+) ((u - cx) h / fx, (v - cy) h / fy) in
// image axes (the survey's convention: a pose is the ground point under the principal point).
// The plane-to-plane warp of a nadir camera is therefore an affine map (a homography whose last
// row is (0, 0, 1)), drawn with cv::warpAffine. Lens distortion is not undone (the intrinsics
// the store keeps are K; D is not stored).
//
// Raster. Rows run along the map's image-axes y (so the mosaic looks as the camera sees it, not
// mirrored), columns along x: in the z-up map frame, column c and row r are the point
// (x0 + (c + 0.5) res, y0 - (r + 0.5) res), which is what the world file says (.pgw: res, 0, 0,
// -res, x0 + res / 2, y0 - res / 2). Uncovered pixels are transparent (PNG alpha 0).
//
// Memory. The mosaic is drawn in tiles (tile_px square, plus a margin on each side so that the
// blending weights at a tile's edge are the ones a whole-mosaic blend would give); only the
// keyframes whose footprint touches a tile are warped for it; decoded images are kept in a cache
// of bounded bytes; the raster goes to a tiled, compressed GeoTIFF and from there to PNG
// (GDAL's CreateCopy streams scanlines), with GDAL's block cache capped. Exposure compensation
// (cv::detail::ChannelsCompensator, one gain per keyframe and channel) is computed on small
// warped copies; its dense N x N system is solved over windows of 1000 consecutive keyframes.
#pragma once

#include <opencv2/core.hpp>

#include <cstddef>
#include <cstdint>
#include <functional>
#include <map>
#include <string>
#include <vector>

#include "uw_multislam/core/export/survey_export.h"
#include "uw_multislam/core/frontend/dataset.h"

namespace uw_multislam {
namespace core {

enum class MosaicBlend { kFeather, kMultiBand, kNone };
const char* mosaicBlendName(MosaicBlend b);
bool parseMosaicBlend(const std::string& name, MosaicBlend* out);

struct MosaicOptions {
  double resolution_m = 0.0;                  // metres per pixel; 0: the median keyframe's ground pixel size
  MosaicBlend blend = MosaicBlend::kFeather;  // doc/tools/export_survey.md: the seam measure
  bool exposure = true;                       // gain compensation
  int tile_px = 1024;                         // tile side
  std::size_t cache_bytes = 128u << 20;       // decoded images kept between tiles
  double max_megapixels = 1000.0;             // a larger raster is refused (choose a coarser resolution)
  int gdal_cache_mb = 64;

  std::string validate() const;
};

/// Where the keyframes' images come from: full-resolution frames of dataset folders, else the
/// store's thumbnails. A session's folder is the one holding the most of its keyframes (same
/// frame index, stamp within 1 microsecond): stamps alone are ambiguous (simulated missions all
/// start at 0).
class MosaicImages {
 public:
  /// Adds a dataset folder's frames (loadDataset). Throws DatasetError.
  void addDataset(const std::string& directory);
  bool hasDatasets() const { return !datasets_.empty(); }
  /// Chooses each session's folder. Returns one line per session saying which folder (or none).
  std::vector<std::string> matchSessions(const SurveyExport& survey);
  /// The keyframe's image (BGR) and the camera scaled to it; empty when there is none (no frame
  /// matched and no thumbnail, or a file that does not decode). `full` tells which it is.
  cv::Mat load(const ExportKeyframe& k, const CameraIntrinsics& camera, CameraIntrinsics* scaled, bool* full) const;
  /// The thumbnail alone (exposure compensation), or the frame when there is no thumbnail.
  cv::Mat loadSmall(const ExportKeyframe& k, const CameraIntrinsics& camera, CameraIntrinsics* scaled) const;

 private:
  const FrameRecord* frameOf(int dataset, const ExportKeyframe& k) const;
  cv::Mat frame(const ExportKeyframe& k, const CameraIntrinsics& camera, CameraIntrinsics* scaled) const;
  static cv::Mat thumbnail(const ExportKeyframe& k, const CameraIntrinsics& camera, CameraIntrinsics* scaled);
  std::vector<Dataset> datasets_;
  std::vector<std::map<int, int>> row_of_index_;    // per dataset: frame index -> row of frames
  std::map<std::int64_t, int> dataset_of_session_;  // store session id -> dataset
};

struct MosaicResult {
  int width = 0, height = 0;
  double resolution_m = 0.0;
  double x0 = 0.0, y0 = 0.0;  // z-up map frame: the raster's left edge x and top edge y
  int keyframes = 0, from_frames = 0, from_thumbnails = 0, missing = 0;
  int tiles = 0;
  double ms = 0.0;
  /// Seam measure: mean gradient magnitude on the pixels where the number of overlapping images
  /// changes (footprint edges inside the mosaic) over the mean gradient of all covered pixels.
  /// 1 = edges invisible; a visible seam raises it.
  double seam_ratio = 0.0;
};

/// Why this build cannot write GeoTIFFs (it was built without GDAL, which is optional), or empty
/// when it can. Without GDAL the PNG is assembled in memory (at most 256 megapixels) and written
/// by OpenCV; everything else is the same.
std::string geotiffUnavailable();

/// Draws `track`'s mosaic and writes `png_path` (PNG, RGBA) and its world file (`png_path` with
/// .pgw), and, when `origin` is not null, `geotiff_path` (GeoTIFF, a transverse Mercator
/// centred on the origin on WGS84, the raster's rotation in the geotransform; refused with
/// geotiffUnavailable() before anything is drawn when the build has no GDAL). Each file is
/// written to a temporary name and renamed. Throws ExportError.
MosaicResult writeMosaic(const ExportTrack& track, const SurveyExport& survey, const MosaicImages& images,
                         const MosaicOptions& options, const std::string& png_path, const GeoOrigin* origin,
                         const std::string& geotiff_path);

}  // namespace core
}  // namespace uw_multislam
