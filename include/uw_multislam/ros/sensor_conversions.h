// The odometry nodelet's inputs in core types: sensor_msgs/Image -> cv::Mat (8-bit grey or BGR,
// what core::Odometry takes), CameraInfo -> core::CameraIntrinsics, Range -> altitude. Each
// returns false with a one-line reason for input the core cannot use (the nodelet counts and
// skips it); none throws. Tested in test/ros/test_sensor_conversions.cpp.
#pragma once

#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/Range.h>

#include <opencv2/core.hpp>
#include <string>

#include "uw_multislam/core/dataset.h"

namespace uw_multislam {
namespace ros_conversions {

/// mono8 and bgr8 are shared without a copy (the Mat keeps the message alive); rgb8, bgra8 and
/// rgba8 are converted to bgr8, mono16 scaled to mono8. Anything else (Bayer, float, YUV),
/// an empty image or a step / data size mismatch is refused.
bool imageFromMsg(const sensor_msgs::ImageConstPtr& msg, cv::Mat* out, std::string* why = nullptr);

/// The pinhole intrinsics of K. Refuses a zero or non-finite focal length, a zero image size or
/// a principal point outside the image. `distorted` (optional) tells whether D has a non-zero
/// coefficient (the core assumes rectified images: the nodelet warns once).
bool cameraFromMsg(const sensor_msgs::CameraInfo& msg, core::CameraIntrinsics* out, bool* distorted = nullptr,
                   std::string* why = nullptr);

/// The range as altitude; refuses non-finite or non-positive values and ones outside
/// [min_range, max_range] (sensor_msgs/Range: such readings must be discarded).
bool altitudeFromMsg(const sensor_msgs::Range& msg, double* altitude_m, std::string* why = nullptr);

}  // namespace ros_conversions
}  // namespace uw_multislam
