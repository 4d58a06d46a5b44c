// The odometry nodelet's inputs in core types: sensor_msgs/Image -> cv::Mat (8-bit grey or BGR,
// what core::Odometry takes), sensor_msgs/CompressedImage -> sensor_msgs/Image (the built-in
// decoder), CameraInfo -> core::CameraIntrinsics, Range -> altitude. Each
// returns false with a one-line reason for input the core cannot use (the nodelet counts and
// skips it); none throws. Tested in test/ros/test_sensor_conversions.cpp.
#pragma once

#include <nav_msgs/Odometry.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/Range.h>

#include <cstdint>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/frontend/image_file.h"
#include "uw_multislam/core/geometry/vehicle_frame.h"

namespace uw_multislam {
namespace ros_conversions {

/// Why imageFromMsg refused an image (the odometry nodelet counts each kind separately).
/// kSizeMismatch: another size than the camera's (ros/image_input.h imageFromInput).
enum class ImageRefusal { kNone, kEmpty, kEncoding, kLayout, kTooSmall, kCorrupt, kTooLarge, kSizeMismatch };
/// "none", "empty", "encoding", "layout", "too_small", "corrupt", "too_large", "size_mismatch".
std::string imageRefusalName(ImageRefusal r);

/// Images narrower or lower than this are refused (kTooSmall): SIFT finds nothing useful in
/// them, and the odometry would start a session on a keyframe without features.
constexpr unsigned kMinImageSide = 32;

/// The default largest image (pixels, width x height) the odometry takes: 25 Mpx, more than a
/// survey camera gives (4096 x 4096 is 16.8 Mpx, 6000 x 4000 is 24 Mpx). A larger image is
/// refused (kTooLarge) from its header, before anything is converted, decoded or allocated: a
/// 10000 x 10000 image used to take 14 s and 5 GB. The odometry's
/// ~max_image_pixels sets it.
constexpr std::uint64_t kDefaultMaxImagePixels = 25000000;

/// The image as the core takes it (8-bit grey or BGR). What is done with each encoding:
///   mono8, 8UC1, bgr8, 8UC3              shared without a copy (the Mat keeps the message alive)
///   rgb8, bgra8, rgba8, 8UC4 (as bgra)   converted to bgr8, alpha dropped
///   mono16, 16UC1                        scaled to 8 bits by the smallest power-of-two range that
///                                        holds the frame's maximum (a 12-bit sensor in mono16 uses
///                                        the full 8 bits, and the scale stays the same frame to frame)
///   bgr16, rgb16, bgra16, rgba16         the same scaling, then to bgr8
///   bayer_{rggb,bggr,gbrg,grbg}{8,16}    debayered (OpenCV, bilinear) to bgr8 (16 bits scaled as above)
///   anything else (float, YUV, 2-channel, signed) refused (kEncoding), as are an empty image
///   (kEmpty), a step / data size that does not fit (kLayout), an image smaller than
///   kMinImageSide in either direction (kTooSmall) and one of more than `max_pixels` pixels
///   (kTooLarge, from width and height before anything else). Never throws.
bool imageFromMsg(const sensor_msgs::ImageConstPtr& msg, cv::Mat* out, std::string* why = nullptr,
                  ImageRefusal* refusal = nullptr, std::uint64_t max_pixels = kDefaultMaxImagePixels);

/// A sensor_msgs/CompressedImage decoded with OpenCV (cv::imdecode, unchanged depth and
/// channels) into a sensor_msgs/Image with the same header, for the odometry when image_transport
/// has no `compressed` plugin (Debian ships none). The result then goes through imageFromMsg like
/// any raw image. The format field is read as compressed_image_transport writes it,
/// "<encoding>; <jpeg|png> compressed [<target>]" (e.g. "bgr8; jpeg compressed bgr8",
/// "mono8; png compressed "), or as the message definition allows, plain "jpeg" / "png":
///   - colour data decodes to bgr8 / bgr16 (bgra8 / bgra16 with alpha), whatever the encoding
///     before compression (the plugin compresses colour as BGR);
///   - one channel decodes to the encoding before compression when it has one channel and the
///     same depth (mono8, mono16, 8UC1, 16UC1, bayer_*: then debayered by imageFromMsg), else to
///     mono8 / mono16.
/// Refused: no data (kEmpty); a format that is neither jpeg nor png, or compressedDepth
/// (kEncoding); data that is not of the format's kind, a JPEG without its end-of-image marker
/// (truncated: libjpeg would only warn and fill grey), or data OpenCV cannot decode (kCorrupt);
/// an image of more than `max_pixels` pixels (kTooLarge), by the size its header declares
/// (compressedImageSize) before it is decoded, by more data than such an image could take
/// (8 bytes a pixel), and by the decoded size. Bytes damaged inside a JPEG's entropy-coded data
/// may still decode (libjpeg only warns), into a damaged image. Never throws.
bool imageFromCompressedMsg(const sensor_msgs::CompressedImage& msg, sensor_msgs::ImagePtr* out,
                            std::string* why = nullptr, ImageRefusal* refusal = nullptr,
                            std::uint64_t max_pixels = kDefaultMaxImagePixels);

/// The width and height a PNG (its IHDR chunk) or a JPEG (its first SOFn frame header) declares,
/// read from the header without decoding. False when the data is neither or its header cannot be
/// read (the decoder then decides).
bool compressedImageSize(const std::vector<std::uint8_t>& data, std::uint64_t* width, std::uint64_t* height);

/// Whether bytes starting as a JPEG lack the end-of-image marker (core/frontend/image_file.h).
using core::isTruncatedJpeg;

/// The camera of the images, through image_geometry::PinholeCameraModel (binning and ROI applied:
/// the size, K and P of the image as it arrives). `rectified` (images from image_proc's
/// image_rect): P's fx, fy, cx, cy and no distortion; otherwise K with D (plumb_bob or
/// rational_polynomial; the core undistorts the feature points). Refuses a zero or non-finite
/// focal length, a zero image size, a principal point outside the image, a zero P for rectified
/// images, and a distortion model the core does not have (equidistant, unknown) with a non-zero D.
bool cameraFromMsg(const sensor_msgs::CameraInfo& msg, bool rectified, core::CameraIntrinsics* out,
                   std::string* why = nullptr);

/// "WxH fx F fy F cx C cy C, distortion MODEL k1 k2 ..." for the log.
std::string describeCamera(const core::CameraIntrinsics& camera);

/// A calibration file (camera_calibration_parsers: YAML or INI) named by a camera_info_url
/// (file:///abs/path, package://pkg/path or a plain absolute path), for bags without camera_info.
bool cameraInfoFromUrl(const std::string& url, sensor_msgs::CameraInfo* out, std::string* why = nullptr);

/// The range as altitude; refuses non-finite or non-positive values and ones outside
/// [min_range, max_range] (sensor_msgs/Range: such readings must be discarded).
/// `max_altitude_m` (slam/odometry/max_altitude_m) bounds it too: a reading above is a glitch or an
/// altimeter's "no bottom" value whatever range the message claims.
bool altitudeFromMsg(const sensor_msgs::Range& msg, double max_altitude_m, double* altitude_m,
                     std::string* why = nullptr);

/// The reading as core::AltitudeBuffer keeps it: altitudeFromMsg's altitude, or NaN for a refused
/// reading (kept as an invalid one: images at its stamp get no altitude), `why` saying why and
/// `above_max` whether it was refused for being above max_altitude_m.
double altitudeReading(const sensor_msgs::Range& msg, double max_altitude_m, bool* above_max, std::string* why);

/// The vehicle's dead reckoning (nav_msgs/Odometry: base_link in its odom frame, z-up, REP-105)
/// as a nav row of the core (the camera's pose in the core's image axes, core::cameraFromVehicle
/// with `mount`; only the motions between rows are used, so the odom frame's origin does not
/// matter). sigma_xy is the larger of the x and y standard deviations, sigma_yaw the yaw's. false
/// (`why` says why) for a pose or covariance that is not finite, a negative variance or a zero stamp.
bool navFromMsg(const nav_msgs::Odometry& msg, const core::CameraMount& mount, core::NavRecord* nav,
                std::string* why = nullptr);

}  // namespace ros_conversions
}  // namespace uw_multislam
