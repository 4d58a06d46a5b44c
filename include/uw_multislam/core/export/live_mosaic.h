// The live mosaic: a small, downsampled photomosaic of the active map that the
// back-end publishes while the mission runs, the active keyframe outlined.
//
// Three steps, so that the host's lock is held only for copies: LiveMosaicImages keeps the image
// each keyframe carries (today the JPEG thumbnail), fed with every keyframe; liveMosaicSnapshot
// copies the active map's keyframe poses out of the SessionManager's view (call it under the host's
// lock: poses only, the images are shared, not copied); drawLiveMosaic warps and draws the
// snapshot WITHOUT any lock, with the same plane warp as export_survey's mosaics
// (mosaic_geometry.h). Each keyframe is drawn over the earlier ones (no blending, no exposure
// compensation: a preview, export_survey makes the product).
//
// Raster: as mosaic.h's (rows along the map's image-axes y, so it looks as the camera sees it;
// turned into the published map's axes by turnLiveMosaic, north up with a datum),
// at options.resolution_m, coarsened when the map would be larger than max_side_px; the extent is
// the union of the keyframes' full-camera footprints; uncovered pixels are black.
#pragma once

#include <opencv2/core.hpp>

#include <cstddef>
#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/geometry/map_frame.h"
#include "uw_multislam/core/geometry/se2.h"

namespace uw_multislam {
namespace core {

class SessionQueries;

struct LiveMosaicOptions {
  double resolution_m = 0.05;  // metres per pixel of the drawn mosaic
  int max_side_px = 1024;      // a larger map is drawn at a coarser resolution to fit
  std::string validate() const;
};

/// One keyframe to draw: its pose in its map's frame (image axes, the core's convention).
struct LiveMosaicKeyframe {
  int session = 0, keyframe = 0;
  Pose2 pose;
  double altitude_m = 0.0;
  CameraIntrinsics camera;                                // the full image's
  std::shared_ptr<const std::vector<std::uint8_t>> jpeg;  // null or empty: counted missing
};

struct LiveMosaicSnapshot {
  int map = -1;  // -1: nothing to draw (no active session with a keyframe)
  std::vector<LiveMosaicKeyframe> keyframes;
  int active = -1;  // index of the active keyframe (outlined), -1: none
};

struct LiveMosaicImage {
  cv::Mat bgr;  // empty when nothing was drawable
  double resolution_m = 0.0;
  double x0 = 0.0, ytop = 0.0;  // image-axes x of the left edge, y of the top edge (metres)
  int drawn = 0, missing = 0;   // keyframes drawn; without an image or a usable pose/altitude
  double ms = 0.0;
};

/// The images the keyframes carried, per (session, keyframe), with the altitude and camera.
/// Not thread-safe (the host's lock).
///
/// Memory: with a resolution, an image finer on the seabed than the mosaic is
/// ever drawn (resolution_m metres per pixel at the keyframe's altitude; the mosaic only gets
/// coarser, max_side_px) is kept downsampled to that resolution (INTER_AREA, JPEG quality 90), so
/// a long session costs about 1 kB per keyframe instead of its thumbnail's 13 kB (320 x 240) and
/// the drawing decodes less. An image it cannot decode, or one without a usable camera and
/// altitude, is kept as given (drawLiveMosaic counts it missing if it cannot draw it).
class LiveMosaicImages {
 public:
  /// resolution_m <= 0: images kept as given.
  explicit LiveMosaicImages(double resolution_m = 0.0) : resolution_m_(resolution_m) {}
  struct Entry {
    double altitude_m = 0.0;
    CameraIntrinsics camera;
    std::shared_ptr<const std::vector<std::uint8_t>> jpeg;
  };
  void add(int session, int keyframe, double altitude_m, const CameraIntrinsics& camera,
           std::vector<std::uint8_t> jpeg);
  const Entry* find(int session, int keyframe) const;
  /// Forgets the session's images (unload_session, delete_session); returns how many.
  int removeSession(int session);
  std::size_t size() const { return entries_.size(); }
  std::size_t bytes() const { return bytes_; }

 private:
  double resolution_m_ = 0.0;
  std::map<std::pair<int, int>, Entry> entries_;
  std::size_t bytes_ = 0;
};

/// The active session's map: every keyframe of its sessions with its pose in the map, the
/// active session's last keyframe as the active one. Keyframes the images do not know (restored
/// sessions, placeholders) are listed without an image.
LiveMosaicSnapshot liveMosaicSnapshot(const SessionQueries& manager, const LiveMosaicImages& images);

/// The snapshot's poses in the published map's axes (map_frame.h): each image-axes pose p becomes
/// zUp(published <- core) (+) p, the image-axes form of the turn the back-end gives every pose it
/// publishes in `map`. With a datum the mosaic is then drawn north up (rows southward, columns
/// eastward), as rviz shows `map`; without one nothing moves.
void turnLiveMosaic(LiveMosaicSnapshot* snapshot, const MapFrame& frame);

/// Draws a snapshot (no lock needed). A keyframe without a decodable image, or without a finite
/// pose and a positive altitude, is counted missing; a snapshot with no drawable keyframe gives
/// an empty image.
LiveMosaicImage drawLiveMosaic(const LiveMosaicSnapshot& snapshot, const LiveMosaicOptions& options);

}  // namespace core
}  // namespace uw_multislam
