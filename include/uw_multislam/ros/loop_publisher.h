// The loop detector's outputs: loops (uw_multislam/Loop) and, in modes global and both, each
// searched keyframe's hash (uw_multislam/KeyframeHash, with the settings it was made with), as
// shared pointers (no copy to nodelets in the same manager). The loop detector's worker only.
#pragma once

#include <ros/ros.h>
#include <std_msgs/Header.h>

#include <Eigen/Core>

#include <vector>

#include "uw_multislam/core/loops/loop_detector.h"
#include "uw_multislam/core/session/slam_config.h"
#include "uw_multislam/ros/pipeline_conversions.h"

namespace uw_multislam {
namespace ros_outputs {

class LoopPublisher {
 public:
  LoopPublisher(ros::NodeHandle nh, bool hashes, const core::SlamConfig& config);
  /// Publishes `loops`; adds how many are local and global to the counts.
  void publish(const std::vector<core::Loop>& loops, const std_msgs::Header& header, long* local, long* global);
  /// Publishes keyframe `k`'s hash `values` (nothing without hashes); true when published.
  bool publishHash(const ros_conversions::KeyframeData& k, const Eigen::VectorXf& values,
                   const std_msgs::Header& header);

 private:
  core::SlamConfig config_;
  ros::Publisher loop_pub_, hash_pub_;
};

}  // namespace ros_outputs
}  // namespace uw_multislam
