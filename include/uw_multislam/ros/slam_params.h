// Parameters of the nodelets. The algorithm options are the core's SlamConfig (the keys of
// config/slam.yaml), read from the parameter server tree where launch/core.launch loads that
// file (<namespace>/slam), so offline_slam and the nodelets share one file, one parser and one
// validation: missing keys keep their defaults, unknown keys and bad values are errors naming
// the key. The nodelets' own parameters are read through ros_params::Params (typed_params.h) into
// the options structs below, whose initialisers are the defaults. Tested in
// test/ros/test_slam_params.cpp, test_typed_params.cpp and test_config_defaults.cpp.
#pragma once

#include <ros/node_handle.h>
#include <xmlrpcpp/XmlRpcValue.h>

#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "uw_multislam/core/export/geo_fix.h"
#include "uw_multislam/core/export/live_mosaic.h"
#include "uw_multislam/core/session/session_manager.h"
#include "uw_multislam/core/session/session_worker.h"
#include "uw_multislam/core/session/slam_config.h"
#include "uw_multislam/ros/frame_publisher.h"
#include "uw_multislam/ros/topics.h"
#include "uw_multislam/ros/typed_params.h"

namespace uw_multislam {
namespace ros_params {

/// The session store's default path: $ROS_HOME/uw_multislam/sessions.db (ROS_HOME defaulting to
/// ~/.ros, as roslaunch's logs).
std::string defaultStorePath();
/// $ROS_HOME/uw_multislam/exports (ROS_HOME defaults to ~/.ros): the export service's default root.
std::string defaultExportRoot();

/// The parameter tree as YAML text (maps, lists, scalars; doubles with full precision).
std::string xmlRpcToYaml(const XmlRpc::XmlRpcValue& value);

/// The SlamConfig of a parameter tree (a map of blocks as in config/slam.yaml). Throws
/// std::invalid_argument "<where>: <reason>" for an unknown key, a bad value or a non-map.
core::SlamConfig slamConfigFromXmlRpc(const XmlRpc::XmlRpcValue& tree, const std::string& where);

/// The SlamConfig at `nh`/`key` (default "slam"); all defaults when the key is absent.
/// Throws std::invalid_argument "<resolved key>: <reason>" for an unknown key or a bad value.
core::SlamConfig slamConfigFromParams(const Params& nh, const std::string& key = "slam");
core::SlamConfig slamConfigFromParams(const ros::NodeHandle& nh, const std::string& key = "slam");

/// The nodelet's own parameters (~ private ones and the shared frames/ block; config/default.yaml
/// documents each), read once by backendNodeletOptions(). The algorithms' are core::SlamConfig.
/// Each default is written here once (or in the core's options it is handed to), and only here.
struct BackendNodeletOptions {
  std::string store_path = defaultStorePath();                       // "" = no store
  double store_max_mb = core::SessionManagerOptions().store_max_mb;  // a cap on the store file (0: none)
  std::string mode = "mapping";  // ~mode at start: mapping or localisation (SessionManager::setLocalisation)
  bool localisation() const { return mode == "localisation"; }
  /// ~reload_stored: every stored session is reloaded at start-up and its keyframes handed to the
  /// loop detectors (each gets them when it subscribes), so that new sessions find global loops to
  /// the stored maps and relocalise in them from their first keyframe. Off: reload_session by hand.
  bool reload_stored = false;
  ros_frames::FrameOptions frames;  // frames/* and the tf switches and rates
  int queue_size = core::SessionWorkerOptions().queue_size;
  int max_waiting_loops = core::SessionWorkerOptions().max_waiting_loops;
  /// The most lost keyframes a gap in a session's ids may bridge: the core's bound, small because
  /// each placeholder is a stored row (doc/robustness.md, "What one message costs").
  int max_keyframe_gap = core::SessionManagerOptions().max_keyframe_gap;
  int worker_nice = core::SessionWorkerOptions().nice;  // 0..19: above 0 the odometry's frames come first
  /// start_session refused while this many sessions in a row have no keyframe. The core's default
  /// is no limit (offline nothing calls start_session in a loop); a live service caller may.
  int max_empty_sessions = 1;
  double stats_period_s = 30.0, diagnostic_period_s = 1.0;
  /// The live mosaic (core/export/live_mosaic.h): redrawn at most at mosaic_rate_hz when the
  /// active map changed (0: off), at mosaic_resolution_m, coarser when wider than mosaic_max_side_px.
  double mosaic_rate_hz = 0.2;
  core::LiveMosaicOptions mosaic;
  /// The `export` service writes below this folder (created at start-up; "" = no exports).
  std::string export_root = defaultExportRoot();
  /// Hash exchange between vehicles: ~fleet/vehicle names this vehicle (""
  /// = off); ~fleet/peers maps each other vehicle's name to its keyframe_features service (how
  /// this back-end asks for a candidate's features).
  std::string fleet_vehicle;
  std::map<std::string, std::string> fleet_peers;
  bool fleet_hash_codes = true;  // ~fleet/hash_codes: hashes as 8-bit codes (same search, 1/4 the bytes)
  /// ~fleet/peer_timeout_s: how long a request for another vehicle's keyframe features is waited
  /// for (UNAVAILABLE after it, counted); that vehicle is then not asked again for as long.
  double fleet_peer_timeout_s = 30.0;
  /// The NavSatFix input (ros/fix_input.h): ~fix/topic, its fixes used as absolute position priors
  /// ("" = off), and how they are matched to keyframes (~fix/max_dt_s, ~fix/default_sigma_m, ~fix/max_waiting).
  std::string fix_topic = topics::kFix;
  core::FixOptions fix;
};

/// The datum's frames against the others (backendNodeletOptions): ~datum/earth_frame must differ from map, odom and
/// base; a non-empty ~datum/utm_frame needs the datum, must differ from those and earth, and the datum must lie in
/// UTM's latitudes (core::utmFromMap). `datum_key`: the resolved ~datum. Throws std::invalid_argument
/// "<datum_key>/earth_frame: ..." or "<datum_key>/utm_frame: ...".
void checkDatumFrames(const ros_frames::FrameOptions& frames, const std::string& datum_key);

/// Reads and validates the back-end nodelet's parameters (std::invalid_argument naming the key):
/// `nh` the pipeline's namespace, `pnh` the node's private one.
BackendNodeletOptions backendNodeletOptions(const Params& nh, const Params& pnh);
/// The same from the parameter server; first warns about an old config file's block
/// (warnAboutFormerPrivateNamespace).
BackendNodeletOptions backendNodeletOptions(const ros::NodeHandle& nh, const ros::NodeHandle& pnh);

/// The session manager's options for the back-end nodelet: the SLAM configuration's, the store
/// path and the nodelet's limits (max_keyframe_gap, max_empty_sessions).
core::SessionManagerOptions sessionManagerOptions(const BackendNodeletOptions& o, const core::SlamConfig& config);
/// The back-end's session worker around its manager (the store opened and restored, ~mode
/// localisation applied): events and INFO lines to `events` and `say`, the worker's warnings and
/// errors to rosconsole (throttled). Throws as SessionManager's constructor.
std::unique_ptr<core::SessionWorker> makeSessionWorker(const BackendNodeletOptions& o, const core::SlamConfig& config,
                                                       core::SessionManager::EventSink events,
                                                       std::function<void(const std::string&)> say);
/// The back-end's start-up lines: optimiser, joins, tf, queue and store; live mosaic and exports.
std::vector<std::string> describeBackend(const BackendNodeletOptions& o, const core::SlamConfig& config);
/// The session worker's options for the back-end nodelet: its queue and waiting-loop limits, and
/// paging of stored sessions (loops.page_stored).
core::SessionWorkerOptions sessionWorkerOptions(const BackendNodeletOptions& o, const core::SlamConfig& config);

/// The loop-detector nodelet's own parameters (~ private; config/default.yaml documents each).
struct LoopDetectorNodeletOptions {
  std::string mode = "both";  // both, local (same-session loops) or global (other sessions, hashes)
  int queue_size = 100;       // keyframes waiting for the worker (oldest dropped when full)
  /// The most lost keyframes a gap in the ids may bridge. Larger than the back-end's: here a
  /// placeholder is < 100 B of RAM, never stored, and a longer bridge keeps loops for the piece after it.
  int max_keyframe_gap = 1000;
  double stats_period_s = 30.0;
  double diagnostic_period_s = 1.0;
  int worker_nice = 0;  // the worker thread's nice value (0..19: above 0 the odometry's frames come first)
  bool publishHashes() const { return mode != "local"; }
};

/// Reads and validates the loop-detector nodelet's parameters (std::invalid_argument naming the key).
LoopDetectorNodeletOptions loopDetectorNodeletOptions(const Params& pnh);
/// The same from the parameter server; first warns about an old config file's block
/// (warnAboutFormerPrivateNamespace).
LoopDetectorNodeletOptions loopDetectorNodeletOptions(const ros::NodeHandle& pnh);

/// The SLAM configuration at `nh`/slam, validated, with the loop kinds ~mode leaves out switched off
/// (loops.local/global.enabled still apply on top of the mode). std::invalid_argument naming the key.
core::SlamConfig loopDetectorConfig(const Params& nh, const LoopDetectorNodeletOptions& o);
core::SlamConfig loopDetectorConfig(const ros::NodeHandle& nh, const LoopDetectorNodeletOptions& o);

/// The loop detector's start-up line: its effective options.
std::string describe(const LoopDetectorNodeletOptions& o, const core::SlamConfig& config);

/// The private namespace a node had before the nodes were named after their executables
/// (launch/slam.launch): `private_ns` with its last name odometry_node, loop_detector_node,
/// local_loops_node, global_loops_node or backend_node turned back into odometry, loop_detector,
/// local_loops, global_loops or backend ("/uw_multislam/odometry_node" -> "/uw_multislam/odometry");
/// "" for any other name.
std::string formerPrivateNamespace(const std::string& private_ns);

/// For an old config file: when the parameter server holds parameters under the node's former
/// private namespace (formerPrivateNamespace of `pnh`'s namespace), logs one WARN naming both
/// namespaces (those parameters are not read any more) and returns true; else false. Every
/// nodelet calls it once while reading its parameters.
bool warnAboutFormerPrivateNamespace(const ros::NodeHandle& pnh);

/// The shared frames/ names of the nodelets' namespace `nh` into `frames` (map_frame, odom_frame,
/// base_frame, session_frame_prefix: non-empty; map, odom and base must differ) and the sensors'
/// mount options (ros_frames::mountOptions). std::invalid_argument naming the key.
void readFrames(const Params& nh, ros_frames::FrameOptions* frames);

}  // namespace ros_params
}  // namespace uw_multislam
