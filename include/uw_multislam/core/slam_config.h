// The SLAM configuration shared by offline_slam and the nodelets: one YAML layout with a block
// per component (config/slam.yaml documents every key). Unknown keys are errors.
#pragma once

#include <string>

#include "uw_multislam/core/iekf.h"
#include "uw_multislam/core/loop_detector.h"
#include "uw_multislam/core/odometry.h"

namespace uw_multislam {
namespace core {

/// Back-end settings. The intra-map IEKF keeps a dense covariance (3N x 3N): it is switched off
/// for a session that grows past max_keyframes, whose trajectory is then the odometry's.
struct BackendOptions {
  bool intra_map_iekf = true;
  IekfOptions iekf;
  int max_keyframes = 1500;

  std::string validate() const;
};

struct SlamConfig {
  OdometryOptions odometry;
  LoopOptions loops;
  BackendOptions backend;

  /// Empty when usable, else "<component>: <reason>".
  std::string validate() const;
};

/// Parses YAML text; missing keys keep their defaults. Throws std::invalid_argument naming the
/// key at fault.
SlamConfig slamConfigFromYaml(const std::string& yaml_text);
/// Reads a file (DatasetError when unreadable, std::invalid_argument when bad, with the path).
SlamConfig loadSlamConfig(const std::string& path);
/// Every key with its value; slamConfigFromYaml(slamConfigToYaml(c)) == c.
std::string slamConfigToYaml(const SlamConfig& config);

}  // namespace core
}  // namespace uw_multislam
