// The files of one exported track (a session or a map): what export_survey writes per track and
// the back-end's `export` service writes for the track it is asked for (doc/tools/
// export_survey.md): <label>.tum, .kitti, .csv, .g2o, .geojson (with an origin), .png + .pgw (mosaic) and
// .tif (mosaic with an origin). Each file is written atomically (survey_export.h).
#pragma once

#include <string>
#include <vector>

#include "uw_multislam/core/export/mosaic.h"
#include "uw_multislam/core/export/survey_export.h"

namespace uw_multislam {
namespace core {

struct TrackFilesOptions {
  bool mosaic = true;
  MosaicOptions mosaic_options;
  const GeoOrigin* origin = nullptr;  // GeoJSON and GeoTIFF when set
};

struct TrackFiles {
  std::vector<std::string> files;  // the paths written, in order
  bool mosaic = false;             // whether `mosaic` below was drawn
  std::string no_mosaic;           // why it was not, when asked for but not drawn
  std::string no_geotiff;          // why the mosaic's GeoTIFF was not written, when an origin asked for it
  MosaicResult mosaic_result;
};

/// Writes `track`'s files into `directory` (which must exist), named by track.label. Throws
/// ExportError (or StoreError / DatasetError from the images) naming the file.
TrackFiles writeTrackFiles(const ExportTrack& track, const SurveyExport& survey, const MosaicImages& images,
                           const std::string& directory, const TrackFilesOptions& options);

}  // namespace core
}  // namespace uw_multislam
