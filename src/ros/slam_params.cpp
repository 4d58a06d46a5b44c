#include "uw_multislam/ros/slam_params.h"

#include <ros/console.h>
#include <ros/names.h>
#include <ros/param.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>

#include <yaml-cpp/yaml.h>

#include "uw_multislam/core/export/geo_datum.h"

namespace uw_multislam {
namespace ros_params {

namespace {

void emit(YAML::Emitter& out, XmlRpc::XmlRpcValue& v) {
  switch (v.getType()) {
    case XmlRpc::XmlRpcValue::TypeBoolean:
      out << static_cast<bool>(v);
      break;
    case XmlRpc::XmlRpcValue::TypeInt:
      out << static_cast<int>(v);
      break;
    case XmlRpc::XmlRpcValue::TypeDouble:
      out << static_cast<double>(v);
      break;
    case XmlRpc::XmlRpcValue::TypeString:
      // Quoted, so that the core's reader refuses text where a number or a bool belongs ('43',
      // 'true'), as in a YAML file; rosparam's numbers left as text (1e-06) stay numbers.
      if (isRosparamNumberText(static_cast<std::string&>(v)))
        out << static_cast<std::string&>(v);
      else
        out << YAML::DoubleQuoted << static_cast<std::string&>(v);
      break;
    case XmlRpc::XmlRpcValue::TypeArray:
      out << YAML::Flow << YAML::BeginSeq;
      for (int i = 0; i < v.size(); ++i) emit(out, v[i]);
      out << YAML::EndSeq;
      break;
    case XmlRpc::XmlRpcValue::TypeStruct:
      out << YAML::BeginMap;
      for (auto& kv : v) {
        out << YAML::Key << kv.first << YAML::Value;
        emit(out, kv.second);
      }
      out << YAML::EndMap;
      break;
    default:
      out << YAML::Null;
      break;  // invalid, date-time, base64: not in our parameters
  }
}

}  // namespace

std::string xmlRpcToYaml(const XmlRpc::XmlRpcValue& value) {
  XmlRpc::XmlRpcValue copy = value;  // the accessors are not const
  YAML::Emitter out;
  out.SetDoublePrecision(17);
  emit(out, copy);
  return out.c_str();
}

core::SlamConfig slamConfigFromXmlRpc(const XmlRpc::XmlRpcValue& tree, const std::string& where) {
  try {
    if (tree.getType() != XmlRpc::XmlRpcValue::TypeStruct) throw std::invalid_argument("must be a map of blocks");
    return core::slamConfigFromYaml(xmlRpcToYaml(tree));
  } catch (const std::exception& e) {
    throw std::invalid_argument(where + ": " + e.what());
  }
}

core::SlamConfig slamConfigFromParams(const Params& nh, const std::string& key) {
  const XmlRpc::XmlRpcValue* tree = nh.find(key);
  if (tree == nullptr) return core::SlamConfig();
  return slamConfigFromXmlRpc(*tree, nh.resolve(key));
}

core::SlamConfig slamConfigFromParams(const ros::NodeHandle& nh, const std::string& key) {
  XmlRpc::XmlRpcValue tree;
  if (!nh.getParam(key, tree)) return core::SlamConfig();
  return slamConfigFromXmlRpc(tree, nh.resolveName(key));
}

void checkDatumFrames(const ros_frames::FrameOptions& f, const std::string& datum_key) {
  if (f.earth_frame == f.map_frame || f.earth_frame == f.odom_frame || f.earth_frame == f.base_frame)
    throw std::invalid_argument(datum_key + "/earth_frame: must differ from map, odom and base frames");
  if (f.utm_frame.empty()) return;
  if (!f.datum)
    throw std::invalid_argument(datum_key + "/utm_frame: needs the datum (datum/latitude_deg and datum/longitude_deg)");
  if (f.utm_frame == f.map_frame || f.utm_frame == f.odom_frame || f.utm_frame == f.base_frame ||
      f.utm_frame == f.earth_frame)
    throw std::invalid_argument(datum_key + "/utm_frame: must differ from map, odom, base and earth frames");
  // Refused here, before the store is opened, rather than by FramePublisher::setDatum after it.
  try {
    core::utmFromMap(*f.datum);
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(datum_key + "/utm_frame: no UTM frame for this datum (" + e.what() +
                                "); leave utm_frame empty");
  }
}

void readFrames(const Params& nh, ros_frames::FrameOptions* f) {
  auto nonempty = [](const std::string& s) { return !s.empty(); };
  param(nh, "frames/map_frame", &f->map_frame, nonempty, "a frame id");
  param(nh, "frames/session_frame_prefix", &f->session_frame_prefix, nonempty, "a non-empty frame id prefix");
  param(nh, "frames/base_frame", &f->base_frame, nonempty, "a frame id");
  param(nh, "frames/odom_frame", &f->odom_frame, nonempty, "a frame id");
  if (f->odom_frame == f->map_frame || f->odom_frame == f->base_frame || f->map_frame == f->base_frame)
    throw std::invalid_argument(nh.resolve("frames") + ": map_frame, odom_frame and base_frame must differ");
  f->mount = ros_frames::mountOptions(nh);
}

namespace {

// ~datum/*: map's origin on WGS84 when both coordinates are set, and the earth and UTM frames.
void readDatum(const Params& pnh, ros_frames::FrameOptions* f) {
  // A datum needs both coordinates: one without the other would put map somewhere wrong, silently.
  const bool has_lat = pnh.has("datum/latitude_deg"), has_lon = pnh.has("datum/longitude_deg");
  if (has_lat != has_lon)
    throw std::invalid_argument(pnh.resolve("datum") + ": latitude_deg and longitude_deg together or not at all");
  core::GeoOrigin d{0.0, 0.0, core::kEnuHeadingDeg};  // without ~datum/heading_deg: the first keyframe's x east
  param(
      pnh, "datum/latitude_deg", &d.lat_deg, [](double v) { return std::abs(v) <= 90.0; }, "in [-90, 90] degrees");
  param(
      pnh, "datum/longitude_deg", &d.lon_deg, [](double v) { return std::abs(v) <= 180.0; }, "in [-180, 180] degrees");
  param(
      pnh, "datum/heading_deg", &d.heading_deg, [](double v) { return std::abs(v) <= 360.0; },
      "in [-360, 360] degrees (the compass heading of the first keyframe's x axis; map is ENU)");
  param(
      pnh, "datum/altitude_m", &d.alt_m, [](double v) { return std::abs(v) <= core::kMaxDatumAltitudeM; },
      "in [-10000, 10000] m (the height of map's origin above the WGS84 ellipsoid)");
  if (has_lat) f->datum = d;
  param(
      pnh, "datum/earth_frame", &f->earth_frame, [](const std::string& s) { return !s.empty(); }, "a frame id");
  // Empty (the default): no UTM frame. navsat_transform's name for it is utm.
  param(pnh, "datum/utm_frame", &f->utm_frame);
  checkDatumFrames(*f, pnh.resolve("datum"));
}

}  // namespace

BackendNodeletOptions backendNodeletOptions(const ros::NodeHandle& nh, const ros::NodeHandle& pnh) {
  warnAboutFormerPrivateNamespace(pnh);
  return backendNodeletOptions(Params(nh), Params(pnh));
}

BackendNodeletOptions backendNodeletOptions(const Params& nh, const Params& pnh) {
  BackendNodeletOptions o;
  auto count = [](int v) { return v >= 1 && v <= 1000000; };
  auto positive = [](double v) { return v > 0; };
  readFrames(nh, &o.frames);
  param(pnh, "queue_size", &o.queue_size, count, "in [1, 1000000]");
  param(pnh, "max_waiting_loops", &o.max_waiting_loops, count, "in [1, 1000000]");
  param(
      pnh, "worker_nice", &o.worker_nice, [](int v) { return v >= 0 && v <= 19; }, "in [0, 19]");
  param(pnh, "max_keyframe_gap", &o.max_keyframe_gap, count, "in [1, 1000000]");
  param(
      pnh, "max_empty_sessions", &o.max_empty_sessions, [](int v) { return v >= 1 && v <= 1000; }, "in [1, 1000]");
  param(pnh, "publish_tf", &o.frames.publish_tf);
  param(pnh, "publish_odom_tf", &o.frames.publish_odom_tf);
  param(pnh, "publish_session_frames", &o.frames.publish_session_frames);
  readDatum(pnh, &o.frames);
  param(
      pnh, "tf_rate", &o.frames.tf_rate_hz, [](double v) { return v > 0 && v <= 1000; }, "in (0, 1000] Hz");
  param(
      pnh, "tf_future_s", &o.frames.tf_future_s, [](double v) { return v >= 0 && v <= 1; }, "in [0, 1] s");
  param(pnh, "stats_period_s", &o.stats_period_s, positive, "positive");
  param(pnh, "diagnostic_period", &o.diagnostic_period_s, positive, "positive");
  param(pnh, "store_path", &o.store_path);
  param(
      pnh, "mosaic_rate", &o.mosaic_rate_hz, [](double v) { return v >= 0 && v <= 10; },
      "in [0, 10] Hz (0: no live mosaic)");
  param(
      pnh, "mosaic_resolution", &o.mosaic.resolution_m, [](double v) { return v > 0 && v <= 100; }, "in (0, 100] m/px");
  param(
      pnh, "mosaic_max_side", &o.mosaic.max_side_px, [](int v) { return v >= 16 && v <= 8192; }, "in [16, 8192] px");
  param(pnh, "export_root", &o.export_root);
  param(
      pnh, "store_max_mb", &o.store_max_mb, [](double v) { return v >= 0 && v <= 1e9; }, "in [0, 1e9] MB (0: no cap)");
  param(
      pnh, "mode", &o.mode, [](const std::string& m) { return m == "mapping" || m == "localisation"; },
      "mapping or localisation");
  param(pnh, "reload_stored", &o.reload_stored);
  param(
      pnh, "fleet/vehicle", &o.fleet_vehicle,
      [](const std::string& v) { return v.empty() || core::validVehicleName(v); },
      "empty (off) or 1 to 64 characters of A-Z a-z 0-9 _ -");
  param(pnh, "fix/topic", &o.fix_topic);
  param(
      pnh, "fix/max_dt_s", &o.fix.max_dt_s, [](double v) { return v > 0 && v <= 60; }, "in (0, 60] s");
  param(
      pnh, "fix/default_sigma_m", &o.fix.default_sigma_m, [](double v) { return v >= 0 && v <= 1e4; },
      "in [0, 10000] m (0: a fix of unknown covariance is refused)");
  param(pnh, "fix/max_waiting", &o.fix.max_waiting, count, "in [1, 1000000]");
  param(
      pnh, "fix/gate_chi2", &o.fix.gate_chi2, [](double v) { return v >= 0 && v <= 1e6; }, "in [0, 1e6] (0: no gate)");
  param(
      pnh, "fix/gate_inflation", &o.fix.gate_inflation, [](double v) { return v >= 1 && v <= 1e6; }, "in [1, 1e6]");
  param(pnh, "fleet/hash_codes", &o.fleet_hash_codes);
  param(
      pnh, "fleet/peer_timeout_s", &o.fleet_peer_timeout_s, [](double t) { return t > 0.0 && t <= 3600.0; },
      "in (0, 3600] seconds");
  param(pnh, "fleet/peers", &o.fleet_peers);
  for (const auto& [vehicle, service] : o.fleet_peers) {
    std::string bad_name;
    if (!core::validVehicleName(vehicle) || vehicle == o.fleet_vehicle || service.empty() ||
        !ros::names::validate(service, bad_name))
      throw std::invalid_argument(pnh.resolve("fleet/peers") + ": '" + vehicle + "': '" + service +
                                  "': another vehicle's name (A-Z a-z 0-9 _ -) and a valid service name" +
                                  (bad_name.empty() ? "" : " (" + bad_name + ")"));
  }
  return o;
}

core::SessionManagerOptions sessionManagerOptions(const BackendNodeletOptions& o, const core::SlamConfig& config) {
  core::SessionManagerOptions m = core::sessionManagerOptions(config, o.store_path);
  m.max_keyframe_gap = o.max_keyframe_gap;
  m.max_empty_sessions = o.max_empty_sessions;
  m.store_max_mb = o.store_max_mb;
  m.requester = "service";  // the audit trail's cause of the requests this head makes
  return m;
}

std::unique_ptr<core::SessionWorker> makeSessionWorker(const BackendNodeletOptions& o, const core::SlamConfig& config,
                                                       core::SessionManager::EventSink events,
                                                       std::function<void(const std::string&)> say) {
  if (o.store_path.empty()) ROS_WARN("back-end: no session store (~store_path empty): in memory only");
  auto manager = std::make_unique<core::SessionManager>(sessionManagerOptions(o, config), std::move(events), say);
  if (o.localisation()) manager->setLocalisation(true);  // ~mode: nothing written from the start
  using S = core::SessionWorker::Severity;
  return std::make_unique<core::SessionWorker>(std::move(manager), sessionWorkerOptions(o, config),
                                               [say](S s, const std::string& line) {
                                                 if (s == S::kInfo) say(line);
                                                 if (s == S::kWarn) ROS_WARN_THROTTLE(5, "back-end: %s", line.c_str());
                                                 if (s == S::kError)
                                                   ROS_ERROR_THROTTLE(5, "back-end: %s", line.c_str());
                                               });
}

std::vector<std::string> describeBackend(const BackendNodeletOptions& o, const core::SlamConfig& config) {
  const core::BackendOptions& b = config.backend;
  const ros_frames::FrameOptions& f = o.frames;
  char optimiser[600], mosaic[400];
  std::snprintf(optimiser, sizeof optimiser,
                "optimiser %s (optimise %s, every %d pending loops), join after %d global loops (gate %.2f m), tf %s "
                "(%s -> %s at %.0f Hz, %s -> %s from %s), queue_size %d, store ",
                core::optimizerName(b.optimizer), b.optimise ? "on" : "off", b.optimise_every, b.join_min_loops,
                b.join_gate_m, f.publish_tf ? "on" : "off", f.map_frame.c_str(), f.odom_frame.c_str(), f.tf_rate_hz,
                f.odom_frame.c_str(), f.base_frame.c_str(),
                f.publish_odom_tf ? "the visual odometry" : "the vehicle (tf)", o.queue_size);
  std::snprintf(mosaic, sizeof mosaic, "live mosaic %s (%.2f Hz, %.3f m/px, at most %d px), exports below ",
                o.mosaic_rate_hz > 0 ? "on" : "off", o.mosaic_rate_hz, o.mosaic.resolution_m, o.mosaic.max_side_px);
  return {optimiser + (o.store_path.empty() ? std::string("none") : o.store_path),
          mosaic + (o.export_root.empty() ? std::string("(none: off)") : o.export_root)};
}

core::SessionWorkerOptions sessionWorkerOptions(const BackendNodeletOptions& o, const core::SlamConfig& config) {
  core::SessionWorkerOptions w;
  w.queue_size = o.queue_size;
  w.max_waiting_loops = o.max_waiting_loops;
  w.page_stored = config.loops.page_stored;
  w.nice = o.worker_nice;
  return w;
}

LoopDetectorNodeletOptions loopDetectorNodeletOptions(const ros::NodeHandle& pnh) {
  warnAboutFormerPrivateNamespace(pnh);
  return loopDetectorNodeletOptions(Params(pnh));
}

LoopDetectorNodeletOptions loopDetectorNodeletOptions(const Params& pnh) {
  LoopDetectorNodeletOptions o;
  auto positive = [](double v) { return v > 0; };
  param(
      pnh, "mode", &o.mode, [](const std::string& m) { return m == "both" || m == "local" || m == "global"; },
      "one of both, local, global");
  param(
      pnh, "queue_size", &o.queue_size, [](int v) { return v >= 1 && v <= 100000; }, "in [1, 100000]");
  param(
      pnh, "max_keyframe_gap", &o.max_keyframe_gap, [](int v) { return v >= 1 && v <= 1000000; }, "in [1, 1000000]");
  param(pnh, "stats_period_s", &o.stats_period_s, positive, "positive");
  param(pnh, "diagnostic_period", &o.diagnostic_period_s, positive, "positive");
  param(
      pnh, "worker_nice", &o.worker_nice, [](int v) { return v >= 0 && v <= 19; }, "in [0, 19]");
  return o;
}

core::SlamConfig loopDetectorConfig(const ros::NodeHandle& nh, const LoopDetectorNodeletOptions& o) {
  return loopDetectorConfig(Params(nh), o);
}

core::SlamConfig loopDetectorConfig(const Params& nh, const LoopDetectorNodeletOptions& o) {
  core::SlamConfig config = slamConfigFromParams(nh);
  const std::string bad = config.validate();
  if (!bad.empty()) throw std::invalid_argument(nh.resolve("slam") + ": " + bad);
  config.loops.local.enabled = config.loops.local.enabled && o.mode != "global";
  config.loops.global.enabled = config.loops.global.enabled && o.mode != "local";
  return config;
}

std::string describe(const LoopDetectorNodeletOptions& o, const core::SlamConfig& config) {
  const core::LoopOptions& l = config.loops;
  char line[1024];
  std::snprintf(
      line, sizeof(line),
      "mode %s (local %s: radius %.2f m up to %.2f m, %d candidates, %d inliers; global %s: hash %s, best_k %d, %d "
      "inliers, seed %llu), queue_size %d (oldest dropped when full), max_keyframe_gap %d, hashes %s, stored "
      "keyframes %s",
      o.mode.c_str(), l.local.enabled ? "on" : "off", l.local.radius_m, l.local.max_radius_m, l.local.max_candidates,
      l.local.min_inliers, l.global.enabled ? "on" : "off", core::hashModeName(l.global.hash_mode).c_str(),
      l.global.best_k, l.global.min_inliers, static_cast<unsigned long long>(l.global.projection_seed), o.queue_size,
      o.max_keyframe_gap, o.publishHashes() ? "published" : "not published",
      l.page_stored ? ("paged (features from the back-end's store through a " + std::to_string(l.feature_cache_mb) +
                       " MiB cache)")
                          .c_str()
                    : "kept in RAM with their features");
  return line;
}

std::string formerPrivateNamespace(const std::string& private_ns) {
  static const char* const kFormerNames[] = {"odometry", "loop_detector", "local_loops", "global_loops", "backend"};
  const std::size_t slash = private_ns.rfind('/');
  const std::string parent = slash == std::string::npos ? std::string() : private_ns.substr(0, slash + 1);
  const std::string name = slash == std::string::npos ? private_ns : private_ns.substr(slash + 1);
  for (const char* former : kFormerNames) {
    if (name == std::string(former) + "_node") return parent + former;
  }
  return "";
}

bool warnAboutFormerPrivateNamespace(const ros::NodeHandle& pnh) {
  const std::string current = pnh.getNamespace();
  const std::string former = formerPrivateNamespace(current);
  XmlRpc::XmlRpcValue old;
  if (former.empty() || !ros::param::get(former, old) || old.getType() != XmlRpc::XmlRpcValue::TypeStruct ||
      old.size() == 0) {
    return false;
  }
  std::string keys;
  for (const auto& kv : old) keys += (keys.empty() ? "" : ", ") + kv.first;
  ROS_WARN_STREAM("parameters under " << former << " are not read any more: this node's parameters are " << current
                                      << "/... (the node was renamed; rename that block of your config file, see "
                                         "config/default.yaml). Not read: "
                                      << keys);
  return true;
}

std::string defaultExportRoot() {
  const char* ros_home = std::getenv("ROS_HOME");
  const char* home = std::getenv("HOME");
  return (ros_home ? std::string(ros_home) : std::string(home ? home : ".") + "/.ros") + "/uw_multislam/exports";
}

std::string defaultStorePath() {
  const char* ros_home = std::getenv("ROS_HOME");
  const char* home = std::getenv("HOME");
  return (ros_home ? std::string(ros_home) : std::string(home ? home : ".") + "/.ros") + "/uw_multislam/sessions.db";
}

}  // namespace ros_params
}  // namespace uw_multislam
