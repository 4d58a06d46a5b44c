#include "uw_multislam/core/store/keyframe_image.h"

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>

namespace uw_multislam {
namespace core {

std::string KeyframeImageOptions::validate() const {
  if (max_side_px != 0 && (max_side_px < 16 || max_side_px > 8192))
    return "image_max_side_px " + std::to_string(max_side_px) + " is out of range (0 = none, or 16..8192)";
  if (jpeg_quality < 1 || jpeg_quality > 100)
    return "image_jpeg_quality " + std::to_string(jpeg_quality) + " is out of range (1..100)";
  return {};
}

std::vector<std::uint8_t> encodeKeyframeImage(const cv::Mat& image, const KeyframeImageOptions& options) {
  std::vector<std::uint8_t> jpeg;
  if (image.empty() || options.max_side_px <= 0) return jpeg;
  cv::Mat grey, small;
  if (image.channels() == 3)
    cv::cvtColor(image, grey, cv::COLOR_BGR2GRAY);
  else if (image.channels() == 4)
    cv::cvtColor(image, grey, cv::COLOR_BGRA2GRAY);
  else
    grey = image;
  if (grey.depth() != CV_8U) grey.convertTo(grey, CV_8U, grey.depth() == CV_16U ? 1.0 / 257.0 : 1.0);
  const int side = std::max(grey.cols, grey.rows);
  if (side > options.max_side_px) {
    // Area averaging: no aliasing on the seabed's fine texture (what the mosaic shows).
    const double f = static_cast<double>(options.max_side_px) / side;
    const cv::Size size(std::max(1, static_cast<int>(grey.cols * f + 0.5)),
                        std::max(1, static_cast<int>(grey.rows * f + 0.5)));
    cv::resize(grey, small, size, 0, 0, cv::INTER_AREA);
  } else {
    small = grey;
  }
  cv::imencode(".jpg", small, jpeg, {cv::IMWRITE_JPEG_QUALITY, options.jpeg_quality});
  return jpeg;
}

}  // namespace core
}  // namespace uw_multislam
