// VLFeat's SIFT (vl/sift.h, Vedaldi & Fulkerson) behind OpenCV's cv::Feature2D, for builds whose
// OpenCV has no SIFT (OpenCV 4.2 of Ubuntu 20.04 without opencv_contrib's nonfree part). The
// multi-session paper's own code computes its SIFT with VLFeat. FeatureExtractor uses it like
// cv::SIFT (odometry.features.sift_backend: vlfeat); its keypoints and descriptors follow OpenCV's
// conventions so that everything after the extractor is unchanged:
//   - pt: pixels, (0, 0) the centre of the top-left pixel; size: 2 sigma (pixels); angle: degrees,
//     [0, 360), measured from the x axis towards y (image y down), as cv::SIFT's;
//   - response: |DoG| at the interpolated extremum with the image in [0, 1], cv::SIFT's contrast;
//   - octave: the octave (-1 the doubled image) in the low byte and the layer in the next, as
//     OpenCV packs them;
//   - descriptors: rows x 128 CV_32F of whole numbers 0..255 (VLFeat's unit vector x 512, clipped
//     at 255, rounded: cv::SIFT's scaling), in cv::SIFT's bin order.
// The settings are FeatureOptions' SIFT ones with OpenCV's meaning: contrast_threshold / octave_layers
// is VLFeat's peak threshold on the [0, 1] image, edge_threshold its edge threshold, sigma the base
// blur of the first level, first_octave VLFeat's o_min (-1 doubles the image, 0 does not).
#pragma once

#include <opencv2/features2d.hpp>

#include <string>

#include "uw_multislam/core/frontend/features.h"

namespace uw_multislam {
namespace core {

/// Why this build cannot run VLFeat's SIFT (built without VLFeat), or empty when it can.
std::string vlfeatSiftUnavailable();

/// A detector with cv::Feature2D's detectAndCompute (no mask, no provided keypoints) keeping the
/// `max_keypoints` strongest by response (cv::SIFT's nfeatures; 0 keeps all). Throws
/// std::invalid_argument when the build has no VLFeat or the options are not valid. Not
/// thread-safe: its scale space buffers are kept between images of one size.
cv::Ptr<cv::Feature2D> createVlfeatSift(const FeatureOptions& options, int max_keypoints);

}  // namespace core
}  // namespace uw_multislam
