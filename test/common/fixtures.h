// The cameras and keyframe inputs that several core tests build alike, written once so that the
// tests cannot drift apart where they mean the same camera or keyframe. ROS-free and gtest-free.
#pragma once

#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/session/session_queries.h"

namespace uw_multislam {
namespace testing_util {

/// A camera without distortion, square pixels (fx = fy = f).
inline core::CameraIntrinsics pinholeCamera(int width, int height, double f, double cx, double cy) {
  core::CameraIntrinsics c;
  c.width = width;
  c.height = height;
  c.fx = c.fy = f;
  c.cx = cx;
  c.cy = cy;
  return c;
}

/// 320 x 240, f = 300 px: at 2 m, a footprint of 2.13 m x 1.6 m.
inline core::CameraIntrinsics camera320() { return pinholeCamera(320, 240, 300.0, 160.0, 120.0); }

/// 640 x 480, f = 500 px: the back-end tests' keyframes.
inline core::CameraIntrinsics camera640() { return pinholeCamera(640, 480, 500.0, 320.0, 240.0); }

/// Keyframe k of `session` at `odometry_pose`, moved by `motion` from keyframe k - 1: frame 10 k,
/// stamped 100 session + k s, 2 m above the seabed, camera640(), no features.
inline core::KeyframeInput keyframeInput(int session, int k, const core::Pose2& odometry_pose,
                                         const core::UncertainPose2& motion) {
  core::KeyframeInput in;
  in.session = session;
  in.keyframe = k;
  in.frame_index = 10 * k;
  in.stamp_s = 100.0 * session + k;
  in.altitude_m = 2.0;
  in.camera = camera640();
  in.motion = motion;
  in.odometry_pose = odometry_pose;
  return in;
}

}  // namespace testing_util
}  // namespace uw_multislam
