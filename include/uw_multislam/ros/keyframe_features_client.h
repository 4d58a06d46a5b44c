// The loop detector's client of the back-end's keyframe_features service: a paged keyframe's
// features when it is a loop candidate, and whether the back-end's store holds a live keyframe yet
// (check_only, before the keyframe is paged out). A persistent connection (one per call
// otherwise), made again after a failure (the back-end respawned). The worker's thread only.
#pragma once

#include <ros/ros.h>

#include <cstdint>
#include <string>

#include "uw_multislam/KeyframeFeatures.h"
#include "uw_multislam/core/frontend/features.h"

namespace uw_multislam {
namespace ros_inputs {

class KeyframeFeaturesClient {
 public:
  explicit KeyframeFeaturesClient(ros::NodeHandle nh) : nh_(nh) {}
  /// The features of a keyframe in the store; std::runtime_error with the reason when the call
  /// fails, is refused or answers an unreadable keyframe (the candidate is then skipped, counted).
  core::FrameFeatures load(int session, int keyframe);
  /// check_only: false when the back-end does not answer; else `code` (uw_multislam/Status) and
  /// `message` are its answer (OK: the store has it).
  bool check(int session, int keyframe, std::uint8_t* code, std::string* message);

 private:
  bool call(uw_multislam::KeyframeFeatures* srv);
  ros::NodeHandle nh_;
  ros::ServiceClient client_;
};

}  // namespace ros_inputs
}  // namespace uw_multislam
