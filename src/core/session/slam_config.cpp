#include "uw_multislam/core/session/slam_config.h"

#include <fstream>
#include <sstream>
#include <utility>

#include "uw_multislam/core/common/yaml_map_reader.h"

namespace uw_multislam {
namespace core {

namespace {

// Every option block lists its keys once, in visit*(); the same list reads the YAML (Reader)
// and writes it (Writer), so the file format cannot drift between the two.

class Reader {
 public:
  Reader(const YAML::Node& node, const std::string& where) : r_(node, where), where_(where) {}
  template <typename T>
  void operator()(const char* key, T& field) {
    r_.read(key, &field);
  }
  template <typename E, typename Name, typename Parse>
  void enumeration(const char* key, E& field, Name name, Parse parse, const char* choices) {
    std::string text = name(field);
    r_.read(key, &text);
    if (!parse(text, &field)) r_.fail("unknown " + std::string(key) + " '" + text + "' (" + choices + ")");
  }
  template <typename F>
  void block(const char* key, F visit) {
    Reader child(r_.child(key), where_ + "." + key);
    visit(child);
    child.finish();
  }
  void finish() const { r_.finish(); }

 private:
  MapReader r_;
  std::string where_;
};

class Writer {
 public:
  explicit Writer(YAML::Emitter& out) : out_(out) {}
  template <typename T>
  void operator()(const char* key, const T& field) {
    out_ << YAML::Key << key << YAML::Value << field;
  }
  template <typename E, typename Name, typename Parse>
  void enumeration(const char* key, const E& field, Name name, Parse, const char*) {
    out_ << YAML::Key << key << YAML::Value << name(field);
  }
  template <typename F>
  void block(const char* key, F visit) {
    out_ << YAML::Key << key << YAML::Value << YAML::BeginMap;
    visit(*this);
    out_ << YAML::EndMap;
  }

 private:
  YAML::Emitter& out_;
};

template <typename V, typename O>
void visitOdometry(V& v, O& o) {
  v("max_altitude_m", o.max_altitude_m);
  v.block("enhancement", [&](V& e) {
    e.enumeration("mode", o.enhancement.mode, enhancementName, parseEnhancement, "none, clahe, dehaze, dehaze_clahe");
    e("clahe_clip_limit", o.enhancement.clahe_clip_limit);
    e("clahe_tile_grid", o.enhancement.clahe_tile_grid);
    e("dark_channel_patch_px", o.enhancement.dark_channel_patch_px);
    e("dehaze_omega", o.enhancement.dehaze_omega);
    e("dehaze_t0", o.enhancement.dehaze_t0);
    e("guided_filter_radius_px", o.enhancement.guided_filter_radius_px);
    e("guided_filter_eps", o.enhancement.guided_filter_eps);
    e("stretch_low_percentile", o.enhancement.stretch_low_percentile);
    e("stretch_high_percentile", o.enhancement.stretch_high_percentile);
  });
  v.block("features", [&](V& f) {
    f.enumeration("type", o.features.type, featureTypeName, parseFeatureType, "sift, orb");
    f.enumeration("sift_backend", o.features.sift_backend, siftBackendName, parseSiftBackend, "auto, opencv, vlfeat");
    f("num_features", o.features.num_features);
    f("grid_rows", o.features.grid_rows);
    f("grid_cols", o.features.grid_cols);
    f("candidate_factor", o.features.candidate_factor);
    f("contrast_threshold", o.features.contrast_threshold);
    f("edge_threshold", o.features.edge_threshold);
    f("sigma", o.features.sigma);
    f("octave_layers", o.features.octave_layers);
    f("border_px", o.features.border_px);
    f("first_octave", o.features.first_octave);
    f("orb_fast_threshold", o.features.orb_fast_threshold);
    f("orb_levels", o.features.orb_levels);
    f("orb_scale_factor", o.features.orb_scale_factor);
  });
  v.block("matching", [&](V& m) {
    m("ratio", o.matching.ratio);
    m("binary_ratio", o.matching.binary_ratio);
    m("mutual", o.matching.mutual);
  });
  v.block("ransac", [&](V& a) {
    a("inlier_threshold_px", o.ransac.inlier_threshold_px);
    a("min_inliers", o.ransac.min_inliers);
    a("confidence", o.ransac.confidence);
    a("min_iterations", o.ransac.min_iterations);
    a("max_iterations", o.ransac.max_iterations);
    a("refine_iterations", o.ransac.refine_iterations);
    a("min_noise_px", o.ransac.min_noise_px);
    a("correlated_noise_px", o.ransac.correlated_noise_px);
    a("seed", o.ransac.seed);
    a("estimate_scale", o.ransac.estimate_scale);
    a("max_scale_change", o.ransac.max_scale_change);
  });
  v.block("keyframes", [&](V& k) {
    k("min_overlap", o.keyframes.min_overlap);
    k("max_rotation_rad", o.keyframes.max_rotation_rad);
    k("max_interval_s", o.keyframes.max_interval_s);
    k("min_tracking_inliers", o.keyframes.min_tracking_inliers);
  });
  v.block("fallback", [&](V& b) {
    b("min_sigma_m", o.fallback.min_sigma_m);
    b("relative_sigma", o.fallback.relative_sigma);
    b("sigma_yaw_rad", o.fallback.sigma_yaw_rad);
    b("bridge_frames", o.fallback.bridge_frames);
  });
  v.block("klt", [&](V& k) {
    k("enabled", o.klt.enabled);
    k("max_corners", o.klt.max_corners);
    k("corner_quality", o.klt.corner_quality);
    k("corner_min_distance_px", o.klt.corner_min_distance_px);
    k("border_px", o.klt.border_px);
    k("window_px", o.klt.window_px);
    k("pyramid_levels", o.klt.pyramid_levels);
    k("max_error", o.klt.max_error);
    k("max_forward_backward_px", o.klt.max_forward_backward_px);
    k("min_tracks", o.klt.min_tracks);
  });
  v.block("dense", [&](V& d) {
    d("enabled", o.dense.enabled);
    d("flat_field_sigma_px", o.dense.flat_field_sigma_px);
    d("contrast_threshold", o.dense.contrast_threshold);
    d("num_features", o.dense.num_features);
    d("ratio", o.dense.ratio);
    d("min_inliers", o.dense.min_inliers);
    d("inliers_per_overlap", o.dense.inliers_per_overlap);
    d("min_hull_fraction", o.dense.min_hull_fraction);
  });
}

template <typename V, typename O>
void visitLoops(V& v, O& o) {
  v("ratio", o.ratio);
  v("feature_cache_mb", o.feature_cache_mb);
  v("page_stored", o.page_stored);
  v("page_live_after", o.page_live_after);
  v.block("local", [&](V& l) {
    l("enabled", o.local.enabled);
    l("radius_m", o.local.radius_m);
    l("sigma_widening", o.local.sigma_widening);
    l("max_radius_m", o.local.max_radius_m);
    l("exclude_recent", o.local.exclude_recent);
    l("max_candidates", o.local.max_candidates);
    l("min_inliers", o.local.min_inliers);
  });
  v.block("global", [&](V& g) {
    g("enabled", o.global.enabled);
    g("best_k", o.global.best_k);
    g("max_l1", o.global.max_l1);
    g("min_inliers", o.global.min_inliers);
    g("projection_seed", o.global.projection_seed);
    g("follow_loops", o.global.follow_loops);
    g.enumeration("hash_mode", o.global.hash_mode, hashModeName, parseHashMode, "sorted_dct, haloc");
  });
}

template <typename V, typename B>
void visitBackend(V& v, B& b) {
  v("optimise", b.optimise);
  v.enumeration("optimizer", b.optimizer, optimizerName, parseOptimizer, "sparse, iekf");
  v("optimise_every", b.optimise_every);
  v("join_min_loops", b.join_min_loops);
  v("join_gate_m", b.join_gate_m);
  v.enumeration("join_policy", b.join_policy, joinPolicyName, parseJoinPolicy, "count, consistent");
  v("join_min_consistent", b.join_min_consistent);
  v("join_min_inliers", b.join_min_inliers);
  v("join_min_spread_m", b.join_min_spread_m);
  v("intra_loop_gate", b.intra_loop_gate);
  v("intra_gate_inflation", b.intra_gate_inflation);
  v("iekf_gate_inflation", b.iekf_gate_inflation);
  v("loop_residual_gate", b.loop_residual_gate);
  v("residual_gate_inflation", b.residual_gate_inflation);
  v("readmit_refused_loops", b.readmit_refused_loops);
  v.block("consistency", [&](V& c) {
    c("confidence", b.consistency.confidence);
    c("min_sigma_m", b.consistency.min_sigma_m);
    c("min_sigma_rad", b.consistency.min_sigma_rad);
    c("max_loops", b.consistency.max_loops);
  });
  v.block("iekf", [&](V& i) {
    i("max_iterations", b.iekf.max_iterations);
    i("tolerance", b.iekf.tolerance);
    i("max_keyframes", b.max_keyframes);
  });
  v.block("sparse", [&](V& s) {
    s("max_iterations", b.sparse.max_iterations);
    s("function_tolerance", b.sparse.function_tolerance);
    s.enumeration("robust_loss", b.sparse.robust_loss, robustLossName, parseRobustLoss, "none, huber, cauchy");
    s("loss_scale", b.sparse.loss_scale);
  });
}

template <typename V, typename C>
void visitConfig(V& v, C& c) {
  v.block("odometry", [&](V& o) { visitOdometry(o, c.odometry); });
  v.block("tracking", [&](V& t) {
    t("max_fallbacks", c.tracking.max_fallbacks);
    t("min_features", c.tracking.min_features);
    t("rejoin_keyframes", c.tracking.rejoin_keyframes);
  });
  v.block("nav", [&](V& n) {
    auto& o = c.odometry.nav;
    n("enabled", o.enabled);
    n.enumeration("on_tracking_loss", o.on_tracking_loss, trackingLossPolicyName, parseTrackingLossPolicy,
                  "new_session, dead_reckoning");
    n("inflation", o.inflation);
    n("min_sigma_m", o.min_sigma_m);
    n("min_sigma_rad", o.min_sigma_rad);
    n("gate_confidence", o.gate_confidence);
    n("fuse", o.fuse);
    n("gate_ransac", o.gate_ransac);
    n("min_features_to_restart", o.min_features_to_restart);
    n("max_speed_m_s", o.max_speed_m_s);
    n("max_yaw_rate_rad_s", o.max_yaw_rate_rad_s);
    n("place_pieces", o.place_pieces);
  });
  v.block("loops", [&](V& l) { visitLoops(l, c.loops); });
  v.block("backend", [&](V& b) { visitBackend(b, c.backend); });
  v.block("store", [&](V& s) {
    s("image_max_side_px", c.store_image.max_side_px);
    s("image_jpeg_quality", c.store_image.jpeg_quality);
  });
}

}  // namespace

std::string SlamConfig::validate() const {
  const std::string n = odometry.nav.validate();  // its keys are the top-level block `nav`
  if (!n.empty()) return "nav." + n;
  const std::string o = odometry.validate();
  if (!o.empty()) return "odometry." + o;
  const std::string t = tracking.validate();
  if (!t.empty()) return "tracking." + t;
  // A new session needs this many features of a frame; more than the extractor keeps never comes
  // (no session ever started, without a word).
  if (tracking.min_features > odometry.features.num_features)
    return "tracking.min_features " + std::to_string(tracking.min_features) +
           " is more than odometry.features.num_features " + std::to_string(odometry.features.num_features);
  const std::string l = loops.validate();
  if (!l.empty()) return "loops." + l;
  // A loop's inliers are matches between two keyframes' features: more than a keyframe keeps
  // never verifies one (no loop was ever found, without a word).
  for (const auto& [key, inliers] : {std::pair<const char*, int>{"loops.local.min_inliers", loops.local.min_inliers},
                                     std::pair<const char*, int>{"loops.global.min_inliers", loops.global.min_inliers}})
    if (inliers > odometry.features.num_features)
      return std::string(key) + " " + std::to_string(inliers) + " is more than odometry.features.num_features " +
             std::to_string(odometry.features.num_features) + ": no loop could be verified";
  const std::string b = backend.validate();
  if (!b.empty()) return "backend." + b;
  const std::string s = store_image.validate();
  return s.empty() ? s : "store." + s;
}

SlamConfig slamConfigFromYaml(const std::string& yaml_text) {
  const YAML::Node root = parseYaml(yaml_text, "config");
  SlamConfig c;
  Reader r(root, "config");
  visitConfig(r, c);
  r.finish();
  const std::string bad = c.validate();
  if (!bad.empty()) throw std::invalid_argument("config: " + bad);
  return c;
}

SlamConfig loadSlamConfig(const std::string& path) {
  return parseYamlFile(path, [](const std::string& text) { return slamConfigFromYaml(text); });
}

std::string slamConfigToYaml(const SlamConfig& c) {
  YAML::Emitter out;
  out.SetDoublePrecision(10);
  out << YAML::BeginMap;
  Writer w(out);
  visitConfig(w, c);
  out << YAML::EndMap;
  return std::string(out.c_str()) + "\n";
}

}  // namespace core
}  // namespace uw_multislam
