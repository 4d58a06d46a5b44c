#include "uw_multislam/ros/image_input.h"

#include <stdexcept>
#include <vector>

namespace uw_multislam {
namespace ros_inputs {

namespace rc = ros_conversions;

bool imageFromInput(const ImageMsg& m, const core::CameraIntrinsics& camera, std::uint64_t max_pixels, cv::Mat* out,
                    std::string* why, rc::ImageRefusal* refusal) {
  sensor_msgs::ImagePtr decoded;
  if (m.compressed && !rc::imageFromCompressedMsg(*m.compressed, &decoded, why, refusal, max_pixels)) return false;
  if (!rc::imageFromMsg(m.compressed ? decoded : m.image, out, why, refusal, max_pixels)) return false;
  // imageFromMsg shares an 8-bit image's buffer without owning it (u null): the decoded message ends here.
  if (m.compressed && out->u == nullptr) *out = out->clone();
  if (out->cols == camera.width && out->rows == camera.height) return true;
  if (why)
    *why = "image " + std::to_string(out->cols) + "x" + std::to_string(out->rows) + " but camera_info says " +
           std::to_string(camera.width) + "x" + std::to_string(camera.height);
  if (refusal) *refusal = rc::ImageRefusal::kSizeMismatch;
  return false;
}

ImageInput::ImageInput(ros::NodeHandle nh, ros::NodeHandle pnh, image_transport::ImageTransport* it,
                       const std::string& topic)
    : nh_(nh), pnh_(pnh), it_(it), base_topic_(topic) {
  // ~image_transport, as image_transport itself reads it (default raw).
  transport_ = image_transport::TransportHints("raw", ros::TransportHints(), pnh_).getTransport();
  // Plugins that load, as "<package>/<transport>" (image_transport/raw, image_transport/compressed, ...).
  std::string names;
  bool installed = false;
  for (const std::string& l : it_->getLoadableTransports()) {
    const std::string name = l.substr(l.rfind('/') + 1);
    installed = installed || name == transport_;
    names += (names.empty() ? "" : ", ") + name;
  }
  const std::string base = nh_.resolveName(topic);
  topic_ = transport_ == "raw" ? base : base + "/" + transport_;
  builtin_decoder_ = transport_ == "compressed" && !installed;
  if (builtin_decoder_) {
    description_ = "image transport 'compressed' on " + topic_ +
                   " (sensor_msgs/CompressedImage, jpeg or png): the built-in OpenCV decoder, as image_transport "
                   "has no compressed plugin (loadable: " +
                   names + ")";
  } else if (installed) {
    description_ = "image transport '" + transport_ + "' on " + topic_ + ": image_transport's plugin";
  } else {
    throw std::invalid_argument(pnh_.resolveName("image_transport") + " = '" + transport_ +
                                "': no image_transport plugin for it is installed (loadable: " + names +
                                "; 'compressed' also works without its plugin)");
  }
}

void ImageInput::subscribe(int queue_size, std::function<void(ImageMsg)> callback) {
  if (builtin_decoder_) {
    // Decoded by the worker, so a corrupt one is counted like any bad image.
    compressed_sub_ = nh_.subscribe<sensor_msgs::CompressedImage>(
        topic_, queue_size, [callback](const sensor_msgs::CompressedImageConstPtr& m) {
          callback({nullptr, m});
        });
  } else {
    const image_transport::TransportHints hints("raw", ros::TransportHints(), pnh_);
    image_sub_ = it_->subscribe(
        base_topic_, queue_size,
        [callback](const sensor_msgs::ImageConstPtr& m) {
          callback({m, nullptr});
        },
        ros::VoidPtr(), hints);
  }
}

void ImageInput::shutdown() {
  image_sub_.shutdown();
  compressed_sub_.shutdown();
}

}  // namespace ros_inputs
}  // namespace uw_multislam
