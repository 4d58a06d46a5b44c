#include "uw_multislam/ros/sensor_conversions.h"

#include <cv_bridge/cv_bridge.h>
#include <sensor_msgs/image_encodings.h>

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <sstream>

namespace uw_multislam {
namespace ros_conversions {

namespace {
bool fail(std::string* why, const std::string& reason) {
  if (why) *why = reason;
  return false;
}
}  // namespace

bool imageFromMsg(const sensor_msgs::ImageConstPtr& msg, cv::Mat* out, std::string* why) {
  namespace enc = sensor_msgs::image_encodings;
  if (!msg) return fail(why, "no image");
  if (msg->width == 0 || msg->height == 0) return fail(why, "empty image (0 x 0)");
  const std::string& e = msg->encoding;
  const bool grey = e == enc::MONO8 || e == enc::MONO16 || e == enc::TYPE_8UC1;
  const bool colour = e == enc::BGR8 || e == enc::RGB8 || e == enc::BGRA8 || e == enc::RGBA8 || e == enc::TYPE_8UC3;
  if (!grey && !colour) {
    return fail(why, "unsupported encoding '" + e + "' (mono8, mono16, bgr8, rgb8, bgra8, rgba8 are)");
  }
  // cv_bridge views the data through step without checking its length: checked here.
  const std::size_t pixel_bytes = static_cast<std::size_t>(enc::numChannels(e)) * (enc::bitDepth(e) / 8);
  if (static_cast<std::size_t>(msg->step) < msg->width * pixel_bytes ||
      static_cast<std::size_t>(msg->step) * msg->height > msg->data.size()) {
    std::ostringstream os;
    os << "image data (" << msg->data.size() << " bytes, step " << msg->step << ") does not fit " << msg->width << "x"
       << msg->height << " " << e;
    return fail(why, os.str());
  }
  try {
    if (e == enc::MONO8 || e == enc::BGR8 || e == enc::TYPE_8UC1 || e == enc::TYPE_8UC3) {
      *out = cv_bridge::toCvShare(msg)->image;  // no copy: shares the message's buffer
    } else if (grey) {
      *out = cv_bridge::toCvCopy(msg, enc::MONO8)->image;
    } else {
      *out = cv_bridge::toCvCopy(msg, enc::BGR8)->image;
    }
  } catch (const std::exception& ex) {
    return fail(why, std::string("cannot convert the image: ") + ex.what());
  }
  if (out->empty()) return fail(why, "empty image after conversion");
  return true;
}

bool cameraFromMsg(const sensor_msgs::CameraInfo& msg, core::CameraIntrinsics* out, bool* distorted,
                   std::string* why) {
  core::CameraIntrinsics c;
  c.width = static_cast<int>(msg.width);
  c.height = static_cast<int>(msg.height);
  c.fx = msg.K[0];
  c.fy = msg.K[4];
  c.cx = msg.K[2];
  c.cy = msg.K[5];
  const std::string bad = c.validate();
  if (!bad.empty()) return fail(why, "camera_info: " + bad);
  if (c.cx < 0 || c.cx > c.width || c.cy < 0 || c.cy > c.height) {
    std::ostringstream os;
    os << "camera_info: principal point (" << c.cx << ", " << c.cy << ") outside the " << c.width << "x" << c.height
       << " image";
    return fail(why, os.str());
  }
  if (distorted) *distorted = std::any_of(msg.D.begin(), msg.D.end(), [](double d) { return d != 0.0; });
  *out = c;
  return true;
}

bool altitudeFromMsg(const sensor_msgs::Range& msg, double* altitude_m, std::string* why) {
  const double r = msg.range;
  if (!std::isfinite(r) || r <= 0) {
    std::ostringstream os;
    os << "altitude " << r << " is not a positive number";
    return fail(why, os.str());
  }
  if ((msg.min_range > 0 && r < msg.min_range) || (msg.max_range > 0 && r > msg.max_range)) {
    std::ostringstream os;
    os << "altitude " << r << " outside the sensor's range [" << msg.min_range << ", " << msg.max_range << "]";
    return fail(why, os.str());
  }
  *altitude_m = r;
  return true;
}

}  // namespace ros_conversions
}  // namespace uw_multislam
