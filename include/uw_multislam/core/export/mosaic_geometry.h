// The plane warp of the photomosaics (mosaic.h, "Geometry" and "Raster"), in one place for
// export_survey's tiled mosaics (mosaic.cpp, library uw_multislam_export) and the back-end's live
// mosaic (live_mosaic.h, in the core the nodelets load, without GDAL).
#pragma once

#include <opencv2/core.hpp>

#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/geometry/se2.h"

namespace uw_multislam {
namespace core {

/// The camera `c` resized to `size` (a thumbnail is the whole image resized): pixel centres map
/// edge to edge.
CameraIntrinsics cameraScaledTo(const CameraIntrinsics& c, const cv::Size& size);

/// Pixel (u, v, 1) of an image seen through `camera` -> the seabed point in the map's image axes
/// (the core's convention: `pose` is the ground point under the principal point, in image axes,
/// z into the seabed) for a nadir camera at `altitude_m`: an affine map (mosaic.h, "Geometry").
cv::Matx23d groundFromPixel(const Pose2& pose, double altitude_m, const CameraIntrinsics& camera);

/// The axis-aligned box of the image corners (pixel edges) of a `size` image under `m`.
cv::Rect2d warpedFootprint(const cv::Matx23d& m, const cv::Size& size);

/// The pixels a footprint in pixel-centre coordinates touches.
cv::Rect pixelBox(const cv::Rect2d& r);

/// A raster over the ground (image axes): column c, row r is the point (x0 + (c + 0.5) res,
/// ytop + (r + 0.5) res); rows run along image-axes y.
struct MosaicRaster {
  double x0 = 0.0, ytop = 0.0;  // image-axes x of the left edge, image-axes y of the top edge
  double res = 0.0;
  int width = 0, height = 0;
  /// ground <- pixel of an image  ->  raster pixel <- pixel of that image.
  cv::Matx23d fromPixel(const cv::Matx23d& ground) const {
    cv::Matx23d m = ground * (1.0 / res);
    m(0, 2) -= x0 / res + 0.5;
    m(1, 2) -= ytop / res + 0.5;
    return m;
  }
};

}  // namespace core
}  // namespace uw_multislam
