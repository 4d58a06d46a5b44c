#include "uw_multislam/core/export/live_mosaic.h"

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>

#include "uw_multislam/core/export/mosaic_geometry.h"
#include "uw_multislam/core/geometry/vehicle_frame.h"
#include "uw_multislam/core/session/session_manager.h"

namespace uw_multislam {
namespace core {

std::string LiveMosaicOptions::validate() const {
  if (!(resolution_m > 0.0) || !std::isfinite(resolution_m))
    return "mosaic resolution " + std::to_string(resolution_m) + " m/px: must be positive";
  if (max_side_px < 16 || max_side_px > 8192)
    return "mosaic max side " + std::to_string(max_side_px) + " px: must be in [16, 8192]";
  return "";
}

namespace {

// Pixels of an image per mosaic pixel, at most: the drawing's warp interpolates (bilinear)
// without averaging, so a finer image would alias its texture, and one at exactly the mosaic's
// resolution would come out blurred by the warp's sub-pixel shifts; at twice the resolution the
// drawing stays close to the ideal (gtest LiveMosaic.ImagesAreKeptAtTheMosaicsResolution...).
constexpr double kOversample = 2.0;

bool usable(double altitude_m, const CameraIntrinsics& c) {
  return std::isfinite(altitude_m) && altitude_m > 0.0 && c.width > 0 && c.height > 0 && c.fx > 0.0 && c.fy > 0.0;
}

// `img` (the whole camera image, resized) area-averaged down to kOversample pixels per
// `resolution_m` on the seabed when it is finer; else `img` itself.
cv::Mat prefiltered(const cv::Mat& img, double altitude_m, const CameraIntrinsics& c, double resolution_m) {
  const double ground = std::min(altitude_m / c.fx * c.width / img.cols, altitude_m / c.fy * c.height / img.rows);
  const double f = kOversample * ground / resolution_m;
  if (!(f < 1.0)) return img;
  cv::Mat small;
  cv::resize(img, small,
             cv::Size(std::max(1, static_cast<int>(std::lround(img.cols * f))),
                      std::max(1, static_cast<int>(std::lround(img.rows * f)))),
             0, 0, cv::INTER_AREA);
  return small;
}

// The image kept at the mosaic's resolution when it is finer (see LiveMosaicImages).
std::vector<std::uint8_t> atResolution(std::vector<std::uint8_t> jpeg, double altitude_m, const CameraIntrinsics& c,
                                       double resolution_m) {
  if (!(resolution_m > 0.0) || !usable(altitude_m, c) || jpeg.empty()) return jpeg;
  cv::Mat img;
  try {
    img = cv::imdecode(jpeg, cv::IMREAD_UNCHANGED);
  } catch (const cv::Exception&) {
  }
  if (img.empty()) return jpeg;
  const cv::Mat small = prefiltered(img, altitude_m, c, resolution_m);
  if (small.size() == img.size()) return jpeg;
  std::vector<std::uint8_t> out;
  cv::imencode(".jpg", small, out, {cv::IMWRITE_JPEG_QUALITY, 90});
  return out.size() < jpeg.size() ? out : jpeg;
}

}  // namespace

void LiveMosaicImages::add(int session, int keyframe, double altitude_m, const CameraIntrinsics& camera,
                           std::vector<std::uint8_t> jpeg) {
  jpeg = atResolution(std::move(jpeg), altitude_m, camera, resolution_m_);
  Entry& e = entries_[{session, keyframe}];
  if (e.jpeg) bytes_ -= e.jpeg->size();
  bytes_ += jpeg.size();
  e.altitude_m = altitude_m;
  e.camera = camera;
  e.jpeg = std::make_shared<const std::vector<std::uint8_t>>(std::move(jpeg));
}

int LiveMosaicImages::removeSession(int session) {
  const auto first = entries_.lower_bound({session, std::numeric_limits<int>::min()});
  const auto last = entries_.lower_bound({session + 1, std::numeric_limits<int>::min()});
  int n = 0;
  for (auto it = first; it != last; ++it, ++n) bytes_ -= it->second.jpeg ? it->second.jpeg->size() : 0;
  entries_.erase(first, last);
  return n;
}

const LiveMosaicImages::Entry* LiveMosaicImages::find(int session, int keyframe) const {
  const auto it = entries_.find({session, keyframe});
  return it == entries_.end() ? nullptr : &it->second;
}

void turnLiveMosaic(LiveMosaicSnapshot* snapshot, const MapFrame& frame) {
  if (frame.isIdentity()) return;
  const Pose2 turn = zUp(frame.publishedFromCore());
  for (LiveMosaicKeyframe& k : snapshot->keyframes) k.pose = compose(turn, k.pose);
}

LiveMosaicSnapshot liveMosaicSnapshot(const SessionQueries& manager, const LiveMosaicImages& images) {
  LiveMosaicSnapshot out;
  const int active = manager.activeSession();
  if (active < 0 || !manager.has(active) || !manager.hasKeyframe(active)) return out;
  out.map = manager.mapOf(active);
  for (int id : manager.sessionIds()) {
    if (manager.mapOf(id) != out.map || !manager.hasKeyframe(id)) continue;
    const std::vector<Pose2> poses = manager.poses(id);
    for (std::size_t k = 0; k < poses.size(); ++k) {
      LiveMosaicKeyframe kf;
      kf.session = id;
      kf.keyframe = static_cast<int>(k);
      kf.pose = poses[k];
      if (const LiveMosaicImages::Entry* e = images.find(id, kf.keyframe)) {
        kf.altitude_m = e->altitude_m;
        kf.camera = e->camera;
        kf.jpeg = e->jpeg;
      }
      if (id == active && k + 1 == poses.size()) out.active = static_cast<int>(out.keyframes.size());
      out.keyframes.push_back(std::move(kf));
    }
  }
  return out;
}

namespace {

bool drawable(const LiveMosaicKeyframe& k) { return k.pose.isFinite() && usable(k.altitude_m, k.camera); }

}  // namespace

LiveMosaicImage drawLiveMosaic(const LiveMosaicSnapshot& snapshot, const LiveMosaicOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  LiveMosaicImage out;
  const int n = static_cast<int>(snapshot.keyframes.size());
  // Extent: every drawable keyframe's full-camera footprint (mosaic.cpp's rule).
  double x_lo = 1e300, x_hi = -1e300, y_lo = 1e300, y_hi = -1e300;
  for (const LiveMosaicKeyframe& k : snapshot.keyframes) {
    if (!drawable(k)) continue;
    const cv::Rect2d g =
        warpedFootprint(groundFromPixel(k.pose, k.altitude_m, k.camera), cv::Size(k.camera.width, k.camera.height));
    x_lo = std::min(x_lo, g.x);
    y_lo = std::min(y_lo, g.y);
    x_hi = std::max(x_hi, g.x + g.width);
    y_hi = std::max(y_hi, g.y + g.height);
  }
  if (x_lo > x_hi) {
    out.missing = n;
    return out;
  }
  MosaicRaster raster;
  raster.x0 = x_lo;
  raster.ytop = y_lo;
  raster.res = std::max(options.resolution_m, std::max(x_hi - x_lo, y_hi - y_lo) / options.max_side_px);
  // ceil, less a rounding's worth: a coarsened map is exactly max_side_px wide, not one more.
  raster.width = std::max(1, static_cast<int>(std::ceil((x_hi - x_lo) / raster.res - 1e-9)));
  raster.height = std::max(1, static_cast<int>(std::ceil((y_hi - y_lo) / raster.res - 1e-9)));
  out.bgr = cv::Mat(raster.height, raster.width, CV_8UC3, cv::Scalar::all(0));
  out.resolution_m = raster.res;
  out.x0 = raster.x0;
  out.ytop = raster.ytop;
  const cv::Rect canvas(0, 0, raster.width, raster.height);
  for (const LiveMosaicKeyframe& k : snapshot.keyframes) {
    cv::Mat img;
    if (drawable(k) && k.jpeg && !k.jpeg->empty()) img = cv::imdecode(*k.jpeg, cv::IMREAD_COLOR);
    if (img.empty()) {
      ++out.missing;
      continue;
    }
    img = prefiltered(img, k.altitude_m, k.camera, raster.res);  // no aliasing in a coarse mosaic
    const CameraIntrinsics cam = cameraScaledTo(k.camera, img.size());
    cv::Matx23d m = raster.fromPixel(groundFromPixel(k.pose, k.altitude_m, cam));
    const cv::Rect b = pixelBox(warpedFootprint(m, img.size())) & canvas;
    if (b.empty()) {
      ++out.missing;
      continue;
    }
    m(0, 2) -= b.x;
    m(1, 2) -= b.y;
    cv::Mat warped, mask;
    cv::warpAffine(img, warped, m, b.size(), cv::INTER_AREA, cv::BORDER_REPLICATE);
    cv::warpAffine(cv::Mat(img.size(), CV_8U, cv::Scalar(255)), mask, m, b.size(), cv::INTER_NEAREST,
                   cv::BORDER_CONSTANT, cv::Scalar(0));
    warped.copyTo(out.bgr(b), mask);
    ++out.drawn;
  }
  if (snapshot.active >= 0 && snapshot.active < n && drawable(snapshot.keyframes[snapshot.active])) {
    // The active keyframe's full image outline, in red, over everything.
    const LiveMosaicKeyframe& k = snapshot.keyframes[snapshot.active];
    const cv::Matx23d m = raster.fromPixel(groundFromPixel(k.pose, k.altitude_m, k.camera));
    std::vector<cv::Point> corners;
    for (const cv::Point2d p :
         {cv::Point2d(-0.5, -0.5), cv::Point2d(k.camera.width - 0.5, -0.5),
          cv::Point2d(k.camera.width - 0.5, k.camera.height - 0.5), cv::Point2d(-0.5, k.camera.height - 0.5)})
      corners.emplace_back(cvRound(m(0, 0) * p.x + m(0, 1) * p.y + m(0, 2)),
                           cvRound(m(1, 0) * p.x + m(1, 1) * p.y + m(1, 2)));
    const int thickness = std::max(1, std::max(raster.width, raster.height) / 300);
    cv::polylines(out.bgr, corners, true, cv::Scalar(0, 0, 255), thickness, cv::LINE_8);
  }
  out.ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return out;
}

}  // namespace core
}  // namespace uw_multislam
