#include "uw_multislam/ros/sensor_conversions.h"

#include <camera_calibration_parsers/parse.h>
#include <cv_bridge/cv_bridge.h>
#include <image_geometry/pinhole_camera_model.h>
#include <ros/package.h>
#include <sensor_msgs/distortion_models.h>
#include <sensor_msgs/image_encodings.h>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <limits>
#include <sstream>

#include "uw_multislam/ros/conversions.h"

namespace uw_multislam {
namespace ros_conversions {

namespace {
bool fail(std::string* why, const std::string& reason) {
  if (why) *why = reason;
  return false;
}
}  // namespace

std::string imageRefusalName(ImageRefusal r) {
  switch (r) {
    case ImageRefusal::kNone:
      return "none";
    case ImageRefusal::kEmpty:
      return "empty";
    case ImageRefusal::kEncoding:
      return "encoding";
    case ImageRefusal::kLayout:
      return "layout";
    case ImageRefusal::kTooSmall:
      return "too_small";
    case ImageRefusal::kCorrupt:
      return "corrupt";
    case ImageRefusal::kTooLarge:
      return "too_large";
    case ImageRefusal::kSizeMismatch:
      return "size_mismatch";
  }
  return "?";
}

namespace {

/// OpenCV's debayering code for a ROS Bayer encoding (OpenCV names the pattern by the second
/// row's first two pixels, as cv_bridge does), or -1.
int bayerCode(const std::string& e) {
  namespace enc = sensor_msgs::image_encodings;
  if (e == enc::BAYER_RGGB8 || e == enc::BAYER_RGGB16) return cv::COLOR_BayerBG2BGR;
  if (e == enc::BAYER_BGGR8 || e == enc::BAYER_BGGR16) return cv::COLOR_BayerRG2BGR;
  if (e == enc::BAYER_GBRG8 || e == enc::BAYER_GBRG16) return cv::COLOR_BayerGR2BGR;
  if (e == enc::BAYER_GRBG8 || e == enc::BAYER_GRBG16) return cv::COLOR_BayerGB2BGR;
  return -1;
}

bool refuse(std::string* why, ImageRefusal* refusal, ImageRefusal kind, const std::string& reason) {
  if (refusal) *refusal = kind;
  return fail(why, reason);
}

bool refuseTooLarge(std::string* why, ImageRefusal* refusal, std::uint64_t width, std::uint64_t height,
                    std::uint64_t max_pixels, const std::string& what) {
  std::ostringstream os;
  os << what << width << "x" << height << " (" << width * height << " pixels) is larger than ~max_image_pixels "
     << max_pixels;
  return refuse(why, refusal, ImageRefusal::kTooLarge, os.str());
}

}  // namespace

bool imageFromMsg(const sensor_msgs::ImageConstPtr& msg, cv::Mat* out, std::string* why, ImageRefusal* refusal,
                  std::uint64_t max_pixels) {
  namespace enc = sensor_msgs::image_encodings;
  if (refusal) *refusal = ImageRefusal::kNone;
  if (!msg) return refuse(why, refusal, ImageRefusal::kEmpty, "no image");
  if (static_cast<std::uint64_t>(msg->width) * msg->height > max_pixels)
    return refuseTooLarge(why, refusal, msg->width, msg->height, max_pixels, "image ");
  if (msg->width == 0 || msg->height == 0 || msg->data.empty()) {
    std::ostringstream os;
    os << "empty image (" << msg->width << " x " << msg->height << ", " << msg->data.size() << " bytes)";
    return refuse(why, refusal, ImageRefusal::kEmpty, os.str());
  }
  const std::string& e = msg->encoding;
  const bool shared = e == enc::MONO8 || e == enc::BGR8 || e == enc::TYPE_8UC1 || e == enc::TYPE_8UC3;
  const bool grey16 = e == enc::MONO16 || e == enc::TYPE_16UC1;
  const bool colour8 = e == enc::RGB8 || e == enc::BGRA8 || e == enc::RGBA8 || e == enc::TYPE_8UC4;
  const bool colour16 = e == enc::BGR16 || e == enc::RGB16 || e == enc::BGRA16 || e == enc::RGBA16;
  const int bayer = bayerCode(e);
  if (!shared && !grey16 && !colour8 && !colour16 && bayer < 0) {
    return refuse(why, refusal, ImageRefusal::kEncoding,
                  "unsupported encoding '" + e +
                      "' (mono8/16, bgr8/16, rgb8/16, bgra8/16, rgba8/16, bayer_*8/16, 8UC1/3/4, 16UC1 are)");
  }
  // cv_bridge views the data through step without checking its length: checked here.
  const std::size_t pixel_bytes = static_cast<std::size_t>(enc::numChannels(e)) * (enc::bitDepth(e) / 8);
  if (static_cast<std::size_t>(msg->step) < msg->width * pixel_bytes ||
      static_cast<std::size_t>(msg->step) * msg->height > msg->data.size()) {
    std::ostringstream os;
    os << "image data (" << msg->data.size() << " bytes, step " << msg->step << ") does not fit " << msg->width << "x"
       << msg->height << " " << e;
    return refuse(why, refusal, ImageRefusal::kLayout, os.str());
  }
  if (msg->width < kMinImageSide || msg->height < kMinImageSide) {
    std::ostringstream os;
    os << "image " << msg->width << "x" << msg->height << " is smaller than " << kMinImageSide << "x" << kMinImageSide;
    return refuse(why, refusal, ImageRefusal::kTooSmall, os.str());
  }
  try {
    const cv::Mat view = cv_bridge::toCvShare(msg)->image;  // no copy: shares the message's buffer
    if (shared) {
      *out = view;
    } else {
      const cv::Mat eight = view.depth() == CV_16U ? core::scaleTo8Bit(view) : view;
      if (bayer >= 0) {
        cv::cvtColor(eight, *out, bayer);
      } else if (grey16) {
        *out = eight;
      } else if (e == enc::RGB8 || e == enc::RGB16) {
        cv::cvtColor(eight, *out, cv::COLOR_RGB2BGR);
      } else if (e == enc::RGBA8 || e == enc::RGBA16) {
        cv::cvtColor(eight, *out, cv::COLOR_RGBA2BGR);
      } else if (e == enc::BGRA8 || e == enc::BGRA16 || e == enc::TYPE_8UC4) {
        cv::cvtColor(eight, *out, cv::COLOR_BGRA2BGR);
      } else {
        *out = eight;  // bgr16
      }
    }
  } catch (const std::exception& ex) {
    return refuse(why, refusal, ImageRefusal::kEncoding, std::string("cannot convert the image: ") + ex.what());
  }
  if (out->empty()) return refuse(why, refusal, ImageRefusal::kEmpty, "empty image after conversion");
  return true;
}

namespace {

enum class Codec { kUnknown, kJpeg, kPng };

/// The codec a CompressedImage format names: after the ';' when there is one
/// (compressed_image_transport), else the whole field ("jpeg", "png").
Codec codecOf(const std::string& format) {
  const std::size_t split = format.find(';');
  std::string c = split == std::string::npos ? format : format.substr(split + 1);
  std::transform(c.begin(), c.end(), c.begin(), [](unsigned char ch) { return std::tolower(ch); });
  if (c.find("compresseddepth") != std::string::npos) return Codec::kUnknown;
  std::istringstream words(c);
  std::string first;
  words >> first;
  if (first == "jpeg" || first == "jpg") return Codec::kJpeg;
  if (first == "png") return Codec::kPng;
  return Codec::kUnknown;
}

bool startsAs(const std::vector<std::uint8_t>& data, Codec codec) {
  static const std::uint8_t kJpeg[] = {0xFF, 0xD8, 0xFF};
  static const std::uint8_t kPng[] = {0x89, 'P', 'N', 'G', 0x0D, 0x0A, 0x1A, 0x0A};
  const std::uint8_t* magic = codec == Codec::kJpeg ? kJpeg : kPng;
  const std::size_t n = codec == Codec::kJpeg ? sizeof(kJpeg) : sizeof(kPng);
  return data.size() >= n && std::equal(magic, magic + n, data.begin());
}

/// The encoding of a decoded image: the one before compression when it fits (one channel, same
/// depth), else grey or BGR(A) by the decoded type; empty for a type the raw path cannot take.
std::string decodedEncoding(const cv::Mat& m, const std::string& before) {
  namespace enc = sensor_msgs::image_encodings;
  const bool sixteen = m.depth() == CV_16U;
  if (m.depth() != CV_8U && !sixteen) return "";
  if (m.channels() == 3) return sixteen ? enc::BGR16 : enc::BGR8;
  if (m.channels() == 4) return sixteen ? enc::BGRA16 : enc::BGRA8;
  if (m.channels() != 1) return "";
  try {
    if (!before.empty() && enc::numChannels(before) == 1 && enc::bitDepth(before) == (sixteen ? 16 : 8) &&
        (enc::isMono(before) || enc::isBayer(before) || before == enc::TYPE_8UC1 || before == enc::TYPE_16UC1)) {
      return before;
    }
  } catch (const std::exception&) {  // an encoding cv_bridge does not know: by the decoded type
  }
  return sixteen ? enc::MONO16 : enc::MONO8;
}

}  // namespace

bool compressedImageSize(const std::vector<std::uint8_t>& b, std::uint64_t* width, std::uint64_t* height) {
  auto be16 = [&](std::size_t i) { return static_cast<std::uint64_t>(b[i]) << 8 | b[i + 1]; };
  if (startsAs(b, Codec::kPng)) {  // signature, then the IHDR chunk: length, "IHDR", width, height
    if (b.size() < 24 || std::string(b.begin() + 12, b.begin() + 16) != "IHDR") return false;
    *width = be16(16) << 16 | be16(18);
    *height = be16(20) << 16 | be16(22);
    return true;
  }
  if (!startsAs(b, Codec::kJpeg)) return false;
  // JPEG markers (ITU T.81 B.1): FF xx, most followed by a 2-byte length that counts itself. The
  // frame header SOFn (C0-CF but C4 DHT, C8 JPG, CC DAC) comes before the first scan (DA).
  std::size_t i = 2;
  while (i + 3 < b.size()) {
    if (b[i] != 0xFF) return false;
    const std::uint8_t marker = b[i + 1];
    if (marker == 0xFF) {  // a fill byte
      ++i;
      continue;
    }
    if (marker == 0x01 || (marker >= 0xD0 && marker <= 0xD8)) {  // no length
      i += 2;
      continue;
    }
    if (marker == 0xD9 || marker == 0xDA) return false;  // the end, or a scan before any frame header
    const std::size_t length = be16(i + 2);
    if (length < 2) return false;
    if ((marker & 0xF0) == 0xC0 && marker != 0xC4 && marker != 0xC8 && marker != 0xCC) {
      if (i + 8 >= b.size()) return false;  // length, precision, height, width
      *height = be16(i + 5);
      *width = be16(i + 7);
      return true;
    }
    i += 2 + length;
  }
  return false;
}

bool imageFromCompressedMsg(const sensor_msgs::CompressedImage& msg, sensor_msgs::ImagePtr* out, std::string* why,
                            ImageRefusal* refusal, std::uint64_t max_pixels) {
  if (refusal) *refusal = ImageRefusal::kNone;
  if (msg.data.empty()) return refuse(why, refusal, ImageRefusal::kEmpty, "empty compressed image (no data)");
  const Codec codec = codecOf(msg.format);
  if (codec == Codec::kUnknown) {
    return refuse(why, refusal, ImageRefusal::kEncoding,
                  "unsupported compressed image format '" + msg.format +
                      "' (jpeg and png are, e.g. 'bgr8; jpeg compressed bgr8' or 'png')");
  }
  const char* name = codec == Codec::kJpeg ? "JPEG" : "PNG";
  std::ostringstream os;
  os << "corrupt compressed image (" << msg.data.size() << " bytes, format '" << msg.format << "'): ";
  if (!startsAs(msg.data, codec)) {
    return refuse(why, refusal, ImageRefusal::kCorrupt, os.str() + "not " + name + " data");
  }
  if (codec == Codec::kJpeg && isTruncatedJpeg(msg.data)) {
    return refuse(why, refusal, ImageRefusal::kCorrupt, os.str() + "truncated JPEG (no end-of-image marker)");
  }
  // The size before decoding: the header's, and no more data than 8 bytes a pixel (16-bit BGRA).
  std::uint64_t width = 0, height = 0;
  if (compressedImageSize(msg.data, &width, &height) && width * height > max_pixels)
    return refuseTooLarge(why, refusal, width, height, max_pixels, std::string("compressed ") + name + " image ");
  if (msg.data.size() / 8 > max_pixels) {
    std::ostringstream big;
    big << "compressed image of " << msg.data.size() << " bytes: more than an image of ~max_image_pixels " << max_pixels
        << " takes";
    return refuse(why, refusal, ImageRefusal::kTooLarge, big.str());
  }
  cv::Mat image;
  try {
    image = cv::imdecode(msg.data, cv::IMREAD_UNCHANGED);
  } catch (const cv::Exception& e) {
    return refuse(why, refusal, ImageRefusal::kCorrupt, os.str() + "OpenCV cannot decode it (" + e.err + ")");
  }
  if (image.empty()) return refuse(why, refusal, ImageRefusal::kCorrupt, os.str() + "OpenCV cannot decode it");
  if (image.total() > max_pixels)  // a header that hid its size: the decoded one
    return refuseTooLarge(why, refusal, image.cols, image.rows, max_pixels, std::string("decoded ") + name + " image ");
  // The encoding before compression: what compressed_image_transport writes before the ';'.
  const std::size_t split = msg.format.find(';');
  std::string before = split == std::string::npos ? "" : msg.format.substr(0, split);
  before.erase(std::remove_if(before.begin(), before.end(), [](unsigned char c) { return std::isspace(c); }),
               before.end());
  const std::string encoding = decodedEncoding(image, before);
  if (encoding.empty()) {
    std::ostringstream bad;
    bad << "compressed image decodes to " << image.channels() << " channel(s) of OpenCV depth " << image.depth()
        << " (8 or 16 bits, 1, 3 or 4 channels are supported)";
    return refuse(why, refusal, ImageRefusal::kEncoding, bad.str());
  }
  try {
    *out = cv_bridge::CvImage(msg.header, encoding, image).toImageMsg();
  } catch (const std::exception& e) {
    return refuse(why, refusal, ImageRefusal::kEncoding, std::string("cannot convert the decoded image: ") + e.what());
  }
  return true;
}

bool cameraFromMsg(const sensor_msgs::CameraInfo& msg, bool rectified, core::CameraIntrinsics* out, std::string* why) {
  image_geometry::PinholeCameraModel model;
  try {
    model.fromCameraInfo(msg);
  } catch (const std::exception& e) {
    return fail(why, std::string("camera_info: ") + e.what());
  }
  core::CameraIntrinsics c;
  const cv::Size size = model.reducedResolution();  // ROI and binning applied
  c.width = size.width;
  c.height = size.height;
  if (rectified) {
    const cv::Matx34d& p = model.projectionMatrix();
    if (p(0, 0) == 0.0 && p(1, 1) == 0.0) {
      return fail(why, "camera_info: P is zero, so rectified images have no camera");
    }
    c.fx = p(0, 0), c.fy = p(1, 1), c.cx = p(0, 2), c.cy = p(1, 2);
  } else {
    const cv::Matx33d& k = model.intrinsicMatrix();
    c.fx = k(0, 0), c.fy = k(1, 1), c.cx = k(0, 2), c.cy = k(1, 2);
    const bool distorted = std::any_of(msg.D.begin(), msg.D.end(), [](double d) { return d != 0.0; });
    namespace dm = sensor_msgs::distortion_models;
    if (distorted) {
      if (msg.distortion_model == dm::PLUMB_BOB) {
        c.distortion_model = core::DistortionModel::kPlumbBob;
      } else if (msg.distortion_model == dm::RATIONAL_POLYNOMIAL) {
        c.distortion_model = core::DistortionModel::kRationalPolynomial;
      } else {
        return fail(why, "camera_info: distortion model '" + msg.distortion_model +
                             "' is not supported (plumb_bob, rational_polynomial): rectify the images "
                             "(image_proc) and set ~rectified_images");
      }
      c.distortion.assign(msg.D.begin(), msg.D.end());
    }
  }
  const std::string bad = c.validate();
  if (!bad.empty()) return fail(why, "camera_info: " + bad);
  if (c.cx < 0 || c.cx > c.width || c.cy < 0 || c.cy > c.height) {
    std::ostringstream os;
    os << "camera_info: principal point (" << c.cx << ", " << c.cy << ") outside the " << c.width << "x" << c.height
       << " image";
    return fail(why, os.str());
  }
  *out = c;
  return true;
}

bool cameraInfoFromUrl(const std::string& url, sensor_msgs::CameraInfo* out, std::string* why) {
  std::string path;
  const std::string file = "file://", package = "package://";
  if (url.rfind(file, 0) == 0) {
    path = url.substr(file.size());
  } else if (url.rfind(package, 0) == 0) {
    const std::string rest = url.substr(package.size());
    const auto slash = rest.find('/');
    const std::string dir = slash == std::string::npos ? "" : ros::package::getPath(rest.substr(0, slash));
    if (dir.empty()) return fail(why, "camera_info_url " + url + ": no such package");
    path = dir + rest.substr(slash);
  } else if (url.rfind("/", 0) == 0) {
    path = url;
  } else {
    return fail(why, "camera_info_url " + url + ": expected file:///absolute/path, package://pkg/path or /path");
  }
  std::string name;
  sensor_msgs::CameraInfo info;
  if (!camera_calibration_parsers::readCalibration(path, name, info)) {
    return fail(why, "camera_info_url " + url + ": cannot read a calibration from " + path);
  }
  *out = info;
  return true;
}

bool altitudeFromMsg(const sensor_msgs::Range& msg, double max_altitude_m, double* altitude_m, std::string* why) {
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
  if (r > max_altitude_m) {
    std::ostringstream os;
    os << "altitude " << r << " above slam/odometry/max_altitude_m (" << max_altitude_m << ")";
    return fail(why, os.str());
  }
  *altitude_m = r;
  return true;
}

std::string describeCamera(const core::CameraIntrinsics& c) {
  char head[160];
  std::snprintf(head, sizeof(head), "%dx%d fx %.1f fy %.1f cx %.1f cy %.1f, distortion %s", c.width, c.height, c.fx,
                c.fy, c.cx, c.cy, core::distortionModelName(c.distortion_model).c_str());
  std::ostringstream d;
  d << head;
  for (double k : c.distortion) d << " " << k;
  return d.str();
}

double altitudeReading(const sensor_msgs::Range& msg, double max_altitude_m, bool* above_max, std::string* why) {
  double altitude = std::numeric_limits<double>::quiet_NaN();
  *above_max = false;
  if (altitudeFromMsg(msg, max_altitude_m, &altitude, why)) return altitude;
  *above_max = std::isfinite(msg.range) && msg.range > max_altitude_m;
  return std::numeric_limits<double>::quiet_NaN();
}

bool navFromMsg(const nav_msgs::Odometry& msg, const core::CameraMount& mount, core::NavRecord* nav, std::string* why) {
  auto refuse = [why](const std::string& w) {
    if (why) *why = w;
    return false;
  };
  core::UncertainPose2 vehicle;
  if (!fromMsg(msg.pose, &vehicle))
    return refuse("nav odometry: the pose or its covariance is not usable (not finite, a negative variance)");
  if (msg.header.stamp.isZero()) return refuse("nav odometry: zero stamp");
  const Eigen::Matrix3d& c = vehicle.covariance;
  if (!(c(0, 0) >= 0) || !(c(1, 1) >= 0) || !(c(2, 2) >= 0))
    return refuse("nav odometry: a negative variance on the diagonal");
  nav->stamp_s = msg.header.stamp.toSec();
  nav->pose = core::cameraFromVehicle(vehicle.mean, mount);
  nav->sigma_xy_m = std::sqrt(std::max(c(0, 0), c(1, 1)));
  nav->sigma_yaw_rad = std::sqrt(c(2, 2));
  if (!std::isfinite(nav->sigma_xy_m) || !std::isfinite(nav->sigma_yaw_rad))
    return refuse("nav odometry: covariance not finite");
  return true;
}

}  // namespace ros_conversions
}  // namespace uw_multislam
