// The image a keyframe keeps in the session store: the whole frame, grey,
// resized so that its longest side is at most max_side_px (never enlarged) and JPEG-encoded at
// jpeg_quality. Mosaics drawn from the store alone (export_survey without --images) use it, with
// the camera scaled by the stored image's size (core/export/mosaic.h). The store's `thumbnail`
// column holds it (a JPEG either way: no schema change). Config block `store` (config/slam.yaml);
// the default is chosen from bench_store's cost per keyframe (doc/session_store.md).
#pragma once

#include <opencv2/core.hpp>

#include <cstdint>
#include <string>
#include <vector>

namespace uw_multislam {
namespace core {

struct KeyframeImageOptions {
  int max_side_px = 320;  // longest side of the stored image; 0 = no image stored
  int jpeg_quality = 75;  // 1..100 (OpenCV's IMWRITE_JPEG_QUALITY)

  /// Empty when usable, else "<key> <reason>".
  std::string validate() const;
};

/// The JPEG of `image` (BGR, grey or BGRA; 8 bit) as the store keeps it; empty for an empty
/// image or max_side_px = 0.
std::vector<std::uint8_t> encodeKeyframeImage(const cv::Mat& image, const KeyframeImageOptions& options);

}  // namespace core
}  // namespace uw_multislam
