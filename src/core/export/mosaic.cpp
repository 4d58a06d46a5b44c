#include "uw_multislam/core/export/mosaic.h"

#ifdef UWMS_HAVE_GDAL
#include <cpl_conv.h>
#include <gdal_priv.h>
#include <ogr_spatialref.h>
#endif

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/stitching/detail/blenders.hpp>
#include <opencv2/stitching/detail/exposure_compensate.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <iomanip>
#include <list>
#include <memory>
#include <ostream>
#include <sstream>

#include "uw_multislam/core/common/file_identity.h"
#include "uw_multislam/core/export/mosaic_geometry.h"
#include "uw_multislam/core/frontend/image_file.h"

namespace uw_multislam {
namespace core {

const char* mosaicBlendName(MosaicBlend b) {
  switch (b) {
    case MosaicBlend::kFeather:
      return "feather";
    case MosaicBlend::kMultiBand:
      return "multiband";
    case MosaicBlend::kNone:
      return "none";
  }
  return "?";
}

bool parseMosaicBlend(const std::string& name, MosaicBlend* out) {
  for (MosaicBlend b : {MosaicBlend::kFeather, MosaicBlend::kMultiBand, MosaicBlend::kNone}) {
    if (name == mosaicBlendName(b)) {
      *out = b;
      return true;
    }
  }
  return false;
}

std::string MosaicOptions::validate() const {
  if (!(resolution_m >= 0.0) || !std::isfinite(resolution_m))
    return "resolution " + std::to_string(resolution_m) + " m/px: must be positive (0: automatic)";
  if (tile_px < 64 || tile_px > 16384) return "tile size " + std::to_string(tile_px) + " px: must be in [64, 16384]";
  if (!(max_megapixels > 0.0)) return "max_megapixels must be positive";
  if (gdal_cache_mb < 8) return "gdal_cache_mb must be at least 8";
  return "";
}

namespace {

CameraIntrinsics scaledTo(const CameraIntrinsics& c, const cv::Size& size) { return cameraScaledTo(c, size); }

// A keyframe the mosaic can place: finite pose, positive finite altitude and a known camera
// (anything else is a bad store row, or a session an older version stored with a 0x0 camera: left
// out and counted as missing, never a NaN extent). Stored cameras are validated when read, so a
// known one has a focal length of at least a pixel.
bool drawable(const ExportKeyframe& k, const CameraIntrinsics& c) {
  return k.pose.mean.isFinite() && std::isfinite(k.altitude_m) && k.altitude_m > 0.0 && !c.unknown() && c.fx > 0.0 &&
         c.fy > 0.0;
}

// Pixel (u, v, 1) of the image seen through `cam` -> ground point in the map's image axes (the
// store's convention; the exported pose is z-up, hence the signs): mosaic_geometry.h's warp.
cv::Matx23d groundFromPixel(const ExportKeyframe& k, const CameraIntrinsics& cam) {
  return core::groundFromPixel(Pose2(k.pose.mean.x(), -k.pose.mean.y(), -k.pose.mean.yaw()), k.altitude_m, cam);
}

using Raster = MosaicRaster;

cv::Rect2d footprint(const cv::Matx23d& m, const cv::Size& size) { return warpedFootprint(m, size); }

// Decoded images between tiles, least recently used evicted beyond a byte budget.
class ImageCache {
 public:
  struct Entry {
    cv::Mat image;
    CameraIntrinsics camera;
    bool full = false;
  };
  ImageCache(const MosaicImages& images, std::size_t budget, int n)
      : source(static_cast<std::size_t>(n), kNotLoaded), images_(images), budget_(budget) {}
  enum Source : char { kNotLoaded, kNone, kFrame, kThumbnail };
  std::vector<char> source;  // what each keyframe was drawn from
  const Entry& get(int index, const ExportKeyframe& k, const CameraIntrinsics& cam) {
    auto it = where_.find(index);
    if (it != where_.end()) {
      order_.splice(order_.begin(), order_, it->second);
      return it->second->second;
    }
    Entry e;
    e.image = images_.load(k, cam, &e.camera, &e.full);
    source[static_cast<std::size_t>(index)] = e.image.empty() ? kNone : e.full ? kFrame : kThumbnail;
    bytes_ += e.image.total() * e.image.elemSize();
    order_.emplace_front(index, std::move(e));
    where_[index] = order_.begin();
    while (bytes_ > budget_ && order_.size() > 1) {
      const auto& last = order_.back();
      bytes_ -= last.second.image.total() * last.second.image.elemSize();
      where_.erase(last.first);
      order_.pop_back();
    }
    return order_.front().second;
  }

 private:
  const MosaicImages& images_;
  std::size_t budget_, bytes_ = 0;
  std::list<std::pair<int, Entry>> order_;
  std::map<int, std::list<std::pair<int, Entry>>::iterator> where_;
};

// One gain per keyframe and colour channel (cv::detail::ChannelsCompensator: the missions' water
// casts differ by channel) from small warped copies. Its system is
// dense N x N (N^2 x 12 bytes): long tracks are solved in windows of consecutive keyframes (the
// overlaps that matter are between neighbours along the track), each window's gains scaled to
// agree with the previous window's on their shared keyframes.
std::vector<cv::Scalar> exposureGains(const ExportTrack& track, const SurveyExport& survey, const MosaicImages& images,
                                      const Raster& raster) {
  const int n = static_cast<int>(track.keyframes.size());
  std::vector<cv::Scalar> gains(n, cv::Scalar::all(1.0));
  if (n < 2) return gains;
  // A coarse raster: the median keyframe about 48 px wide.
  std::vector<double> widths;
  for (const ExportKeyframe& k : track.keyframes) {
    const CameraIntrinsics& c = survey.camera(k.session);
    if (drawable(k, c)) widths.push_back(c.width * k.altitude_m / c.fx);
  }
  if (widths.size() < 2) return gains;
  std::nth_element(widths.begin(), widths.begin() + widths.size() / 2, widths.end());
  Raster low = raster;
  low.res = std::max(raster.res, widths[widths.size() / 2] / 48.0);
  std::vector<cv::UMat> small(n), masks(n);
  std::vector<cv::Point> corners(n);
  std::vector<bool> ok(n, false);
  for (int i = 0; i < n; ++i) {
    const ExportKeyframe& k = track.keyframes[i];
    if (!drawable(k, survey.camera(k.session))) continue;
    CameraIntrinsics cam;
    const cv::Mat img = images.loadSmall(k, survey.camera(k.session), &cam);
    if (img.empty()) continue;
    cv::Matx23d m = low.fromPixel(groundFromPixel(k, cam));
    const cv::Rect box = pixelBox(footprint(m, img.size()));
    m(0, 2) -= box.x;
    m(1, 2) -= box.y;
    cv::Mat w, mask;
    cv::warpAffine(img, w, m, box.size(), cv::INTER_AREA, cv::BORDER_REPLICATE);
    cv::warpAffine(cv::Mat(img.size(), CV_8U, cv::Scalar(255)), mask, m, box.size(), cv::INTER_NEAREST,
                   cv::BORDER_CONSTANT, cv::Scalar(0));
    w.copyTo(small[i]);
    mask.copyTo(masks[i]);
    corners[i] = box.tl();
    ok[i] = true;
  }
  constexpr int kWindow = 1000, kOverlap = 200;
  for (int start = 0; start < n; start += kWindow - kOverlap) {
    const int end = std::min(n, start + kWindow);
    std::vector<int> ids;
    std::vector<cv::Point> c;
    std::vector<cv::UMat> im;
    std::vector<std::pair<cv::UMat, uchar>> mk;
    for (int i = start; i < end; ++i) {
      if (!ok[i]) continue;
      ids.push_back(i);
      c.push_back(corners[i]);
      im.push_back(small[i]);
      mk.emplace_back(masks[i], static_cast<uchar>(255));
    }
    if (ids.size() >= 2) {
      cv::detail::ChannelsCompensator compensator;
      compensator.feed(c, im, mk);
      const std::vector<cv::Scalar> g = compensator.gains();
      for (int ch = 0; ch < 3; ++ch) {
        double num = 0.0, den = 0.0;
        for (std::size_t j = 0; j < ids.size(); ++j)
          if (start > 0 && ids[j] < start + kOverlap) num += gains[ids[j]][ch], den += g[j][ch];
        const double scale = den > 0.0 ? num / den : 1.0;
        for (std::size_t j = 0; j < ids.size(); ++j) gains[ids[j]][ch] = g[j][ch] * scale;
      }
    }
    if (end == n) break;
  }
  return gains;
}

#ifdef UWMS_HAVE_GDAL
/// The mosaic's raster, tile by tile into a tiled, compressed GeoTIFF, then streamed into the PNG
/// by GDAL's CreateCopy: memory stays within GDAL's capped block cache. GDAL writes by path: it is
/// given the temporaries AtomicFile made (exclusive, no link followed, in the destination's
/// directory) by their /proc/self/fd paths, which reopen those very files whatever their names have
/// become; each is renamed into place by commit(). Without an origin the GeoTIFF is only the PNG's
/// source: its temporary is never renamed (removed with this object).
class RasterFile {
 public:
  RasterFile(const std::string& png_path, const std::string& tif_path, mode_t mode, int width, int height, int cache_mb)
      : png_path_(png_path) {
    GDALAllRegister();
    CPLSetConfigOption("GDAL_CACHEMAX", std::to_string(cache_mb).c_str());
    CPLSetConfigOption("GDAL_PAM_ENABLED", "NO");  // no .aux.xml beside the outputs
    try {
      tif_ = std::make_unique<AtomicFile>(tif_path, mode);
      png_file_ = std::make_unique<AtomicFile>(png_path, mode);
    } catch (const FileWriteError& e) {
      throw ExportError(e.what());
    }
    GDALDriver* gtiff = GetGDALDriverManager()->GetDriverByName("GTiff");
    png_ = GetGDALDriverManager()->GetDriverByName("PNG");
    if (!gtiff || !png_) throw ExportError("GDAL has no GTiff or PNG driver");
    char** create = nullptr;
    create = CSLSetNameValue(create, "TILED", "YES");
    create = CSLSetNameValue(create, "COMPRESS", "DEFLATE");
    create = CSLSetNameValue(create, "PHOTOMETRIC", "RGB");
    create = CSLSetNameValue(create, "ALPHA", "YES");
    create = CSLSetNameValue(create, "BIGTIFF", "IF_SAFER");
    ds_ = gtiff->Create(tif_->reopenPath().c_str(), width, height, 4, GDT_Byte, create);
    CSLDestroy(create);
    if (!ds_)
      throw ExportError(png_path + ": GDAL cannot create its GeoTIFF (" + tif_->temporaryName() +
                        "): " + CPLGetLastErrorMsg());
  }
  RasterFile(const RasterFile&) = delete;
  RasterFile& operator=(const RasterFile&) = delete;
  ~RasterFile() {
    if (ds_) GDALClose(ds_);
    // The AtomicFiles remove their temporaries unless committed.
  }
  void write(const cv::Rect& r, cv::Mat& rgba) {
    if (ds_->RasterIO(GF_Write, r.x, r.y, r.width, r.height, rgba.data, r.width, r.height, GDT_Byte, 4, nullptr, 4,
                      static_cast<GSpacing>(rgba.step), 1, nullptr) != CE_None)
      throw ExportError(png_path_ + ": GDAL cannot write its GeoTIFF (" + tif_->temporaryName() +
                        "): " + CPLGetLastErrorMsg());
  }
  /// A transverse Mercator centred on the origin (WGS84): at survey scale its grid is the local
  /// tangent plane of the GeoJSON tracks to well under a millimetre per kilometre. (x0, y0): the
  /// raster's top-left corner in the z-up map frame.
  void georeference(const GeoOrigin& origin, double x0, double y0, double res) {
    OGRSpatialReference srs;
    srs.SetWellKnownGeogCS("WGS84");
    srs.SetTM(origin.lat_deg, origin.lon_deg, 1.0, 0.0, 0.0);
    srs.SetLinearUnits(SRS_UL_METER, 1.0);
    // Pixel corner (c, r) -> map z-up (x0 + c res, y0 - r res) -> (east, north).
    const double hd = origin.heading_deg * M_PI / 180.0, sh = std::sin(hd), chd = std::cos(hd);
    double gt[6] = {x0 * sh - y0 * chd, res * sh, res * chd, x0 * chd + y0 * sh, res * chd, -res * sh};
    ds_->SetGeoTransform(gt);
    ds_->SetSpatialRef(&srs);
  }
  /// Completes the PNG's temporary from the GeoTIFF's (nothing renamed yet).
  void finish() {
    GDALClose(ds_);
    ds_ = nullptr;
    GDALDataset* src = static_cast<GDALDataset*>(GDALOpen(tif_->reopenPath().c_str(), GA_ReadOnly));
    if (!src) throw ExportError(png_path_ + ": GDAL cannot reopen its GeoTIFF (" + tif_->temporaryName() + ")");
    char** copy = CSLSetNameValue(nullptr, "WORLDFILE", "NO");
    GDALDataset* out = png_->CreateCopy(png_file_->reopenPath().c_str(), src, FALSE, copy, nullptr, nullptr);
    CSLDestroy(copy);
    GDALClose(src);
    if (!out) throw ExportError(png_path_ + ": GDAL cannot write the PNG: " + CPLGetLastErrorMsg());
    GDALClose(out);
  }
  /// Renames the PNG into place, and the GeoTIFF when `keep_geotiff`.
  void commit(bool keep_geotiff) {
    try {
      png_file_->commit();
      if (keep_geotiff) tif_->commit();
    } catch (const FileWriteError& e) {
      throw ExportError(e.what());
    }
  }

 private:
  std::string png_path_;
  std::unique_ptr<AtomicFile> tif_, png_file_;
  GDALDriver* png_ = nullptr;
  GDALDataset* ds_ = nullptr;
};
#else
/// Without GDAL: the raster in memory (4 bytes a pixel, at most kMaxPixels), encoded once by
/// OpenCV's PNG encoder into the PNG's AtomicFile; no GeoTIFF (geotiffUnavailable()).
class RasterFile {
 public:
  RasterFile(const std::string& png_path, const std::string& /*tif_path: GDAL's*/, mode_t mode, int width, int height,
             int /*cache_mb: GDAL's*/)
      : png_path_(png_path) {
    if (static_cast<double>(width) * height > kMaxPixels)
      throw ExportError(png_path + ": " + std::to_string(width) + " x " + std::to_string(height) +
                        " px is more than a build without GDAL assembles in memory (" +
                        std::to_string(static_cast<int>(kMaxPixels / 1e6)) +
                        " megapixels; GDAL streams it to disk): give a coarser --resolution");
    try {
      png_file_ = std::make_unique<AtomicFile>(png_path, mode);
    } catch (const FileWriteError& e) {
      throw ExportError(e.what());
    }
    rgba_.create(height, width, CV_8UC4);
  }
  RasterFile(const RasterFile&) = delete;
  RasterFile& operator=(const RasterFile&) = delete;
  void write(const cv::Rect& r, cv::Mat& rgba) { rgba.copyTo(rgba_(r)); }
  void georeference(const GeoOrigin&, double, double, double) { throw ExportError(geotiffUnavailable()); }
  void finish() {
    cv::Mat bgra;
    cv::cvtColor(rgba_, bgra, cv::COLOR_RGBA2BGRA);
    rgba_.release();
    std::vector<uchar> bytes;
    bool ok = false;
    try {
      ok = cv::imencode(".png", bgra, bytes);
    } catch (const cv::Exception& e) {
      throw ExportError(png_path_ + ": cannot encode the PNG: " + e.what());
    }
    if (!ok) throw ExportError(png_path_ + ": cannot encode the PNG");
    png_file_->stream().write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
  }
  void commit(bool keep_geotiff) {
    if (keep_geotiff) throw ExportError(png_path_ + ": " + geotiffUnavailable());
    try {
      png_file_->commit();
    } catch (const FileWriteError& e) {
      throw ExportError(e.what());
    }
  }

 private:
  static constexpr double kMaxPixels = 256e6;  // 1 GiB of RGBA
  std::string png_path_;
  std::unique_ptr<AtomicFile> png_file_;
  cv::Mat rgba_;
};
#endif

}  // namespace

std::string geotiffUnavailable() {
#ifdef UWMS_HAVE_GDAL
  return std::string();
#else
  return "GeoTIFF export needs GDAL, and this build has none (install libgdal-dev, or GDAL >= 3.0, and rebuild); "
         "the mosaic's PNG, its world file and the other files are written without it";
#endif
}

void MosaicImages::addDataset(const std::string& directory) {
  datasets_.push_back(loadDataset(directory));
  row_of_index_.emplace_back();
  for (std::size_t i = 0; i < datasets_.back().frames.size(); ++i)
    row_of_index_.back()[datasets_.back().frames[i].index] = static_cast<int>(i);
}

const FrameRecord* MosaicImages::frameOf(int dataset, const ExportKeyframe& k) const {
  const auto it = row_of_index_[dataset].find(k.frame_index);
  if (it == row_of_index_[dataset].end()) return nullptr;
  const FrameRecord& f = datasets_[dataset].frames[it->second];
  return std::abs(f.stamp_s - k.stamp_s) <= 1e-6 ? &f : nullptr;
}

std::vector<std::string> MosaicImages::matchSessions(const SurveyExport& survey) {
  std::vector<std::string> lines;
  // The folder the session is named after: the same directory (its identity: any path to it, a
  // link or a bind mount too), or, when the name no longer exists as given, the same path text.
  auto same = [](const std::string& a, const std::string& b) {
    FileId x, y;
    if (fileIdOf(a, &x) && fileIdOf(b, &y)) return x == y;
    std::error_code ec;
    return std::filesystem::weakly_canonical(a, ec) == std::filesystem::weakly_canonical(b, ec);
  };
  for (const ExportTrack& s : survey.sessions) {
    // Most keyframes found; among equals (simulated missions share stamps and indexes), the
    // folder the session is named after (offline_slam names a session by its folder).
    int best = -1, best_n = 0, ties = 0, other_size = 0;
    bool best_named = false;
    const CameraIntrinsics* cam = survey.findCamera(s.sessions.front());
    if (cam && cam->unknown()) cam = nullptr;  // not "another size"
    for (int d = 0; d < static_cast<int>(datasets_.size()); ++d) {
      // Frames are matched by stamp and index, which another mission can share (simulated ones
      // do, and any counter from 0): a folder whose images are not the session camera's size
      // holds another camera's frames and is never drawn into this session's mosaic.
      const CameraIntrinsics& dc = datasets_[d].camera;
      if (cam && (dc.width != cam->width || dc.height != cam->height)) {
        ++other_size;
        continue;
      }
      int n = 0;
      for (const ExportKeyframe& k : s.keyframes) n += frameOf(d, k) != nullptr;
      const bool named = same(datasets_[d].directory, s.name);
      if (n == 0) continue;
      if (n > best_n || (n == best_n && named && !best_named)) {
        ties = n == best_n ? ties : 0;
        best = d, best_n = n, best_named = named;
      } else if (n == best_n && named == best_named) {
        ++ties;
      }
    }
    if (best >= 0) dataset_of_session_[s.sessions.front()] = best;
    std::string line = s.label + " (" + s.name + "): ";
    if (best < 0) {
      line += "no folder holds its keyframes (thumbnails drawn)";
    } else {
      line += datasets_[best].directory + ", " + std::to_string(best_n) + " of " + std::to_string(s.keyframes.size()) +
              " keyframes";
      if (ties > 0)
        line += " (ambiguous: " + std::to_string(ties) + " other folders hold them as well; the first taken)";
    }
    if (other_size > 0 && cam)
      line += "; " + std::to_string(other_size) + " folder(s) of images other than its camera's " +
              std::to_string(cam->width) + "x" + std::to_string(cam->height) + " left out";
    lines.push_back(line);
  }
  return lines;
}

cv::Mat MosaicImages::frame(const ExportKeyframe& k, const CameraIntrinsics& camera, CameraIntrinsics* scaled) const {
  const auto it = dataset_of_session_.find(k.session);
  if (it == dataset_of_session_.end()) return {};
  const FrameRecord* f = frameOf(it->second, k);
  if (!f) return {};
  cv::Mat img = readFrameImageBgr(datasets_[it->second].imagePath(*f));
  if (!img.empty()) *scaled = scaledTo(camera, img.size());
  return img;
}

cv::Mat MosaicImages::thumbnail(const ExportKeyframe& k, const CameraIntrinsics& camera, CameraIntrinsics* scaled) {
  if (k.thumbnail.empty()) return {};
  cv::Mat img = cv::imdecode(k.thumbnail, cv::IMREAD_COLOR);
  // The thumbnail is the whole image resized (session_store.h): the camera scales with it.
  if (!img.empty()) *scaled = scaledTo(camera, img.size());
  return img;
}

cv::Mat MosaicImages::load(const ExportKeyframe& k, const CameraIntrinsics& camera, CameraIntrinsics* scaled,
                           bool* full) const {
  cv::Mat img = frame(k, camera, scaled);
  *full = !img.empty();
  return *full ? img : thumbnail(k, camera, scaled);
}

cv::Mat MosaicImages::loadSmall(const ExportKeyframe& k, const CameraIntrinsics& camera,
                                CameraIntrinsics* scaled) const {
  cv::Mat img = thumbnail(k, camera, scaled);
  return img.empty() ? frame(k, camera, scaled) : img;
}

MosaicResult writeMosaic(const ExportTrack& track, const SurveyExport& survey, const MosaicImages& images,
                         const MosaicOptions& options, const std::string& png_path, const GeoOrigin* origin,
                         const std::string& geotiff_path) {
  const auto t0 = std::chrono::steady_clock::now();
  if (const std::string why = options.validate(); !why.empty()) throw ExportError("mosaic: " + why);
  if (track.keyframes.empty()) throw ExportError(png_path + ": " + track.label + " has no keyframes");
  MosaicResult result;
  const int n = static_cast<int>(track.keyframes.size());
  // Resolution: given, or the median keyframe's ground pixel of the images drawn.
  Raster raster;
  raster.res = options.resolution_m;
  if (raster.res <= 0.0) {
    std::vector<double> px;
    // A stored image's ground pixel grows by camera width / stored width. The stored size is set
    // per run (config `store`), so one decoded image per session gives it.
    std::map<std::int64_t, double> stored_scale;
    auto storedScale = [&](const ExportKeyframe& k, const CameraIntrinsics& c) {
      auto it = stored_scale.find(k.session);
      if (it != stored_scale.end()) return it->second;
      const cv::Mat img = cv::imdecode(k.thumbnail, cv::IMREAD_GRAYSCALE);
      const double scale = img.empty() ? 1.0 : static_cast<double>(c.width) / img.cols;
      if (!img.empty()) stored_scale[k.session] = scale;
      return scale;
    };
    for (const ExportKeyframe& k : track.keyframes) {
      const CameraIntrinsics& c = survey.camera(k.session);
      if (!drawable(k, c)) continue;
      const double scale = images.hasDatasets() || k.thumbnail.empty() ? 1.0 : storedScale(k, c);
      px.push_back(k.altitude_m / c.fx * scale);
    }
    if (px.empty())
      throw ExportError(png_path + ": no keyframe of " + track.label + " has a valid pose, altitude and stored camera");
    std::nth_element(px.begin(), px.begin() + px.size() / 2, px.end());
    raster.res = px[px.size() / 2];
  }
  // Extent: every footprint (the full camera's corners).
  std::vector<cv::Rect2d> ground(n);
  double x_lo = 1e300, x_hi = -1e300, y_lo = 1e300, y_hi = -1e300;
  for (int i = 0; i < n; ++i) {
    const ExportKeyframe& k = track.keyframes[i];
    const CameraIntrinsics& c = survey.camera(k.session);
    if (!drawable(k, c)) continue;
    ground[i] = footprint(groundFromPixel(k, c), cv::Size(c.width, c.height));
    x_lo = std::min(x_lo, ground[i].x);
    y_lo = std::min(y_lo, ground[i].y);
    x_hi = std::max(x_hi, ground[i].x + ground[i].width);
    y_hi = std::max(y_hi, ground[i].y + ground[i].height);
  }
  if (x_lo > x_hi)
    throw ExportError(png_path + ": no keyframe of " + track.label + " has a valid pose, altitude and stored camera");
  raster.x0 = x_lo;
  raster.ytop = y_lo;
  const double w = std::ceil((x_hi - x_lo) / raster.res), h = std::ceil((y_hi - y_lo) / raster.res);
  if (!(w * h <= options.max_megapixels * 1e6)) {
    // Sizes past any integer (--resolution 1e-300) in exponent form, the others whole.
    const auto px = [](double v) {
      std::ostringstream os;
      if (v < 1e15) os << std::fixed << std::setprecision(0);
      os << v;
      return os.str();
    };
    std::ostringstream os;
    os << png_path << ": " << px(w) << " x " << px(h) << " px at " << raster.res << " m/px is more than "
       << options.max_megapixels << " megapixels: give a coarser --resolution";
    throw ExportError(os.str());
  }
  raster.width = std::max(1, static_cast<int>(w));
  raster.height = std::max(1, static_cast<int>(h));
  result.width = raster.width;
  result.height = raster.height;
  result.resolution_m = raster.res;
  result.x0 = raster.x0;
  result.y0 = -raster.ytop;
  result.keyframes = n;

  const std::vector<cv::Scalar> gains = options.exposure ? exposureGains(track, survey, images, raster)
                                                         : std::vector<cv::Scalar>(n, cv::Scalar::all(1.0));

  // Tiles and the keyframes touching each (with the blending margin).
  const int tile = options.tile_px;
  const int margin = options.blend == MosaicBlend::kMultiBand ? 128 : options.blend == MosaicBlend::kFeather ? 52 : 0;
  const int nx = (raster.width + tile - 1) / tile, ny = (raster.height + tile - 1) / tile;
  std::vector<std::vector<int>> touching(static_cast<std::size_t>(nx) * ny);
  std::vector<cv::Rect> box(n);
  for (int i = 0; i < n; ++i) {
    const ExportKeyframe& k = track.keyframes[i];
    if (!drawable(k, survey.camera(k.session))) continue;  // counted missing: never loaded
    const cv::Rect2d r((ground[i].x - raster.x0) / raster.res - 0.5, (ground[i].y - raster.ytop) / raster.res - 0.5,
                       ground[i].width / raster.res, ground[i].height / raster.res);
    box[i] = pixelBox(r);
    const int tx0 = std::max(0, (box[i].x - margin) / tile), tx1 = std::min(nx - 1, (box[i].br().x + margin) / tile);
    const int ty0 = std::max(0, (box[i].y - margin) / tile), ty1 = std::min(ny - 1, (box[i].br().y + margin) / tile);
    for (int ty = ty0; ty <= ty1; ++ty)
      for (int tx = tx0; tx <= tx1; ++tx) touching[static_cast<std::size_t>(ty) * nx + tx].push_back(i);
  }

  if (origin && !geotiffUnavailable().empty()) throw ExportError(geotiff_path + ": " + geotiffUnavailable());
  // Its temporaries go with it unless committed.
  RasterFile out(png_path, origin ? geotiff_path : png_path + ".tif", survey.modes.file, raster.width, raster.height,
                 options.gdal_cache_mb);
  {
    ImageCache cache(images, options.cache_bytes, n);
    double seam_sum = 0.0, all_sum = 0.0;
    long long seam_n = 0, all_n = 0;
    for (int ty = 0; ty < ny; ++ty) {
      for (int tx = 0; tx < nx; ++tx) {
        const cv::Rect core(tx * tile, ty * tile, std::min(tile, raster.width - tx * tile),
                            std::min(tile, raster.height - ty * tile));
        const cv::Rect region(core.x - margin, core.y - margin, core.width + 2 * margin, core.height + 2 * margin);
        const std::vector<int>& list = touching[static_cast<std::size_t>(ty) * nx + tx];
        cv::Mat rgba(core.size(), CV_8UC4, cv::Scalar::all(0));
        cv::Mat coverage(region.size(), CV_16U, cv::Scalar(0));
        std::unique_ptr<cv::detail::Blender> blender;
        if (options.blend == MosaicBlend::kFeather) blender = std::make_unique<cv::detail::FeatherBlender>();
        if (options.blend == MosaicBlend::kMultiBand) blender = std::make_unique<cv::detail::MultiBandBlender>();
        cv::Mat plain(region.size(), CV_8UC3, cv::Scalar::all(0)), plain_mask(region.size(), CV_8U, cv::Scalar(0));
        if (blender) blender->prepare(region);
        int fed = 0;
        for (int i : list) {
          const cv::Rect b = box[i] & region;
          if (b.empty()) continue;
          const ExportKeyframe& k = track.keyframes[i];
          const ImageCache::Entry& e = cache.get(i, k, survey.camera(k.session));
          if (e.image.empty()) continue;
          cv::Matx23d m = raster.fromPixel(groundFromPixel(k, e.camera));
          m(0, 2) -= b.x;
          m(1, 2) -= b.y;
          cv::Mat warped, mask;
          cv::warpAffine(e.image, warped, m, b.size(), cv::INTER_LINEAR, cv::BORDER_REPLICATE);
          cv::warpAffine(cv::Mat(e.image.size(), CV_8U, cv::Scalar(255)), mask, m, b.size(), cv::INTER_NEAREST,
                         cv::BORDER_CONSTANT, cv::Scalar(0));
          if (cv::countNonZero(mask) == 0) continue;
          const cv::Rect local(b.tl() - region.tl(), b.size());
          cv::add(coverage(local), cv::Scalar(1), coverage(local), mask);
          if (blender) {
            cv::Mat w16;
            cv::multiply(warped, gains[i], w16, 1.0, CV_16SC3);
            blender->feed(w16, mask, b.tl());
          } else {
            cv::Mat w8;
            cv::multiply(warped, gains[i], w8, 1.0, CV_8UC3);
            w8.copyTo(plain(local), mask);
            plain_mask(local).setTo(255, mask);
          }
          ++fed;
        }
        if (fed > 0) {
          cv::Mat out8, out_mask;
          if (blender) {
            cv::Mat dst, dst_mask;
            blender->blend(dst, dst_mask);
            dst.convertTo(out8, CV_8UC3);
            out_mask = dst_mask;
          } else {
            out8 = plain;
            out_mask = plain_mask;
          }
          const cv::Rect inner(margin, margin, core.width, core.height);
          cv::Mat bgr = out8(inner), alpha = out_mask(inner).clone(), cov = coverage(inner);
          alpha.setTo(0, cov == 0);  // multi-band blending spreads its mask; only drawn pixels count
          cv::cvtColor(bgr, rgba, cv::COLOR_BGR2RGBA);
          std::vector<cv::Mat> ch;
          cv::split(rgba, ch);
          ch[3] = alpha;
          ch[0].setTo(0, alpha == 0);
          ch[1].setTo(0, alpha == 0);
          ch[2].setTo(0, alpha == 0);
          cv::merge(ch, rgba);
          // Seam measure: gradient on the edges between coverage counts, against all covered pixels.
          cv::Mat gray, gx, gy, grad;
          cv::cvtColor(bgr, gray, cv::COLOR_BGR2GRAY);
          cv::Sobel(gray, gx, CV_32F, 1, 0);
          cv::Sobel(gray, gy, CV_32F, 0, 1);
          grad = cv::abs(gx) + cv::abs(gy);
          cv::Mat inside;
          cv::erode(alpha, inside, cv::Mat::ones(5, 5, CV_8U));
          for (int r = 0; r + 1 < cov.rows; ++r) {
            const auto* c0 = cov.ptr<std::uint16_t>(r);
            const auto* c1 = cov.ptr<std::uint16_t>(r + 1);
            const auto* in = inside.ptr<uchar>(r);
            const auto* g = grad.ptr<float>(r);
            for (int c = 0; c + 1 < cov.cols; ++c) {
              if (!in[c]) continue;
              all_sum += g[c];
              ++all_n;
              if (c0[c] != c0[c + 1] || c0[c] != c1[c]) {
                seam_sum += g[c];
                ++seam_n;
              }
            }
          }
        }
        out.write(core, rgba);
        ++result.tiles;
      }
    }
    result.seam_ratio = seam_n > 0 && all_n > 0 && all_sum > 0.0 ? (seam_sum / seam_n) / (all_sum / all_n) : 0.0;
    for (char c : cache.source) {
      result.from_frames += c == ImageCache::kFrame;
      result.from_thumbnails += c == ImageCache::kThumbnail;
      result.missing += c == ImageCache::kNone || c == ImageCache::kNotLoaded;
    }
    if (origin) out.georeference(*origin, result.x0, result.y0, raster.res);
    out.finish();
    // World file: pixel size, rotation terms, then the centre of the upper-left pixel (z-up map frame).
    std::filesystem::path world(png_path);
    world.replace_extension(".pgw");
    writeExportFile(world.string(), survey.modes.file, [&](std::ostream& f) {
      f << std::setprecision(12) << raster.res << "\n0\n0\n"
        << -raster.res << "\n"
        << result.x0 + raster.res / 2.0 << "\n"
        << result.y0 - raster.res / 2.0 << "\n";
    });
    out.commit(origin != nullptr);
  }
  result.ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return result;
}

}  // namespace core
}  // namespace uw_multislam
