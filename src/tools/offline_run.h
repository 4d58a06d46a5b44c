// The offline runner: the SLAM core over dataset folders without a ROS master (offline_slam's work; its
// main only parses the command line). Its contract: offline_slam --help and doc/run_outputs.md.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "uw_multislam/core/loops/loop_detector.h"
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

/// offline_slam's command line, each value checked and every combination allowed (offline_slam.cpp).
struct OfflineOptions {
  std::vector<std::string> folders;                    // --session: dataset folders, in order: consecutive missions
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
