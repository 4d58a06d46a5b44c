// The odometry's image input: image_transport with ~image_transport's plugin (raw by default), or,
// for `compressed` without its plugin (Debian ships none), sensor_msgs/CompressedImage on
// <image>/compressed, decoded later by the worker with OpenCV (imageFromInput). Which of the two
// is used is decided once at construction and logged; another transport without its plugin is
// refused (std::invalid_argument naming ~image_transport).
#pragma once

#include <image_transport/image_transport.h>
#include <ros/ros.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>

#include <opencv2/core.hpp>

#include <cstdint>
#include <functional>
#include <string>

#include "uw_multislam/ros/sensor_conversions.h"

namespace uw_multislam {
namespace ros_inputs {

/// An image as it came: raw, or compressed for the built-in decoder.
struct ImageMsg {
  sensor_msgs::ImageConstPtr image;
  sensor_msgs::CompressedImageConstPtr compressed;  // instead of image
  const std_msgs::Header& header() const { return image ? image->header : compressed->header; }
};

/// The image as the core takes it, a compressed one decoded first (ros_conversions::imageFromMsg
/// and imageFromCompressedMsg: false with the reason and the kind of refusal), and of the size of
/// `camera` (else kSizeMismatch). Never throws.
bool imageFromInput(const ImageMsg& m, const core::CameraIntrinsics& camera, std::uint64_t max_pixels, cv::Mat* out,
                    std::string* why, ros_conversions::ImageRefusal* refusal);

class ImageInput {
 public:
  /// Decides the transport from `pnh`'s ~image_transport for the image topic `topic` of `nh`.
  ImageInput(ros::NodeHandle nh, ros::NodeHandle pnh, image_transport::ImageTransport* it, const std::string& topic);
  /// Subscribes; `callback` gets every image (the callbacks' threads).
  void subscribe(int queue_size, std::function<void(ImageMsg)> callback);
  void shutdown();
  const std::string& topic() const { return topic_; }  // resolved, with /compressed for that transport
  const std::string& transport() const { return transport_; }
  /// The start-up line: which transport, and how.
  const std::string& description() const { return description_; }

 private:
  ros::NodeHandle nh_, pnh_;
  image_transport::ImageTransport* it_;
  std::string base_topic_, topic_, transport_, description_;
  bool builtin_decoder_ = false;
  image_transport::Subscriber image_sub_;
  ros::Subscriber compressed_sub_;
};

}  // namespace ros_inputs
}  // namespace uw_multislam
