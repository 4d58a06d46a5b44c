// export_survey: the survey's products from a session store or an offline_slam output folder:
// argument parsing and calls into core/export/survey_export.h and run_export.h; contract:
// --help, doc/tools/export_survey.md.
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "cli.h"

#include "uw_multislam/core/export/mosaic.h"
#include "uw_multislam/core/export/run_export.h"
#include "uw_multislam/core/export/survey_export.h"
#include "uw_multislam/core/export/track_files.h"
#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/store/session_store.h"

namespace core = uw_multislam::core;
namespace po = boost::program_options;
namespace tools = uw_multislam::tools;

namespace {

const char* kUsage = R"usage(usage: export_survey --db STORE --out DIR [--origin LAT,LON,HEADING_DEG] [options]
       export_survey --run RUN_DIR [--session DIR ...] --out DIR [--origin ...] [options]

Reads a session store (offline_slam --db, the back-end's store) read-only, or an offline_slam output
folder (--run) with its dataset folders, and writes, per session (session_<id>) and per map
(map_<id>, id = its first session's store id) into DIR:
  <name>.tum      stamp x y z qx qy qz qw per keyframe (evo, TUM RGB-D format)
  <name>.kitti    the 3x4 pose matrix [R | t] per keyframe, row-major on one line
  <name>.csv      stamp_s,session,keyframe,frame_index,x_m,y_m,yaw_rad,altitude_m and the pose's
                  covariance cov_xx,cov_xy,cov_xyaw,cov_yy,cov_yyaw,cov_yawyaw
  <name>.g2o      VERTEX_SE2 per keyframe (index in the file's keyframe order), FIX 0, EDGE_SE2
                  per odometry motion, link and loop with its information matrix (inverse covariance)
  <name>.geojson  the track in WGS84 (lon, lat) when --origin is given
  <name>.png      the photomosaic (RGBA, transparent where no image), and <name>.pgw its world
                  file (metres per pixel, centre of the upper-left pixel in the map frame)
  <name>.tif      the mosaic as a GeoTIFF when --origin is given (transverse Mercator centred
                  on the origin, WGS84)
Poses are in the map frame the back-end publishes (z up, x along the map's first image columns,
y against its rows; doc/frames.md): the camera's level frame, z = 0 on the seabed,
yaw about z. A session's files hold its keyframes in its map's frame. Each file is written to a
temporary name and renamed, so none is ever half-written. The store is never modified.

From an offline_slam output folder (--run; doc/run_outputs.md): the poses of trajectory.csv
(6 decimals), sessions numbered by pieces.csv's store_session, the engine's session id (the
folder's number unless a tracking loss split a folder; the store's export of the same run names
them alike: a session's id is its store id), maps chained by links.csv, odometry motions from odometry.csv, loops from loops.csv
with their measured pose and covariance from loop_poses.csv; stamps, altitudes, cameras and the
mosaics' images from the dataset folders. What the folder does not record is not invented: the
CSV's six covariance columns are "nan" (no pose covariance is written by offline_slam), the g2o
odometry and link edges are comment lines "# EDGE_SE2 i j dx dy dyaw information unknown" (their
covariance is not written either), and the g2o holds every accepted loop with a measured pose (the
folder does not say which ones a join link summarised).

options:
  --db STORE        the session store (SQLite) to read
  --run RUN_DIR     instead of --db: an offline_slam output folder (trajectory.csv, odometry.csv,
                    loops.csv, loop_poses.csv, links.csv, pieces.csv, inputs.csv)
  --session DIR...  with --run: the dataset folders of run session 0, 1, ... in order (default:
                    the folders inputs.csv names, as written); each is checked against inputs.csv
                    (frame count, first and last stamp) and its frames are drawn in the mosaics
  --out DIR         output directory (created if missing)
  --origin LAT,LON,HEADING_DEG
                    WGS84 latitude and longitude (degrees) of the map frame's origin and the
                    compass heading of its x axis (degrees clockwise from north): GeoJSON tracks
                    and GeoTIFFs. Without it none are written; a dataset folder's nav_frame.yaml
                    datum is not taken (it is the origin of nav.csv's frame, and a map's frame is
                    its first keyframe's); the line "origin: ..." says which was used
  --resolution M    mosaic metres per pixel (default: the median keyframe's ground pixel size
                    of the images drawn)
  --images DIR...   dataset folders whose frames (matched by stamp and frame index; a folder whose
                    camera.yaml gives another image size than the session's camera is left out)
                    are drawn at full resolution; without them the keyframe images kept in the store are
                    drawn (their size: config store.image_max_side_px of the run that wrote it)
  --blend B         feather (default), multiband or none (cv::detail blenders; none: each
                    keyframe drawn over the earlier ones)
  --no-exposure     no gain compensation between keyframes (per colour channel)
  --tile PX         mosaic tile side in pixels (default 1024; memory grows with its square)
  --no-mosaic       tracks and graphs only
  --quiet           no summary
  -h, --help        this text

Exit status 0 on success, 2 on bad arguments, 1 with a one-line reason on bad input.)usage";

struct Arguments {
  std::string db, run_dir, out;
  std::vector<std::string> session_dirs, image_dirs;
  std::optional<core::GeoOrigin> origin;
  core::MosaicOptions mosaic_options;
  bool quiet = false, mosaic = true;
};

std::string parseOrigin(const std::string& text, std::optional<core::GeoOrigin>* origin) {
  core::GeoOrigin o;
  std::string why;
  if (!core::parseGeoOrigin(text, &o, &why)) return "bad --origin: " + why;
  *origin = o;
  return "";
}

/// The line that says which georeference the exports take. A dataset folder's nav_frame.yaml may
/// hold a datum, but it is the origin of nav.csv's world frame, and offline_slam's maps are not in
/// that frame (a map's frame is its first keyframe's, whatever frame the nav is written in: the
/// same trajectory.csv from a nav in the session frame, in ENU and in NED), so it is not taken.
std::string originLine(const std::optional<core::GeoOrigin>& origin, const std::vector<std::string>& dataset_dirs) {
  char line[512];
  if (origin) {
    std::snprintf(line, sizeof line, "origin: --origin %.7f, %.7f, map x axis heading %.1f deg", origin->lat_deg,
                  origin->lon_deg, origin->heading_deg);
    return line;
  }
  for (const std::string& dir : dataset_dirs) {
    const std::filesystem::path yaml = std::filesystem::path(dir) / "nav_frame.yaml";
    if (!std::filesystem::exists(yaml)) continue;
    const core::NavFrame f = core::readNavFrameYaml(yaml.string());  // checked by loadRunExport's dataset read
    if (!f.has_origin) continue;
    std::snprintf(line, sizeof line,
                  "origin: none (no --origin: no GeoJSON, no GeoTIFF); %s has a datum (%.7f, %.7f), the origin of "
                  "nav.csv's frame '%s', not of the run's maps (each map's frame is its first keyframe's): not used",
                  yaml.string().c_str(), f.latitude_deg, f.longitude_deg, f.name.c_str());
    return line;
  }
  return "origin: none (no --origin: no GeoJSON, no GeoTIFF)";
}

std::string parseResolution(const std::string& text, double* metres) {
  if (!tools::parseNumber(text, metres) || *metres <= 0.0 || *metres > 100.0)
    return "bad --resolution '%value%': metres per pixel, in (0, 100]";
  return "";
}

std::string parseTile(const std::string& text, int* px) {
  double v = 0.0;
  if (!tools::parseNumber(text, &v) || v != std::floor(v) || v < 64 || v > 16384)
    return "bad --tile '%value%': pixels, an integer in [64, 16384]";
  *px = static_cast<int>(v);
  return "";
}

std::string parseBlend(const std::string& text, core::MosaicBlend* blend) {
  return core::parseMosaicBlend(text, blend) ? "" : "bad --blend '%value%': multiband, feather or none";
}

std::optional<int> parseArguments(int argc, char** argv, Arguments* a) {
  bool no_mosaic = false, no_exposure = false;
  tools::CommandLine cli("export_survey", kUsage);
  auto option = cli.add();
  option("db", po::value(&a->db));
  option("run", po::value(&a->run_dir));
  option("session", po::value(&a->session_dirs)->multitoken());
  option("out", po::value(&a->out));
  option("origin", tools::checked(&a->origin, parseOrigin));
  option("resolution", tools::checked(&a->mosaic_options.resolution_m, parseResolution));
  option("images", po::value(&a->image_dirs)->multitoken());
  option("blend", tools::checked(&a->mosaic_options.blend, parseBlend));
  option("no-exposure", tools::flag(&no_exposure));
  option("tile", tools::checked(&a->mosaic_options.tile_px, parseTile));
  option("no-mosaic", tools::flag(&no_mosaic));
  option("quiet", tools::flag(&a->quiet));
  if (const auto status = cli.parse(argc, argv)) return status;
  a->mosaic = !no_mosaic;
  if (no_exposure) a->mosaic_options.exposure = false;
  if (a->db.empty() == a->run_dir.empty()) return cli.bad("one of --db STORE or --run RUN_DIR is required");
  if (!a->session_dirs.empty() && a->run_dir.empty()) return cli.bad("--session goes with --run");
  if (!a->run_dir.empty() && !a->image_dirs.empty())
    return cli.bad("--images goes with --db (with --run the --session folders' frames are drawn)");
  if (a->out.empty()) return cli.bad("--out DIR is required");
  return std::nullopt;
}

int exportSurvey(Arguments a) {
  const std::string &db = a.db, &run_dir = a.run_dir, &out = a.out;
  const std::vector<std::string>& session_dirs = a.session_dirs;
  std::vector<std::string>& image_dirs = a.image_dirs;
  const bool quiet = a.quiet, mosaic = a.mosaic;
  const core::MosaicOptions& mosaic_options = a.mosaic_options;
  try {
    std::vector<std::string> notes;
    core::SurveyExport survey;
    if (run_dir.empty()) {
      survey = core::loadSurveyExport(db);
    } else {
      core::RunExport run = core::loadRunExport(run_dir, session_dirs);
      survey = std::move(run.survey);
      image_dirs = run.dataset_dirs;
      notes = run.notes;
    }
    core::MosaicImages images;
    for (const std::string& dir : image_dirs) images.addDataset(dir);  // checked before any output
    if (images.hasDatasets())
      for (const std::string& line : images.matchSessions(survey))
        if (!quiet) std::printf("images of %s\n", line.c_str());
    namespace fs = std::filesystem;
    std::error_code ec;
    try {  // new directories take the store's permissions (0700 for a 0600 store)
      core::makeDirectories(out, survey.modes.directory);
    } catch (const core::FileWriteError&) {  // said below
    }
    if (!fs::is_directory(out, ec)) {
      std::fprintf(stderr, "export_survey: %s: cannot create the output directory\n", out.c_str());
      return 1;
    }
    int files = 0;
    core::TrackFilesOptions track_options;
    track_options.mosaic = mosaic;
    track_options.mosaic_options = mosaic_options;
    track_options.origin = a.origin ? &*a.origin : nullptr;
    auto writeAll = [&](const core::ExportTrack& t) {
      const core::TrackFiles written = core::writeTrackFiles(t, survey, images, out, track_options);
      files += static_cast<int>(written.files.size());
      if (!written.no_mosaic.empty())
        std::printf("%s.png: not drawn: %s\n", t.label.c_str(), written.no_mosaic.c_str());
      if (!written.no_geotiff.empty())
        std::printf("%s.tif: not written: %s\n", t.label.c_str(), written.no_geotiff.c_str());
      if (!written.mosaic || quiet) return;
      const core::MosaicResult& r = written.mosaic_result;
      std::printf(
          "%s.png: %d x %d px at %.4f m/px, %d tiles, %s blending%s, %.0f ms, seam ratio %.3f; images: %d "
          "frames, %d thumbnails, %d missing\n",
          t.label.c_str(), r.width, r.height, r.resolution_m, r.tiles, core::mosaicBlendName(mosaic_options.blend),
          mosaic_options.exposure ? " + gains" : "", r.ms, r.seam_ratio, r.from_frames, r.from_thumbnails, r.missing);
    };
    if (!quiet) std::printf("%s\n", originLine(a.origin, image_dirs).c_str());
    for (const core::ExportTrack& s : survey.sessions) writeAll(s);
    for (const core::ExportTrack& m : survey.maps) writeAll(m);
    if (!quiet) {
      for (const core::ExportTrack& m : survey.maps)
        std::printf("%s (%s): %zu sessions, %zu keyframes, %zu edges\n", m.label.c_str(), m.name.c_str(),
                    m.sessions.size(), m.keyframes.size(), m.edges.size());
      std::printf("%zu sessions, %zu maps: %d files in %s%s\n", survey.sessions.size(), survey.maps.size(), files,
                  out.c_str(), a.origin ? "" : " (no --origin: no GeoJSON)");
      for (const std::string& note : notes) std::printf("note: %s\n", note.c_str());
      if (mosaic && image_dirs.empty())
        std::printf(
            "note: mosaics drawn from the keyframe images kept in the store (config store.image_max_side_px): "
            "give --images DATASET_DIR... for full-resolution frames\n");
      if (survey.pending_loops > 0)
        std::printf("note: %d loops were pending optimisation in the store; the poses are as stored\n",
                    survey.pending_loops);
    }
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "export_survey: %s\n", e.what());
    return 1;
  }
}

}  // namespace

int main(int argc, char** argv) {
  Arguments arguments;
  if (const auto status = parseArguments(argc, argv, &arguments)) return *status;
  return exportSurvey(std::move(arguments));
}
