#include "uw_multislam/core/export/track_files.h"

#include <algorithm>
#include <filesystem>

namespace uw_multislam {
namespace core {

TrackFiles writeTrackFiles(const ExportTrack& t, const SurveyExport& survey, const MosaicImages& images,
                           const std::string& directory, const TrackFilesOptions& options) {
  TrackFiles out;
  const std::string base = (std::filesystem::path(directory) / t.label).string();
  auto wrote = [&](const std::string& ext) { out.files.push_back(base + ext); };
  const mode_t mode = survey.modes.file;  // the store's permissions (0600 for a 0600 store)
  writeTum(base + ".tum", t, mode);
  wrote(".tum");
  writeKitti(base + ".kitti", t, mode);
  wrote(".kitti");
  writeTrackCsv(base + ".csv", t, mode);
  wrote(".csv");
  writeG2o(base + ".g2o", t, mode);
  wrote(".g2o");
  if (options.origin) {
    std::vector<const ExportTrack*> sessions;  // the track's sessions, one GeoJSON feature each
    for (std::int64_t id : t.sessions)
      for (const ExportTrack& s : survey.sessions)
        if (s.sessions.front() == id) sessions.push_back(&s);
    writeGeoJson(base + ".geojson", sessions, *options.origin, mode);
    wrote(".geojson");
  }
  if (!options.mosaic) return out;
  // A track all of whose sessions were stored without a camera (0x0, older stores) cannot be
  // drawn: its other files are written, the mosaic is left out with the reason.
  const bool any_camera = std::any_of(t.sessions.begin(), t.sessions.end(), [&](std::int64_t id) {
    const CameraIntrinsics* c = survey.findCamera(id);
    return c && !c->unknown();
  });
  if (!any_camera) {
    out.no_mosaic = "no session of " + t.label + " has a stored camera (0x0, written by an older version)";
    return out;
  }
  // A build without GDAL draws the PNG and refuses only the GeoTIFF, saying why.
  const GeoOrigin* geotiff_origin = options.origin;
  if (options.origin && !geotiffUnavailable().empty()) {
    out.no_geotiff = geotiffUnavailable();
    geotiff_origin = nullptr;
  }
  out.mosaic_result =
      writeMosaic(t, survey, images, options.mosaic_options, base + ".png", geotiff_origin, base + ".tif");
  out.mosaic = true;
  wrote(".png");
  wrote(".pgw");
  if (geotiff_origin) wrote(".tif");
  return out;
}

}  // namespace core
}  // namespace uw_multislam
