// The survey generator: renders bottom-looking camera missions over a seabed world with exact
// ground truth, one dataset folder per session (doc/dataset_format.md) plus the
// mission's world_gt.csv and loops_gt.csv.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/sim/seabed_world.h"
#include "uw_multislam/sim/survey_mission.h"
#include "uw_multislam/sim/water_model.h"

namespace uw_multislam {
namespace core {

struct SessionSpec {
  std::string name = "s0";  // folder name
  MissionSpec mission;
  WaterOptions water;
  CameraIntrinsics camera{320, 240, 300.0, 300.0, 159.5, 119.5};
  /// Standard deviation of the altimeter reading written to frames.csv (the ground truth and
  /// the rendering use the true altitude).
  double altimeter_noise_m = 0.01;
  /// "jpg" or "png".
  std::string image_format = "jpg";
  int jpeg_quality = 95;
};

struct WorldSpec {
  /// Empty: the procedural seabed. Otherwise a mosaic image and its georeference text file.
  std::string mosaic_image;
  std::string mosaic_georef;
  ProceduralSeabedOptions procedural;
  /// Procedural raster resolution; 0 = automatic (0.8 x the finest ground pixel of any camera
  /// at its lowest altitude, so frames are never magnified).
  double auto_metres_per_px = 0.0;
};

struct SurveySpec {
  std::uint64_t seed = 1;
  WorldSpec world;
  std::vector<SessionSpec> sessions;
  /// loops_gt.csv: frame pairs whose centres are closer than this fraction of the footprint
  /// height (image_height * altitude / fy, the lower altitude of the two)...
  double loop_distance_fraction = 0.4;
  /// ...and that are not neighbours: same-session pairs fewer than this many frames apart are left out.
  int loop_min_frame_gap = 3;

  /// Empty when usable, else a sentence naming the session and the bad value.
  std::string validate() const;
};

/// Names of the built-in presets, and the spec of one (throws std::invalid_argument).
std::vector<std::string> surveyPresets();
SurveySpec surveyPreset(const std::string& name);

/// One ground-truth pose in the world frame.
struct WorldPose {
  int session = 0;
  int index = 0;
  Pose2 pose;
  double altitude_m = 0.0;
};

struct SurveyLoop {
  int session_a, index_a, session_b, index_b;
};

/// Every non-neighbour pair closer than loop_distance_fraction of the footprint height.
std::vector<SurveyLoop> groundTruthLoops(const SurveySpec& spec, const std::vector<WorldPose>& poses);

struct SurveyResult {
  std::vector<std::string> session_dirs;
  std::vector<WorldPose> world_poses;
  std::vector<SurveyLoop> loops;
  int frames = 0;
  int blank_frames = 0;
  double metres_per_px = 0.0;
};

/// Builds the world of a spec (procedural or mosaic).
SeabedWorld buildWorld(const SurveySpec& spec);

/// Plans every session and checks that each frame sees only valid seabed; throws
/// std::invalid_argument naming the first session/frame that leaves it.
std::vector<std::vector<MissionFrame>> planSurvey(const SurveySpec& spec, const SeabedWorld& world);

/// Renders the survey into `out_dir` (created; existing session folders are replaced).
/// `progress` (optional) is called after each frame with (session, frame, frames in session).
SurveyResult generateSurvey(const SurveySpec& spec, const std::string& out_dir,
                            const std::function<void(int, int, int)>& progress = nullptr);

}  // namespace core
}  // namespace uw_multislam
