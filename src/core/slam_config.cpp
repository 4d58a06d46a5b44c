#include "uw_multislam/core/slam_config.h"

#include <fstream>
#include <sstream>

#include "uw_multislam/core/yaml_map_reader.h"

namespace uw_multislam {
namespace core {

namespace {

void readOdometry(const YAML::Node& node, OdometryOptions* o) {
  MapReader r(node, "odometry");
  {
    MapReader e(r.child("enhancement"), "odometry.enhancement");
    std::string mode = enhancementName(o->enhancement.mode);
    e.read("mode", &mode);
    if (!parseEnhancement(mode, &o->enhancement.mode)) {
      e.fail("unknown mode '" + mode + "' (none, clahe, dehaze, dehaze_clahe)");
    }
    e.read("clahe_clip_limit", &o->enhancement.clahe_clip_limit);
    e.read("clahe_tile_grid", &o->enhancement.clahe_tile_grid);
    e.read("dark_channel_patch_px", &o->enhancement.dark_channel_patch_px);
    e.read("dehaze_omega", &o->enhancement.dehaze_omega);
    e.read("dehaze_t0", &o->enhancement.dehaze_t0);
    e.read("guided_filter_radius_px", &o->enhancement.guided_filter_radius_px);
    e.read("guided_filter_eps", &o->enhancement.guided_filter_eps);
    e.read("stretch_low_percentile", &o->enhancement.stretch_low_percentile);
    e.read("stretch_high_percentile", &o->enhancement.stretch_high_percentile);
    e.finish();
  }
  {
    MapReader f(r.child("features"), "odometry.features");
    f.read("num_features", &o->features.num_features);
    f.read("grid_rows", &o->features.grid_rows);
    f.read("grid_cols", &o->features.grid_cols);
    f.read("candidate_factor", &o->features.candidate_factor);
    f.read("contrast_threshold", &o->features.contrast_threshold);
    f.read("edge_threshold", &o->features.edge_threshold);
    f.read("sigma", &o->features.sigma);
    f.read("octave_layers", &o->features.octave_layers);
    f.read("border_px", &o->features.border_px);
    f.finish();
  }
  {
    MapReader m(r.child("matching"), "odometry.matching");
    m.read("ratio", &o->matching.ratio);
    m.read("mutual", &o->matching.mutual);
    m.finish();
  }
  {
    MapReader a(r.child("ransac"), "odometry.ransac");
    a.read("inlier_threshold_px", &o->ransac.inlier_threshold_px);
    a.read("min_inliers", &o->ransac.min_inliers);
    a.read("confidence", &o->ransac.confidence);
    a.read("min_iterations", &o->ransac.min_iterations);
    a.read("max_iterations", &o->ransac.max_iterations);
    a.read("refine_iterations", &o->ransac.refine_iterations);
    a.read("min_noise_px", &o->ransac.min_noise_px);
    a.read("seed", &o->ransac.seed);
    a.read("estimate_scale", &o->ransac.estimate_scale);
    a.read("max_scale_change", &o->ransac.max_scale_change);
    a.finish();
  }
  {
    MapReader k(r.child("keyframes"), "odometry.keyframes");
    k.read("min_overlap", &o->keyframes.min_overlap);
    k.read("max_rotation_rad", &o->keyframes.max_rotation_rad);
    k.read("max_interval_s", &o->keyframes.max_interval_s);
    k.read("min_tracking_inliers", &o->keyframes.min_tracking_inliers);
    k.finish();
  }
  {
    MapReader b(r.child("fallback"), "odometry.fallback");
    b.read("min_sigma_m", &o->fallback.min_sigma_m);
    b.read("relative_sigma", &o->fallback.relative_sigma);
    b.read("sigma_yaw_rad", &o->fallback.sigma_yaw_rad);
    b.finish();
  }
  r.finish();
}

void readLoops(const YAML::Node& node, LoopOptions* o) {
  MapReader r(node, "loops");
  {
    MapReader l(r.child("local"), "loops.local");
    l.read("enabled", &o->local.enabled);
    l.read("radius_m", &o->local.radius_m);
    l.read("sigma_widening", &o->local.sigma_widening);
    l.read("max_radius_m", &o->local.max_radius_m);
    l.read("exclude_recent", &o->local.exclude_recent);
    l.read("max_candidates", &o->local.max_candidates);
    l.read("min_inliers", &o->local.min_inliers);
    l.finish();
  }
  {
    MapReader g(r.child("global"), "loops.global");
    g.read("enabled", &o->global.enabled);
    g.read("best_k", &o->global.best_k);
    g.read("max_l1", &o->global.max_l1);
    g.read("min_inliers", &o->global.min_inliers);
    g.read("projection_seed", &o->global.projection_seed);
    std::string mode = hashModeName(o->global.hash_mode);
    g.read("hash_mode", &mode);
    if (!parseHashMode(mode, &o->global.hash_mode)) g.fail("unknown hash_mode '" + mode + "' (sorted_dct, haloc)");
    g.finish();
  }
  r.finish();
}

}  // namespace

std::string SlamConfig::validate() const {
  const std::string o = odometry.validate();
  if (!o.empty()) return "odometry." + o;
  const std::string l = loops.validate();
  return l.empty() ? l : "loops." + l;
}

SlamConfig slamConfigFromYaml(const std::string& yaml_text) {
  YAML::Node root;
  try {
    root = YAML::Load(yaml_text);
  } catch (const YAML::Exception& e) {
    throw std::invalid_argument(std::string("config YAML: ") + e.what());
  }
  SlamConfig c;
  MapReader r(root, "config");
  readOdometry(r.child("odometry"), &c.odometry);
  readLoops(r.child("loops"), &c.loops);
  r.finish();
  const std::string bad = c.validate();
  if (!bad.empty()) throw std::invalid_argument("config: " + bad);
  return c;
}

SlamConfig loadSlamConfig(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw DatasetError(path + ": cannot open");
  std::stringstream ss;
  ss << in.rdbuf();
  try {
    return slamConfigFromYaml(ss.str());
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(path + ": " + e.what());
  }
}

std::string slamConfigToYaml(const SlamConfig& c) {
  const OdometryOptions& o = c.odometry;
  YAML::Emitter out;
  out.SetDoublePrecision(10);
  auto kv = [&out](const char* k, const auto& v) { out << YAML::Key << k << YAML::Value << v; };
  out << YAML::BeginMap << YAML::Key << "odometry" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "enhancement" << YAML::Value << YAML::BeginMap;
  kv("mode", enhancementName(o.enhancement.mode));
  kv("clahe_clip_limit", o.enhancement.clahe_clip_limit);
  kv("clahe_tile_grid", o.enhancement.clahe_tile_grid);
  kv("dark_channel_patch_px", o.enhancement.dark_channel_patch_px);
  kv("dehaze_omega", o.enhancement.dehaze_omega);
  kv("dehaze_t0", o.enhancement.dehaze_t0);
  kv("guided_filter_radius_px", o.enhancement.guided_filter_radius_px);
  kv("guided_filter_eps", o.enhancement.guided_filter_eps);
  kv("stretch_low_percentile", o.enhancement.stretch_low_percentile);
  kv("stretch_high_percentile", o.enhancement.stretch_high_percentile);
  out << YAML::EndMap << YAML::Key << "features" << YAML::Value << YAML::BeginMap;
  kv("num_features", o.features.num_features);
  kv("grid_rows", o.features.grid_rows);
  kv("grid_cols", o.features.grid_cols);
  kv("candidate_factor", o.features.candidate_factor);
  kv("contrast_threshold", o.features.contrast_threshold);
  kv("edge_threshold", o.features.edge_threshold);
  kv("sigma", o.features.sigma);
  kv("octave_layers", o.features.octave_layers);
  kv("border_px", o.features.border_px);
  out << YAML::EndMap << YAML::Key << "matching" << YAML::Value << YAML::BeginMap;
  kv("ratio", o.matching.ratio);
  kv("mutual", o.matching.mutual);
  out << YAML::EndMap << YAML::Key << "ransac" << YAML::Value << YAML::BeginMap;
  kv("inlier_threshold_px", o.ransac.inlier_threshold_px);
  kv("min_inliers", o.ransac.min_inliers);
  kv("confidence", o.ransac.confidence);
  kv("min_iterations", o.ransac.min_iterations);
  kv("max_iterations", o.ransac.max_iterations);
  kv("refine_iterations", o.ransac.refine_iterations);
  kv("min_noise_px", o.ransac.min_noise_px);
  kv("seed", o.ransac.seed);
  kv("estimate_scale", o.ransac.estimate_scale);
  kv("max_scale_change", o.ransac.max_scale_change);
  out << YAML::EndMap << YAML::Key << "keyframes" << YAML::Value << YAML::BeginMap;
  kv("min_overlap", o.keyframes.min_overlap);
  kv("max_rotation_rad", o.keyframes.max_rotation_rad);
  kv("max_interval_s", o.keyframes.max_interval_s);
  kv("min_tracking_inliers", o.keyframes.min_tracking_inliers);
  out << YAML::EndMap << YAML::Key << "fallback" << YAML::Value << YAML::BeginMap;
  kv("min_sigma_m", o.fallback.min_sigma_m);
  kv("relative_sigma", o.fallback.relative_sigma);
  kv("sigma_yaw_rad", o.fallback.sigma_yaw_rad);
  out << YAML::EndMap << YAML::EndMap;
  const LoopOptions& l = c.loops;
  out << YAML::Key << "loops" << YAML::Value << YAML::BeginMap;
  out << YAML::Key << "local" << YAML::Value << YAML::BeginMap;
  kv("enabled", l.local.enabled);
  kv("radius_m", l.local.radius_m);
  kv("sigma_widening", l.local.sigma_widening);
  kv("max_radius_m", l.local.max_radius_m);
  kv("exclude_recent", l.local.exclude_recent);
  kv("max_candidates", l.local.max_candidates);
  kv("min_inliers", l.local.min_inliers);
  out << YAML::EndMap << YAML::Key << "global" << YAML::Value << YAML::BeginMap;
  kv("enabled", l.global.enabled);
  kv("best_k", l.global.best_k);
  kv("max_l1", l.global.max_l1);
  kv("min_inliers", l.global.min_inliers);
  kv("projection_seed", l.global.projection_seed);
  kv("hash_mode", hashModeName(l.global.hash_mode));
  out << YAML::EndMap << YAML::EndMap << YAML::EndMap;
  return std::string(out.c_str()) + "\n";
}

}  // namespace core
}  // namespace uw_multislam
