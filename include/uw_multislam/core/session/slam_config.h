// The SLAM configuration shared by offline_slam and the nodelets: one YAML layout with a block
// per component (config/slam.yaml documents every key). Unknown keys are errors.
#pragma once

#include <string>

#include "uw_multislam/core/backend/backend.h"
#include "uw_multislam/core/frontend/odometry.h"
#include "uw_multislam/core/frontend/tracking.h"
#include "uw_multislam/core/loops/loop_detector.h"
#include "uw_multislam/core/store/keyframe_image.h"

namespace uw_multislam {
namespace core {

struct SlamConfig {
  OdometryOptions odometry;
  TrackingLossOptions tracking;
  LoopOptions loops;
  BackendOptions backend;
  KeyframeImageOptions store_image;  // YAML block `store`: the keyframe image the store keeps

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
