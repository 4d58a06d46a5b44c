// The offline runner: the SLAM core over dataset folders (or bags, read by the ROS side: offline_slam --bag)
// without a ROS master (offline_slam's work; its main only parses the command line). Its contract:
// offline_slam --help and doc/run_outputs.md.
#pragma once

#include <opencv2/core.hpp>

#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/loops/loop_detector.h"
#include "uw_multislam/core/session/slam_config.h"
#include "uw_multislam/core/store/interrupted_run.h"

namespace uw_multislam::tools {

/// Exit status when a folder is already in the store: finished (pass --again) or interrupted (--interrupted).
constexpr int kInStore = 3;

/// An operator's link (--add-link, the back-end's add_link): keyframe_a of session_a to keyframe_b of session_b.
struct OperatorLink {
  core::Loop loop;        // sessions and keyframes; z and its covariance when measured
  bool measured = false;  // z given; else found by RANSAC between the two stored keyframes
  double yaw = 0.0;       // z's yaw as given (rad), before Pose2 wrapped it: checked to be in [-pi, pi]
};

/// --add-link A:KA:B:KB[:X:Y:YAW:SXY:SYAW] -> a link (sessions, keyframes; z when measured). false:
/// not that shape, or a number that is not one (sigmas must be >= 1e-6).
bool parseOperatorLink(const std::string& spec, OperatorLink* link);

/// One camera stream the runner processes: a dataset folder, or a bag the ROS side read (ros/bag_input.h).
struct StreamInput {
  core::Dataset dataset;  // frames, camera, nav; `directory`: the folder or the bag, the stream's name
  /// The image of frame i (its position in dataset.frames), thread-safe; empty: the folder's image files.
  std::function<cv::Mat(std::size_t i, std::string* why)> image;
  double recorded_s = 0.0;  // a bag's recording length (the real-time ratio); 0 for a folder
  std::string summary;      // a bag's one line: what was read
};
/// Opens a bag as a stream (the configuration: the odometry's altitude bound); throws std::exception.
using OpenBag = std::function<StreamInput(const std::string& path, const core::SlamConfig& config)>;

/// offline_slam's command line, each value checked and every combination allowed (offline_slam.cpp).
struct OfflineOptions {
  std::vector<std::string> folders;                    // --session: dataset folders, in order: consecutive missions
  std::vector<std::string> bags;                       // --bag: bags, in order, one stream each (not with folders)
  OpenBag open_bag;                                    // reads a bag (offline_slam's main: the ROS side)
  std::string out;                                     // --out: the output directory (created); unused with dump_config
  std::string config_file;                             // --config; empty: the defaults
  std::string db;                                      // --db: the session store; empty: none
  std::optional<bool> nav;                             // --nav on|off; unset: the configuration's odometry.nav.enabled
  std::optional<core::InterruptedChoice> interrupted;  // --interrupted; unset: an interrupted run is refused
  std::vector<OperatorLink> links;                     // --add-link, applied in this order
  int threads = 1;                                     // --threads: 1, or workers preparing the next frames
  long finish_after = 0;                               // --finish-after: frames per folder; 0: every frame
  bool dump_config = false;                            // print the effective configuration, nothing else
  bool quiet = false, again = false, detect_loops = false, localise_only = false;
};

/// Runs offline_slam as `options` say: the outputs into options.out, progress on stdout, problems on stderr
/// in one line each. Returns the exit status: 0, 1 (bad input, a link refused, a store write failed), or
/// kInStore.
int runOffline(const OfflineOptions& options);

}  // namespace uw_multislam::tools
