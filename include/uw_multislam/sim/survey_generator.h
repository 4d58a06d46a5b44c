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

/// The vehicle's dead-reckoning navigation (DVL + INS) written to nav.csv, and its errors. The
/// DVL's body-frame displacement between frames is scaled by (1 + scale_error) and rotated into
/// the world by the INS heading, true heading + heading_bias_rad + a heading random walk; each
/// step's translation gets a white error (a random walk in position). Signs of the scale error
/// and the bias are drawn per session from the survey seed, their magnitudes are fixed: on a
/// straight track the position error is then sqrt(scale_error^2 + heading_bias_rad^2) of the
/// distance travelled (about 1 % with the defaults) plus the random walk's
/// random_walk_m_per_sqrt_m * sqrt(distance) per axis (a heading random walk h adds a cross-track
/// variance h^2 d^3 / 3). The first frame's nav position is exact, its yaw off by the bias.
/// nav.csv's sigma columns: sigma_xy_m = sqrt(scale^2 + bias^2) * d + random_walk * sqrt(d),
/// sigma_yaw_rad = |heading_bias_rad| + heading_random_walk * sqrt(d), d the distance so far.
///
/// Where nav.csv's poses are (`frame`): in gt.csv's frame (the session's first frame's image axes,
/// as before), or in the mission's world frame, written in ENU or NED with a nav_frame.yaml beside
/// it (SurveySpec::nav_datum). The world frame is world_gt.csv's seen as a north-up chart: its
/// origin is world_gt.csv's, east along its x (the raster's columns), north against its y (the
/// rows), so ENU (x, y, yaw) = (x_w, -y_w, -yaw_w) (zUp, core/geometry/vehicle_frame.h) and NED is
/// ENU through swapEnuNed (core/frontend/dataset.h). Every session's nav then shares one frame.
enum class NavOutputFrame { kSession, kEnu, kNed };
/// "session", "enu", "ned".
std::string navOutputFrameName(NavOutputFrame f);
bool parseNavOutputFrame(const std::string& name, NavOutputFrame* f);

struct NavErrorSpec {
  bool enabled = false;  // write nav.csv (off: the folders are as before)
  double scale_error = 0.007;
  double heading_bias_rad = 0.007;
  double random_walk_m_per_sqrt_m = 0.002;
  double heading_random_walk_rad_per_sqrt_m = 0.0005;
  NavOutputFrame frame = NavOutputFrame::kSession;

  std::string validate() const;
};

/// The nav track of a planned mission (rows at the frame stamps, in the first frame's image axes
/// as gt.csv), drawn with `seed`.
std::vector<NavRecord> simulateNav(const std::vector<MissionFrame>& plan, const NavErrorSpec& spec, std::uint64_t seed);
/// The same track in the world frame of the plan (world_gt.csv's axes, z down); simulateNav is
/// this one seen from the plan's first frame.
std::vector<NavRecord> simulateWorldNav(const std::vector<MissionFrame>& plan, const NavErrorSpec& spec,
                                        std::uint64_t seed);
/// World-frame rows (simulateWorldNav) as nav.csv writes them for `frame` kEnu or kNed.
std::vector<NavRecord> navRowsInConvention(std::vector<NavRecord> world_rows, WorldConvention convention);

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
  NavErrorSpec nav;
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

/// nav_frame.yaml of the sessions whose nav is written in the world frame (NavErrorSpec::frame):
/// the frame's name and, optionally, the latitude and longitude of its origin.
struct NavDatumSpec {
  std::string name = "survey";
  std::vector<double> origin_lat_lon_deg;  // empty, or [latitude, longitude]

  std::string validate() const;
  /// The nav_frame.yaml of a session whose nav is written in `convention`.
  NavFrame frame(WorldConvention convention) const;
};

struct SurveySpec {
  std::uint64_t seed = 1;
  WorldSpec world;
  std::vector<SessionSpec> sessions;
  NavDatumSpec nav_datum;
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
