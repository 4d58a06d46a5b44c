// The cameras that several core tests build alike, written once so that the tests cannot drift
// apart where they mean the same camera. ROS-free and gtest-free.
#pragma once

#include "uw_multislam/core/frontend/dataset.h"

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

}  // namespace testing_util
}  // namespace uw_multislam
