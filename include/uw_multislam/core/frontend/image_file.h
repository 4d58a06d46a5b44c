#pragma once
// Reading a dataset folder's image files the way the live odometry reads its messages
// (ros/sensor_conversions): a cut-off JPEG is refused, 16-bit images are scaled to 8 bits by the
// smallest power-of-two range holding the frame's maximum, alpha is dropped.

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace uw_multislam {
namespace core {

/// What a path of type `t` is, for a message refusing it as an image file ("a directory", "a FIFO
/// (named pipe)", "a socket", ...; "a regular file" for one).
std::string fileTypeName(std::filesystem::file_type t);

/// Whether bytes starting as a JPEG (FF D8 FF) lack the end-of-image marker FF D9 (trailing
/// zero or white-space padding allowed): libjpeg decodes such a cut-off file with only a warning
/// (the missing rows come out grey).
bool isTruncatedJpeg(const std::vector<std::uint8_t>& bytes);

/// 16 bits -> 8 bits by the smallest 2^b - 1 >= the frame's maximum (b >= 8): a 12-bit sensor's
/// data uses the full 8 bits; the scale changes only when a frame's maximum crosses a power of two.
cv::Mat scaleTo8Bit(const cv::Mat& in16);

/// An image file decoded as stored (IMREAD_ANYCOLOR | IMREAD_ANYDEPTH: grey stays grey, 16 bits
/// stay 16 bits). Empty, with `why` (naming the file), when it cannot be opened or read, is not a
/// regular file (a directory, a FIFO: opened without blocking and refused by what it is), is empty,
/// is a truncated JPEG or does not decode.
cv::Mat decodeImageFile(const std::string& path, std::string* why);

/// An image file as the odometry takes it: 8 bits, grey or BGR (16 bits scaled as above; the
/// decoder drops alpha). Empty, with `why` (naming the file), when it cannot be read or decoded,
/// is a truncated JPEG, or has another depth (float images are refused: cv::imread with
/// IMREAD_COLOR used to convert them) or channel count.
cv::Mat readFrameImage(const std::string& path, std::string* why);

/// readFrameImage, grey turned into BGR (as cv::IMREAD_COLOR gave every image before): for the
/// consumers that keep or draw colour images (keyframe thumbnails, mosaics, offline_slam's frames).
cv::Mat readFrameImageBgr(const std::string& path, std::string* why = nullptr);

}  // namespace core
}  // namespace uw_multislam
