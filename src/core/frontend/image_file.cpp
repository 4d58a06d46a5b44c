#include "uw_multislam/core/frontend/image_file.h"

#include <cctype>
#include <fstream>
#include <iterator>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace uw_multislam {
namespace core {

namespace {

// An empty image, with why the file at `path` was not read.
cv::Mat refusal(const std::string& path, const std::string& reason, std::string* why) {
  if (why) *why = path + ": " + reason;
  return cv::Mat();
}

}  // namespace

bool isTruncatedJpeg(const std::vector<std::uint8_t>& b) {
  if (b.size() < 3 || b[0] != 0xFF || b[1] != 0xD8 || b[2] != 0xFF) return false;  // not a JPEG
  std::size_t end = b.size();
  while (end > 2 && (b[end - 1] == 0x00 || std::isspace(b[end - 1]))) --end;
  return !(end >= 4 && b[end - 2] == 0xFF && b[end - 1] == 0xD9);
}

cv::Mat scaleTo8Bit(const cv::Mat& in16) {
  double max_value = 0.0;
  cv::minMaxLoc(in16.reshape(1), nullptr, &max_value);
  double range = 255.0;
  while (range < max_value && range < 65535.0) range = range * 2.0 + 1.0;
  cv::Mat out;
  in16.convertTo(out, CV_MAKETYPE(CV_8U, in16.channels()), 255.0 / range);
  return out;
}

cv::Mat decodeImageFile(const std::string& path, std::string* why) {
  const auto refuse = [&](const std::string& reason) { return refusal(path, reason, why); };
  std::ifstream in(path, std::ios::binary);
  if (!in) return refuse("cannot open");
  const std::vector<std::uint8_t> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (in.bad()) return refuse("read error");
  if (bytes.empty()) return refuse("empty file");
  if (isTruncatedJpeg(bytes)) return refuse("corrupt image (truncated JPEG: no end-of-image marker)");
  cv::Mat image;
  try {
    image = cv::imdecode(bytes, cv::IMREAD_ANYCOLOR | cv::IMREAD_ANYDEPTH);
  } catch (const cv::Exception& e) {
    return refuse("cannot decode image (" + e.err + ")");
  }
  if (image.empty()) return refuse("cannot decode image (corrupt or not an image file)");
  return image;
}

cv::Mat readFrameImage(const std::string& path, std::string* why) {
  const auto refuse = [&](const std::string& reason) { return refusal(path, reason, why); };
  cv::Mat image = decodeImageFile(path, why);
  if (image.empty()) return image;
  if (image.depth() == CV_16U) {
    image = scaleTo8Bit(image);
  } else if (image.depth() != CV_8U) {
    return refuse("unsupported image depth (OpenCV depth " + std::to_string(image.depth()) + "; 8 or 16 bits are)");
  }
  if (image.channels() == 4) {  // the decoders drop alpha with IMREAD_ANYCOLOR; kept should one not
    cv::cvtColor(image, image, cv::COLOR_BGRA2BGR);
  } else if (image.channels() != 1 && image.channels() != 3) {
    return refuse("unsupported image (" + std::to_string(image.channels()) + " channels)");
  }
  return image;
}

cv::Mat readFrameImageBgr(const std::string& path, std::string* why) {
  cv::Mat image = readFrameImage(path, why);
  if (!image.empty() && image.channels() == 1) cv::cvtColor(image, image, cv::COLOR_GRAY2BGR);
  return image;
}

}  // namespace core
}  // namespace uw_multislam
