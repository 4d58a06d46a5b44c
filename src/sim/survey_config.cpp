#include "uw_multislam/sim/survey_config.h"

#include "uw_multislam/core/common/yaml_map_reader.h"

#include <yaml-cpp/yaml.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <stdexcept>

namespace uw_multislam {
namespace core {

namespace fs = std::filesystem;

namespace {

void readCamera(const YAML::Node& n, const std::string& where, CameraIntrinsics* c) {
  MapReader r(n, where);
  r.read("image_width", &c->width);
  r.read("image_height", &c->height);
  r.read("fx", &c->fx);
  r.read("fy", &c->fy);
  r.read("cx", &c->cx);
  r.read("cy", &c->cy);
  // Lens distortion of the rendered images (make_survey --distortion does the same): k1, k2[, p1,
  // p2, k3] is plumb_bob (padded with zeros to five), eight numbers rational_polynomial.
  std::vector<double> d;
  r.read("distortion", &d);
  if (!d.empty()) {
    if (d.size() > 5 && d.size() != 8) {
      r.fail("'distortion' needs 1 to 5 numbers (plumb_bob) or 8 (rational_polynomial)");
    }
    c->distortion_model = d.size() == 8 ? DistortionModel::kRationalPolynomial : DistortionModel::kPlumbBob;
    d.resize(d.size() == 8 ? 8 : 5, 0.0);
    c->distortion = d;
  }
  r.finish();
}

void readMission(const YAML::Node& n, const std::string& where, MissionSpec* m) {
  MapReader r(n, where);
  std::string pattern = patternName(m->pattern);
  r.read("pattern", &pattern);
  if (!parsePattern(pattern, &m->pattern)) {
    r.fail("unknown pattern '" + pattern + "' (lawnmower, out_and_back, loop, figure_eight)");
  }
  r.readVector2("start_m", &m->start_m);
  r.read("heading_rad", &m->heading_rad);
  r.read("length_m", &m->length_m);
  r.read("width_m", &m->width_m);
  r.read("leg_spacing_m", &m->leg_spacing_m);
  r.read("laps", &m->laps);
  r.read("speed_m_s", &m->speed_m_s);
  r.read("frame_period_s", &m->frame_period_s);
  r.read("camera_yaw_offset_rad", &m->camera_yaw_offset_rad);
  r.read("altitude_m", &m->altitude_m);
  r.read("altitude_amplitude_m", &m->altitude_amplitude_m);
  r.read("altitude_period_m", &m->altitude_period_m);
  r.read("wobble_yaw_rad", &m->wobble_yaw_rad);
  r.read("wobble_period_m", &m->wobble_period_m);
  r.read("start_time_s", &m->start_time_s);
  r.finish();
}

void readWater(const YAML::Node& n, const std::string& where, WaterOptions* w) {
  MapReader r(n, where);
  r.read("illumination", &w->illumination);
  r.readVector3("colour_gain_bgr", &w->colour_gain_bgr);
  r.read("vignetting", &w->vignetting);
  r.read("light_cone", &w->light_cone);
  r.read("light_cone_width", &w->light_cone_width);
  r.readVector2("light_cone_offset", &w->light_cone_offset);
  r.read("turbidity_per_m", &w->turbidity_per_m);
  r.readVector3("backscatter_bgr", &w->backscatter_bgr);
  r.read("motion_blur_exposure_s", &w->motion_blur_exposure_s);
  r.read("marine_snow_per_frame", &w->marine_snow_per_frame);
  r.read("noise_sigma", &w->noise_sigma);
  const YAML::Node stretches = r.child("stretches");
  r.finish();
  if (!stretches || stretches.IsNull()) return;
  if (!stretches.IsSequence()) r.fail("'stretches' must be a list");
  w->stretches.clear();
  for (std::size_t i = 0; i < stretches.size(); ++i) {
    MapReader sr(stretches[i], where + ".stretches[" + std::to_string(i) + "]");
    FrameStretch s;
    std::string kind = "blank";
    sr.read("first_frame", &s.first_frame);
    sr.read("num_frames", &s.num_frames);
    sr.read("kind", &kind);
    if (kind == "blank") {
      s.kind = FrameStretch::Kind::kBlank;
    } else if (kind == "occluded") {
      s.kind = FrameStretch::Kind::kOccluded;
    } else {
      sr.fail("kind must be blank or occluded");
    }
    sr.finish();
    w->stretches.push_back(s);
  }
}

std::string resolve(const std::string& path, const std::string& base_dir) {
  if (path.empty() || fs::path(path).is_absolute()) return path;
  return (fs::path(base_dir) / path).lexically_normal().string();
}

}  // namespace

SurveySpec surveyFromYaml(const std::string& yaml_text, const std::string& base_dir) {
  const YAML::Node root = parseYaml(yaml_text, "survey");
  MapReader r(root, "survey");
  std::string preset;
  r.read("preset", &preset);
  SurveySpec spec = preset.empty() ? SurveySpec() : surveyPreset(preset);
  r.read("seed", &spec.seed);
  r.read("loop_distance_fraction", &spec.loop_distance_fraction);
  r.read("loop_min_frame_gap", &spec.loop_min_frame_gap);
  {
    MapReader w(r.child("world"), "world");
    w.read("mosaic_image", &spec.world.mosaic_image);
    w.read("mosaic_georef", &spec.world.mosaic_georef);
    spec.world.mosaic_image = resolve(spec.world.mosaic_image, base_dir);
    spec.world.mosaic_georef = resolve(spec.world.mosaic_georef, base_dir);
    w.read("width_m", &spec.world.procedural.width_m);
    w.read("height_m", &spec.world.procedural.height_m);
    w.read("metres_per_px", &spec.world.auto_metres_per_px);
    w.read("featureless_fraction", &spec.world.procedural.featureless_fraction);
    w.read("seagrass_fraction", &spec.world.procedural.seagrass_fraction);
    w.read("rock_density_per_m2", &spec.world.procedural.rock_density_per_m2);
    w.read("pebble_density_per_m2", &spec.world.procedural.pebble_density_per_m2);
    w.finish();
  }
  {
    MapReader d(r.child("nav_datum"), "nav_datum");
    d.read("name", &spec.nav_datum.name);
    d.read("origin_lat_lon_deg", &spec.nav_datum.origin_lat_lon_deg);
    d.finish();
  }
  const YAML::Node sessions = r.child("sessions");
  if (sessions && !sessions.IsNull()) {
    if (!sessions.IsSequence()) r.fail("'sessions' must be a list");
    spec.sessions.clear();
    for (std::size_t i = 0; i < sessions.size(); ++i) {
      const std::string where = "sessions[" + std::to_string(i) + "]";
      MapReader sr(sessions[i], where);
      SessionSpec s;
      s.name = "s" + std::to_string(i);
      sr.read("name", &s.name);
      sr.read("altimeter_noise_m", &s.altimeter_noise_m);
      sr.read("image_format", &s.image_format);
      sr.read("jpeg_quality", &s.jpeg_quality);
      readCamera(sr.child("camera"), where + ".camera", &s.camera);
      readMission(sr.child("mission"), where + ".mission", &s.mission);
      readWater(sr.child("water"), where + ".water", &s.water);
      {
        // The dead-reckoning nav written to nav.csv (survey_generator.h, NavErrorSpec).
        MapReader nr(sr.child("nav"), where + ".nav");
        nr.read("enabled", &s.nav.enabled);
        nr.read("scale_error", &s.nav.scale_error);
        nr.read("heading_bias_rad", &s.nav.heading_bias_rad);
        nr.read("random_walk_m_per_sqrt_m", &s.nav.random_walk_m_per_sqrt_m);
        nr.read("heading_random_walk_rad_per_sqrt_m", &s.nav.heading_random_walk_rad_per_sqrt_m);
        std::string frame = navOutputFrameName(s.nav.frame);
        nr.read("frame", &frame);
        if (!parseNavOutputFrame(frame, &s.nav.frame)) nr.fail("frame '" + frame + "' is not session, enu or ned");
        nr.finish();
      }
      sr.finish();
      spec.sessions.push_back(s);
    }
  }
  r.finish();
  const std::string bad = spec.validate();
  if (!bad.empty()) throw std::invalid_argument("survey: " + bad);
  return spec;
}

SurveySpec loadSurveyYaml(const std::string& path) {
  const std::string base_dir = fs::path(path).parent_path().string();
  return parseYamlFile(path, [&](const std::string& text) { return surveyFromYaml(text, base_dir); });
}

std::string surveyToYaml(const SurveySpec& spec) {
  YAML::Emitter out;
  out.SetDoublePrecision(10);
  auto vec = [&out](const auto& v) {
    out << YAML::Flow << YAML::BeginSeq;
    for (int i = 0; i < v.size(); ++i) out << v[i];
    out << YAML::EndSeq;
  };
  out << YAML::BeginMap;
  out << YAML::Key << "seed" << YAML::Value << spec.seed;
  out << YAML::Key << "loop_distance_fraction" << YAML::Value << spec.loop_distance_fraction;
  out << YAML::Key << "loop_min_frame_gap" << YAML::Value << spec.loop_min_frame_gap;
  const auto& w = spec.world;
  out << YAML::Key << "world" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "mosaic_image" << YAML::Value << w.mosaic_image;
  out << YAML::Key << "mosaic_georef" << YAML::Value << w.mosaic_georef;
  out << YAML::Key << "width_m" << YAML::Value << w.procedural.width_m;
  out << YAML::Key << "height_m" << YAML::Value << w.procedural.height_m;
  out << YAML::Key << "metres_per_px" << YAML::Value << w.auto_metres_per_px;
  out << YAML::Key << "featureless_fraction" << YAML::Value << w.procedural.featureless_fraction;
  out << YAML::Key << "seagrass_fraction" << YAML::Value << w.procedural.seagrass_fraction;
  out << YAML::Key << "rock_density_per_m2" << YAML::Value << w.procedural.rock_density_per_m2;
  out << YAML::Key << "pebble_density_per_m2" << YAML::Value << w.procedural.pebble_density_per_m2;
  out << YAML::EndMap;
  out << YAML::Key << "nav_datum" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "name" << YAML::Value << spec.nav_datum.name;
  out << YAML::Key << "origin_lat_lon_deg" << YAML::Value;
  vec(Eigen::Map<const Eigen::VectorXd>(spec.nav_datum.origin_lat_lon_deg.data(),
                                        static_cast<Eigen::Index>(spec.nav_datum.origin_lat_lon_deg.size())));
  out << YAML::EndMap;
  out << YAML::Key << "sessions" << YAML::Value << YAML::BeginSeq;
  for (const auto& s : spec.sessions) {
    out << YAML::BeginMap;
    out << YAML::Key << "name" << YAML::Value << s.name;
    out << YAML::Key << "altimeter_noise_m" << YAML::Value << s.altimeter_noise_m;
    out << YAML::Key << "image_format" << YAML::Value << s.image_format;
    out << YAML::Key << "jpeg_quality" << YAML::Value << s.jpeg_quality;
    out << YAML::Key << "camera" << YAML::Value << YAML::Flow << YAML::BeginMap;
    out << YAML::Key << "image_width" << YAML::Value << s.camera.width << YAML::Key << "image_height" << YAML::Value
        << s.camera.height << YAML::Key << "fx" << YAML::Value << s.camera.fx << YAML::Key << "fy" << YAML::Value
        << s.camera.fy << YAML::Key << "cx" << YAML::Value << s.camera.cx << YAML::Key << "cy" << YAML::Value
        << s.camera.cy;
    if (s.camera.distorted()) out << YAML::Key << "distortion" << YAML::Value << YAML::Flow << s.camera.distortion;
    out << YAML::EndMap;
    const auto& m = s.mission;
    out << YAML::Key << "mission" << YAML::Value << YAML::BeginMap;
    out << YAML::Key << "pattern" << YAML::Value << patternName(m.pattern);
    out << YAML::Key << "start_m" << YAML::Value;
    vec(m.start_m);
    out << YAML::Key << "heading_rad" << YAML::Value << m.heading_rad;
    out << YAML::Key << "length_m" << YAML::Value << m.length_m;
    out << YAML::Key << "width_m" << YAML::Value << m.width_m;
    out << YAML::Key << "leg_spacing_m" << YAML::Value << m.leg_spacing_m;
    out << YAML::Key << "laps" << YAML::Value << m.laps;
    out << YAML::Key << "speed_m_s" << YAML::Value << m.speed_m_s;
    out << YAML::Key << "frame_period_s" << YAML::Value << m.frame_period_s;
    out << YAML::Key << "camera_yaw_offset_rad" << YAML::Value << m.camera_yaw_offset_rad;
    out << YAML::Key << "altitude_m" << YAML::Value << m.altitude_m;
    out << YAML::Key << "altitude_amplitude_m" << YAML::Value << m.altitude_amplitude_m;
    out << YAML::Key << "altitude_period_m" << YAML::Value << m.altitude_period_m;
    out << YAML::Key << "wobble_yaw_rad" << YAML::Value << m.wobble_yaw_rad;
    out << YAML::Key << "wobble_period_m" << YAML::Value << m.wobble_period_m;
    out << YAML::Key << "start_time_s" << YAML::Value << m.start_time_s;
    out << YAML::EndMap;
    const auto& wa = s.water;
    out << YAML::Key << "water" << YAML::Value << YAML::BeginMap;
    out << YAML::Key << "illumination" << YAML::Value << wa.illumination;
    out << YAML::Key << "colour_gain_bgr" << YAML::Value;
    vec(wa.colour_gain_bgr);
    out << YAML::Key << "vignetting" << YAML::Value << wa.vignetting;
    out << YAML::Key << "light_cone" << YAML::Value << wa.light_cone;
    out << YAML::Key << "light_cone_width" << YAML::Value << wa.light_cone_width;
    out << YAML::Key << "light_cone_offset" << YAML::Value;
    vec(wa.light_cone_offset);
    out << YAML::Key << "turbidity_per_m" << YAML::Value << wa.turbidity_per_m;
    out << YAML::Key << "backscatter_bgr" << YAML::Value;
    vec(wa.backscatter_bgr);
    out << YAML::Key << "motion_blur_exposure_s" << YAML::Value << wa.motion_blur_exposure_s;
    out << YAML::Key << "marine_snow_per_frame" << YAML::Value << wa.marine_snow_per_frame;
    out << YAML::Key << "noise_sigma" << YAML::Value << wa.noise_sigma;
    out << YAML::Key << "stretches" << YAML::Value << YAML::BeginSeq;
    for (const auto& st : wa.stretches) {
      out << YAML::Flow << YAML::BeginMap << YAML::Key << "first_frame" << YAML::Value << st.first_frame << YAML::Key
          << "num_frames" << YAML::Value << st.num_frames << YAML::Key << "kind" << YAML::Value
          << (st.kind == FrameStretch::Kind::kBlank ? "blank" : "occluded") << YAML::EndMap;
    }
    out << YAML::EndSeq;
    out << YAML::EndMap;
    out << YAML::Key << "nav" << YAML::Value << YAML::BeginMap;
    out << YAML::Key << "enabled" << YAML::Value << s.nav.enabled;
    out << YAML::Key << "scale_error" << YAML::Value << s.nav.scale_error;
    out << YAML::Key << "heading_bias_rad" << YAML::Value << s.nav.heading_bias_rad;
    out << YAML::Key << "random_walk_m_per_sqrt_m" << YAML::Value << s.nav.random_walk_m_per_sqrt_m;
    out << YAML::Key << "heading_random_walk_rad_per_sqrt_m" << YAML::Value << s.nav.heading_random_walk_rad_per_sqrt_m;
    out << YAML::Key << "frame" << YAML::Value << navOutputFrameName(s.nav.frame);
    out << YAML::EndMap;
    out << YAML::EndMap;
  }
  out << YAML::EndSeq;
  out << YAML::EndMap;
  return std::string(out.c_str()) + "\n";
}

}  // namespace core
}  // namespace uw_multislam
