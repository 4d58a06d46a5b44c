// Conversions between the core's keyframes, loops and hashes and the pipeline's messages
// (uw_multislam/Keyframe, Loop, KeyframeHash). One place for them; every function has
// a test in test/ros/test_pipeline_conversions.cpp.
//
// Messages from the wire are checked: fromMsg returns false with a one-line reason (never
// throws) for inconsistent array sizes, non-finite numbers, a bad camera or covariance, so that a
// nodelet can count and skip a bad message.
#pragma once

#include <std_msgs/Header.h>

#include <Eigen/Core>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "uw_multislam/Keyframe.h"
#include "uw_multislam/KeyframeHash.h"
#include "uw_multislam/Loop.h"
#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/frontend/features.h"
#include "uw_multislam/core/frontend/odometry.h"
#include "uw_multislam/core/geometry/uncertain_pose.h"
#include "uw_multislam/core/loops/haloc.h"
#include "uw_multislam/core/loops/loop_detector.h"
#include "uw_multislam/core/session/frame_stream.h"
#include "uw_multislam/core/session/session_queries.h"

namespace uw_multislam {
namespace ros_conversions {

/// How the keyframe's motion from the previous keyframe was obtained (Keyframe.status).
enum class KeyframeQuality { kFirst, kMatched, kFallback };

/// Everything a Keyframe message carries, in core types.
struct KeyframeData {
  int session = 0;
  int keyframe = 0;
  int frame_index = 0;
  double altitude_m = 0.0;
  core::CameraIntrinsics camera;
  /// Keypoints (position and response only travel) and descriptors as the extractor gives them
  /// (SIFT: CV_32F, from the 8-bit message's values; ORB: 32 bytes CV_8U; core::extractorDescriptors).
  core::FrameFeatures features;
  /// The keyframe's hash (core::HalocProjections::kHashSize values), or empty when not computed
  /// (messages from older senders): receivers hash the features themselves then.
  Eigen::VectorXf hash;
  /// The keyframe's image as a small JPEG (the store's thumbnail; the live mosaic), may be empty.
  std::vector<std::uint8_t> thumbnail;
  core::UncertainPose2 motion;  // X_k^{k-1}; exact identity for keyframe 0
  core::Pose2 odometry_pose;    // X_k^0 of the odometry
  KeyframeQuality quality = KeyframeQuality::kFirst;
  int matches = 0;
  int inliers = 0;
  double overlap = 0.0;
  double scale = 1.0;
  /// Keyframe 0 of a piece the nav places (Keyframe.msg placement_*), else none.
  std::optional<core::NavPlacementInput> nav_placement = std::nullopt;
};

/// A keyframe the front end released (core::FrameStream), as loop detection and the back-end need it:
/// its features, camera, altitude, motion, pose, hash and placement, and how its motion was measured
/// (a promoted keyframe's own match, from when it was tracked).
KeyframeData keyframeData(const core::StreamKeyframe& k);

/// Descriptors are rounded and saturated to 8 bits (SIFT's values are integers in 0..255).
uw_multislam::Keyframe toKeyframeMsg(const KeyframeData& k, const std_msgs::Header& header);
/// unload_session's notice on reloaded_keyframes (in order with the keyframes reload_session sent
/// there): keyframe -1, no features, `session`: the loop detectors forget that session.
uw_multislam::Keyframe unloadSessionMsg(int session);
bool isUnloadSessionMsg(const uw_multislam::Keyframe& msg);
bool fromMsg(const uw_multislam::Keyframe& m, KeyframeData* out, std::string* why = nullptr);

uw_multislam::Loop toLoopMsg(const core::Loop& loop, const std_msgs::Header& header);
bool fromMsg(const uw_multislam::Loop& m, core::Loop* out, std::string* why = nullptr);

/// A keyframe's hash; values must have core::HalocProjections::kHashSize entries (a message may
/// carry them as 8-bit codes instead: fromMsg turns them back into values).
struct KeyframeHashData {
  int session = 0;
  int keyframe = 0;
  int frame_index = 0;
  core::HashMode mode = core::HashMode::kSortedDct;
  std::uint64_t projection_seed = 0;
  int num_features = 0;
  core::FeatureType features = core::FeatureType::kSift;  // of the descriptors hashed
  Eigen::VectorXf values;
};
uw_multislam::KeyframeHash toKeyframeHashMsg(const KeyframeHashData& h, const std_msgs::Header& header);
bool fromMsg(const uw_multislam::KeyframeHash& m, KeyframeHashData* out, std::string* why = nullptr);

/// Hash exchange between vehicles: keyframe `k` (its hash, motion, pose,
/// camera and altitude; no features, no image) as vehicle `vehicle` sends it on fleet/hashes_out,
/// with the hash settings it was made with; `codes`: the hash as the loop detector's 8-bit codes
/// (384 bytes instead of 1536, the same search) instead of values.
/// `k` by value: a caller done with it moves it in, and its features and image are not copied only
/// to be dropped.
uw_multislam::KeyframeHash toFleetHashMsg(KeyframeData k, const std::string& vehicle, core::HashMode mode,
                                          std::uint64_t projection_seed, int num_features, core::FeatureType features,
                                          const std_msgs::Header& header, bool codes = false);
/// The notice that `vehicle`'s session `session` has ended (session_ended, keyframe -1, no values).
uw_multislam::KeyframeHash fleetSessionEndedMsg(const std::string& vehicle, int session, const ros::Time& stamp);
/// A fleet hash as a keyframe without features (checked as fromMsg(Keyframe) checks one), and
/// its hash settings in `settings`. A notice (session_ended) is refused here: callers test it first.
bool fromFleetHashMsg(const uw_multislam::KeyframeHash& m, KeyframeData* out, KeyframeHashData* settings,
                      std::string* why = nullptr);

/// 3x3 covariance <-> row-major float64[9].
void toArray(const Eigen::Matrix3d& c, boost::array<double, 9>* out);
Eigen::Matrix3d fromArray(const boost::array<double, 9>& a);

}  // namespace ros_conversions
}  // namespace uw_multislam
