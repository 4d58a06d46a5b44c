// The odometry's output of new keyframes: each as a uw_multislam/Keyframe with its features, its
// hash (paper (6)(7), computed once by the front end, core::FrameStream; the loop detectors and the
// back-end reuse it) and the store's thumbnail, and, only while someone subscribes, its
// image with the features drawn (odometry/keyframe_image). Messages are published as shared
// pointers, so nodelets in the same manager receive them without a copy. The odometry's worker only.
#pragma once

#include <image_transport/image_transport.h>
#include <ros/ros.h>
#include <std_msgs/Header.h>

#include <opencv2/core.hpp>

#include <vector>

#include "uw_multislam/core/session/frame_stream.h"
#include "uw_multislam/core/session/slam_config.h"
#include "uw_multislam/core/store/keyframe_image.h"

namespace uw_multislam {
namespace ros_outputs {

class KeyframePublisher {
 public:
  KeyframePublisher(ros::NodeHandle nh, image_transport::ImageTransport* it, const core::SlamConfig& config);
  /// The keyframes a frame released (core::FrameResult::keyframes); `frame_index`, `image` and `header` are the
  /// frame's. Returns how many were published.
  int publish(const std::vector<core::StreamKeyframe>& keyframes, int frame_index, const cv::Mat& image,
              const std_msgs::Header& header);

 private:
  core::KeyframeImageOptions store_image_;
  ros::Publisher keyframe_pub_;
  image_transport::Publisher image_pub_;
};

}  // namespace ros_outputs
}  // namespace uw_multislam
