#include "uw_multislam/sim/survey_generator.h"

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <random>
#include <regex>
#include <set>
#include <sstream>
#include <stdexcept>

#include "uw_multislam/core/frontend/camera_model.h"
#include "uw_multislam/core/geometry/vehicle_frame.h"

namespace uw_multislam {
namespace core {

namespace fs = std::filesystem;

namespace {

double footprintHeight(const CameraIntrinsics& c, double altitude_m) { return c.height * altitude_m / c.fy; }

double lowestAltitude(const MissionSpec& m) { return m.altitude_m - m.altitude_amplitude_m; }

// A camera with lens distortion: the ideal pinhole view is rendered with a margin wide enough for
// every raw pixel's ray, then resampled at the undistorted position of each raw pixel. A pinhole
// camera renders directly (no maps).
struct Lens {
  CameraIntrinsics view;  // the pinhole camera rendered
  cv::Mat map_x, map_y;   // raw pixel -> pixel of `view`; empty without distortion
};

Lens lensOf(const CameraIntrinsics& camera) {
  Lens lens;
  lens.view = camera.pinhole();
  if (!camera.distorted()) return lens;
  std::vector<cv::Point2f> raw;
  raw.reserve(static_cast<std::size_t>(camera.width) * camera.height);
  for (int v = 0; v < camera.height; ++v) {
    for (int u = 0; u < camera.width; ++u) raw.emplace_back(static_cast<float>(u), static_cast<float>(v));
  }
  const std::vector<cv::Point2f> ideal = undistortPixels(raw, camera);
  double margin = 0.0;
  for (const auto& p : ideal) {
    const double x = p.x, y = p.y;
    margin = std::max({margin, -x, -y, x - (camera.width - 1), y - (camera.height - 1)});
  }
  const int m = static_cast<int>(std::ceil(margin)) + 2;
  lens.view.width += 2 * m, lens.view.height += 2 * m, lens.view.cx += m, lens.view.cy += m;
  lens.map_x.create(camera.height, camera.width, CV_32F);
  lens.map_y.create(camera.height, camera.width, CV_32F);
  for (int v = 0, i = 0; v < camera.height; ++v) {
    for (int u = 0; u < camera.width; ++u, ++i) {
      lens.map_x.at<float>(v, u) = ideal[i].x + m;
      lens.map_y.at<float>(v, u) = ideal[i].y + m;
    }
  }
  return lens;
}

cv::Mat renderThrough(const Lens& lens, const SeabedWorld& world, const Pose2& pose, double altitude_m) {
  const cv::Mat view = world.render(pose, altitude_m, lens.view);
  if (lens.map_x.empty()) return view;
  cv::Mat raw;
  cv::remap(view, raw, lens.map_x, lens.map_y, cv::INTER_LINEAR, cv::BORDER_REPLICATE);
  return raw;
}

// A seed per (survey, session, frame) so that every frame is reproducible on its own.
std::uint64_t frameSeed(std::uint64_t seed, int session, int frame) {
  std::uint64_t h = seed * 0x9E3779B97F4A7C15ULL;
  h ^= static_cast<std::uint64_t>(session + 1) * 0xBF58476D1CE4E5B9ULL;
  h ^= static_cast<std::uint64_t>(frame + 1) * 0x94D049BB133111EBULL;
  return h ^ (h >> 31);
}

}  // namespace

std::string NavErrorSpec::validate() const {
  for (const double v : {scale_error, heading_bias_rad, random_walk_m_per_sqrt_m, heading_random_walk_rad_per_sqrt_m})
    if (!std::isfinite(v)) return "nav: every error must be finite";
  if (!(std::abs(scale_error) < 0.5)) return "nav: scale_error must be in (-0.5, 0.5)";
  if (!(std::abs(heading_bias_rad) < 1.0)) return "nav: heading_bias_rad must be in (-1, 1)";
  if (random_walk_m_per_sqrt_m < 0 || heading_random_walk_rad_per_sqrt_m < 0) return "nav: random walks must be >= 0";
  return {};
}

std::string navOutputFrameName(NavOutputFrame f) {
  switch (f) {
    case NavOutputFrame::kEnu:
      return "enu";
    case NavOutputFrame::kNed:
      return "ned";
    default:
      return "session";
  }
}

bool parseNavOutputFrame(const std::string& name, NavOutputFrame* f) {
  for (const NavOutputFrame c : {NavOutputFrame::kSession, NavOutputFrame::kEnu, NavOutputFrame::kNed}) {
    if (name == navOutputFrameName(c)) {
      *f = c;
      return true;
    }
  }
  return false;
}

std::string NavDatumSpec::validate() const {
  if (!origin_lat_lon_deg.empty() && origin_lat_lon_deg.size() != 2)
    return "nav_datum: origin_lat_lon_deg takes [latitude, longitude] or []";
  const std::string bad = frame(WorldConvention::kEnu).validate();
  return bad.empty() ? "" : "nav_datum: " + bad;
}

NavFrame NavDatumSpec::frame(WorldConvention convention) const {
  NavFrame f;
  f.name = name;
  f.convention = convention;
  f.has_origin = origin_lat_lon_deg.size() == 2;
  if (f.has_origin) f.latitude_deg = origin_lat_lon_deg[0], f.longitude_deg = origin_lat_lon_deg[1];
  return f;
}

std::vector<NavRecord> navRowsInConvention(std::vector<NavRecord> rows, WorldConvention convention) {
  for (NavRecord& r : rows) r.pose = convention == WorldConvention::kNed ? swapEnuNed(zUp(r.pose)) : zUp(r.pose);
  return rows;
}

std::vector<NavRecord> simulateNav(const std::vector<MissionFrame>& plan, const NavErrorSpec& spec,
                                   std::uint64_t seed) {
  std::vector<NavRecord> nav = simulateWorldNav(plan, spec, seed);
  for (NavRecord& r : nav) r.pose = between(plan.front().pose, r.pose);
  return nav;
}

std::vector<NavRecord> simulateWorldNav(const std::vector<MissionFrame>& plan, const NavErrorSpec& spec,
                                        std::uint64_t seed) {
  std::vector<NavRecord> nav;
  if (plan.empty()) return nav;
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> g(0.0, 1.0);
  std::bernoulli_distribution sign(0.5);
  const double scale = (sign(rng) ? 1 : -1) * spec.scale_error;
  const double bias = (sign(rng) ? 1 : -1) * spec.heading_bias_rad;
  const double drift = std::hypot(spec.scale_error, spec.heading_bias_rad);
  Eigen::Vector2d position = plan.front().pose.translation();
  double heading_walk = 0.0;
  double heading = 0.0;  // the INS heading of the previous frame
  for (std::size_t k = 0; k < plan.size(); ++k) {
    const MissionFrame& f = plan[k];
    if (k > 0) {
      const Pose2& prev = plan[k - 1].pose;
      const double step = (f.pose.translation() - prev.translation()).norm();
      // The DVL's displacement in the body frame, scaled, turned into the world by the INS heading.
      const Eigen::Vector2d body = prev.rotation().transpose() * (f.pose.translation() - prev.translation());
      // y's draw first, as x86-64 took them (C++ leaves the order of a call's arguments
      // unspecified; aarch64 took x first and drew another nav track for the same seed).
      const double walk_y = g(rng), walk_x = g(rng);
      position += Pose2(0, 0, heading).rotation() * ((1.0 + scale) * body) +
                  spec.random_walk_m_per_sqrt_m * std::sqrt(step) * Eigen::Vector2d(walk_x, walk_y);
      heading_walk += spec.heading_random_walk_rad_per_sqrt_m * std::sqrt(step) * g(rng);
    }
    heading = normalizeAngle(f.pose.yaw() + bias + heading_walk);
    const double d = f.path_m - plan.front().path_m;
    nav.push_back({f.stamp_s, Pose2(position.x(), position.y(), heading),
                   drift * d + spec.random_walk_m_per_sqrt_m * std::sqrt(d),
                   std::abs(spec.heading_bias_rad) + spec.heading_random_walk_rad_per_sqrt_m * std::sqrt(d)});
  }
  return nav;
}

std::string SurveySpec::validate() const {
  if (sessions.empty()) return "the survey has no sessions";
  if (!(loop_distance_fraction > 0 && loop_distance_fraction <= 2)) return "loop_distance_fraction must be in (0, 2]";
  if (loop_min_frame_gap < 1) return "loop_min_frame_gap must be at least 1";
  if (world.mosaic_image.empty() != world.mosaic_georef.empty()) {
    return "a mosaic world needs both mosaic_image and mosaic_georef";
  }
  if (!(world.auto_metres_per_px >= 0)) return "world metres_per_px must be >= 0 (0 = automatic)";
  if (const std::string bad = nav_datum.validate(); !bad.empty()) return bad;
  const std::regex name_re("[A-Za-z0-9_-]+");
  std::set<std::string> names;
  for (const auto& s : sessions) {
    const std::string where = "session '" + s.name + "': ";
    if (!std::regex_match(s.name, name_re)) return where + "name must be letters, digits, '_' or '-'";
    if (!names.insert(s.name).second) return where + "duplicate session name";
    std::string bad = s.mission.validate();
    if (bad.empty()) bad = s.water.validate();
    if (bad.empty()) bad = s.camera.validate();
    if (!bad.empty()) return where + bad;
    if (s.image_format != "jpg" && s.image_format != "png") return where + "image_format must be jpg or png";
    if (s.jpeg_quality < 1 || s.jpeg_quality > 100) return where + "jpeg_quality must be in 1..100";
    if (!(s.altimeter_noise_m >= 0 && s.altimeter_noise_m < 1)) return where + "altimeter_noise_m must be in [0, 1)";
    if (const std::string nav = s.nav.validate(); !nav.empty()) return where + nav;
  }
  return {};
}

SeabedWorld buildWorld(const SurveySpec& spec) {
  if (!spec.world.mosaic_image.empty())
    return SeabedWorld::fromMosaic(spec.world.mosaic_image, spec.world.mosaic_georef);
  ProceduralSeabedOptions o = spec.world.procedural;
  o.seed = spec.seed;
  if (spec.world.auto_metres_per_px > 0) {
    o.metres_per_px = spec.world.auto_metres_per_px;
  } else {
    double finest = 1e9;
    for (const auto& s : spec.sessions) {
      finest = std::min(finest, lowestAltitude(s.mission) / std::max(s.camera.fx, s.camera.fy));
    }
    o.metres_per_px = std::clamp(0.8 * finest, 0.002, 0.05);
  }
  return SeabedWorld::procedural(o);
}

std::vector<std::vector<MissionFrame>> planSurvey(const SurveySpec& spec, const SeabedWorld& world) {
  const std::string bad = spec.validate();
  if (!bad.empty()) throw std::invalid_argument(bad);
  std::vector<std::vector<MissionFrame>> plans;
  for (const auto& s : spec.sessions) {
    plans.push_back(planMission(s.mission));
    const auto& frames = plans.back();
    const CameraIntrinsics view = lensOf(s.camera).view;  // with a distorted lens, the wider pinhole rendered
    for (std::size_t k = 0; k < frames.size(); ++k) {
      if (!world.viewIsValid(frames[k].pose, frames[k].altitude_m, view)) {
        std::ostringstream os;
        os << std::fixed << std::setprecision(2) << "session '" << s.name << "' frame " << k << " at ("
           << frames[k].pose.x() << ", " << frames[k].pose.y() << ") m leaves the seabed world (" << world.widthM()
           << " x " << world.heightM() << " m, origin at raster pixel " << world.originPx().x() << ", "
           << world.originPx().y() << "): move or shrink the mission";
        throw std::invalid_argument(os.str());
      }
    }
  }
  return plans;
}

std::vector<SurveyLoop> groundTruthLoops(const SurveySpec& spec, const std::vector<WorldPose>& poses) {
  std::vector<SurveyLoop> loops;
  for (std::size_t a = 0; a < poses.size(); ++a) {
    for (std::size_t b = a + 1; b < poses.size(); ++b) {
      const WorldPose& pa = poses[a];
      const WorldPose& pb = poses[b];
      if (pa.session == pb.session && std::abs(pa.index - pb.index) < spec.loop_min_frame_gap) continue;
      const double h = std::min(footprintHeight(spec.sessions[pa.session].camera, pa.altitude_m),
                                footprintHeight(spec.sessions[pb.session].camera, pb.altitude_m));
      if ((pa.pose.translation() - pb.pose.translation()).norm() < spec.loop_distance_fraction * h) {
        loops.push_back({pa.session, pa.index, pb.session, pb.index});
      }
    }
  }
  return loops;
}

SurveyResult generateSurvey(const SurveySpec& spec, const std::string& out_dir,
                            const std::function<void(int, int, int)>& progress) {
  const SeabedWorld world = buildWorld(spec);
  const auto plans = planSurvey(spec, world);
  SurveyResult result;
  result.metres_per_px = world.metresPerPixel();
  fs::create_directories(out_dir);

  for (std::size_t si = 0; si < spec.sessions.size(); ++si) {
    const SessionSpec& s = spec.sessions[si];
    const auto& plan = plans[si];
    const Lens lens = lensOf(s.camera);
    const fs::path dir = fs::path(out_dir) / s.name;
    fs::remove_all(dir);
    fs::create_directories(dir);
    std::mt19937_64 altimeter_rng(frameSeed(spec.seed, static_cast<int>(si), -1));
    std::normal_distribution<double> altimeter_noise(0.0, 1.0);
    std::vector<FrameRecord> frames;
    std::vector<GroundTruthRecord> gt;
    const std::vector<int> params = s.image_format == "jpg" ? std::vector<int>{cv::IMWRITE_JPEG_QUALITY, s.jpeg_quality}
                                                            : std::vector<int>{cv::IMWRITE_PNG_COMPRESSION, 3};
    for (std::size_t k = 0; k < plan.size(); ++k) {
      const MissionFrame& mf = plan[k];
      const int index = static_cast<int>(k);
      const cv::Mat clean = renderThrough(lens, world, mf.pose, mf.altitude_m);
      WaterFrame wf;
      wf.index = index;
      wf.altitude_m = mf.altitude_m;
      // The seabed moves in the image opposite to the camera, scaled by the ground pixel size.
      const double ground_px = mf.altitude_m / s.camera.fx;
      wf.image_velocity_px_s = -(mf.pose.rotation().transpose() * mf.velocity_m_s) / ground_px;
      cv::RNG rng(frameSeed(spec.seed, static_cast<int>(si), index));
      const cv::Mat img = applyWater(clean, s.water, wf, rng);
      std::ostringstream name;
      name << std::setw(4) << std::setfill('0') << index << "." << s.image_format;
      if (!cv::imwrite((dir / name.str()).string(), img, params)) {
        throw DatasetError((dir / name.str()).string() + ": cannot write image");
      }
      if (s.water.stretchAt(index)) ++result.blank_frames;
      const double measured = mf.altitude_m + s.altimeter_noise_m * altimeter_noise(altimeter_rng);
      frames.push_back({index, name.str(), mf.stamp_s, measured});
      gt.push_back({index, name.str(), between(plan.front().pose, mf.pose)});
      result.world_poses.push_back({static_cast<int>(si), index, mf.pose, mf.altitude_m});
      ++result.frames;
      if (progress) progress(static_cast<int>(si), index, static_cast<int>(plan.size()));
    }
    writeCameraYaml((dir / "camera.yaml").string(), s.camera);
    writeFramesCsv((dir / "frames.csv").string(), frames);
    writeGroundTruthCsv((dir / "gt.csv").string(), gt);
    const std::uint64_t nav_seed = frameSeed(spec.seed, static_cast<int>(si), -2);
    if (s.nav.enabled && s.nav.frame == NavOutputFrame::kSession) {
      writeNavCsv((dir / "nav.csv").string(), simulateNav(plan, s.nav, nav_seed));
    } else if (s.nav.enabled) {
      const WorldConvention c = s.nav.frame == NavOutputFrame::kNed ? WorldConvention::kNed : WorldConvention::kEnu;
      writeNavCsv((dir / "nav.csv").string(), navRowsInConvention(simulateWorldNav(plan, s.nav, nav_seed), c));
      writeNavFrameYaml((dir / "nav_frame.yaml").string(), spec.nav_datum.frame(c));
    }
    result.session_dirs.push_back(dir.string());
  }

  result.loops = groundTruthLoops(spec, result.world_poses);
  std::ofstream world_gt(fs::path(out_dir) / "world_gt.csv");
  world_gt << "session,index,x_m,y_m,yaw_rad\n" << std::fixed;
  for (const auto& p : result.world_poses) {
    world_gt << p.session << "," << p.index << "," << std::setprecision(6) << p.pose.x() << "," << p.pose.y() << ","
             << std::setprecision(7) << p.pose.yaw() << "\n";
  }
  std::ofstream loops(fs::path(out_dir) / "loops_gt.csv");
  loops << "session_a,index_a,session_b,index_b\n";
  for (const auto& l : result.loops)
    loops << l.session_a << "," << l.index_a << "," << l.session_b << "," << l.index_b << "\n";
  if (!world_gt || !loops) throw DatasetError(out_dir + ": cannot write world_gt.csv / loops_gt.csv");
  return result;
}

// ----------------------------------------------------------------------------------------------
// Presets.

std::vector<std::string> surveyPresets() { return {"demo", "textured", "hazy", "featureless", "blank"}; }

SurveySpec surveyPreset(const std::string& name) {
  SurveySpec spec;
  spec.world.procedural.width_m = 22.0;
  spec.world.procedural.height_m = 17.0;

  SessionSpec lawn;
  lawn.name = "s0";
  lawn.mission.pattern = MissionPattern::kLawnmower;
  lawn.mission.start_m = Eigen::Vector2d(4.0, 4.0);
  lawn.mission.length_m = 14.0;
  lawn.mission.width_m = 5.6;
  lawn.mission.leg_spacing_m = 1.4;
  lawn.mission.altitude_amplitude_m = 0.2;

  if (name == "demo") {
    // Two missions on different days over overlapping ground: the second one dimmer, bluer and
    // more turbid, with the camera turned 90 degrees and a loop that crosses the first survey.
    SessionSpec second;
    second.name = "s1";
    second.mission.pattern = MissionPattern::kLoop;
    second.mission.start_m = Eigen::Vector2d(12.0, 8.0);
    second.mission.heading_rad = M_PI / 2;
    second.mission.camera_yaw_offset_rad = M_PI / 2;
    second.mission.length_m = 10.0;
    second.mission.width_m = 6.0;
    second.mission.altitude_m = 2.8;
    second.mission.altitude_amplitude_m = 0.15;
    second.mission.start_time_s = 86400.0;
    second.water.illumination = 0.7;
    second.water.colour_gain_bgr = Eigen::Vector3d(1.15, 1.0, 0.75);
    second.water.turbidity_per_m = 0.05;
    second.water.light_cone = 0.45;
    second.water.vignetting = 0.3;
    second.water.marine_snow_per_frame = 15;
    second.water.noise_sigma = 2.5;
    second.water.motion_blur_exposure_s = 0.004;
    spec.sessions = {lawn, second};
  } else if (name == "textured") {
    // Clear water over textured seabed: the odometry drift benchmark.
    lawn.water.turbidity_per_m = 0.0;
    lawn.water.vignetting = 0.0;
    spec.world.procedural.featureless_fraction = 0.0;
    spec.sessions = {lawn};
  } else if (name == "hazy") {
    // Turbid water with backscatter, a light cone and marine snow.
    lawn.water.turbidity_per_m = 0.25;
    lawn.water.backscatter_bgr = Eigen::Vector3d(0.55, 0.5, 0.2);
    lawn.water.light_cone = 0.6;
    lawn.water.vignetting = 0.35;
    lawn.water.marine_snow_per_frame = 40;
    lawn.water.noise_sigma = 3.0;
    spec.sessions = {lawn};
  } else if (name == "featureless") {
    // Large stretches of smooth sand.
    spec.world.procedural.featureless_fraction = 0.6;
    spec.world.procedural.rock_density_per_m2 = 0.1;
    spec.sessions = {lawn};
  } else if (name == "blank") {
    // Tracking loss: a stretch of blank frames and one of occluded frames.
    SessionSpec s = lawn;
    s.mission.pattern = MissionPattern::kOutAndBack;
    s.mission.length_m = 14.0;
    s.mission.leg_spacing_m = 1.0;
    s.water.stretches = {{15, 8, FrameStretch::Kind::kBlank}, {40, 4, FrameStretch::Kind::kOccluded}};
    spec.sessions = {s};
  } else {
    throw std::invalid_argument("unknown preset '" + name + "'");
  }
  return spec;
}

}  // namespace core
}  // namespace uw_multislam
