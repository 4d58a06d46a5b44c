#include "uw_multislam/core/frontend/image_file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cctype>
#include <cerrno>
#include <cstring>

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

std::filesystem::file_type typeOf(mode_t mode) {
  using T = std::filesystem::file_type;
  if (S_ISREG(mode)) return T::regular;
  if (S_ISDIR(mode)) return T::directory;
  if (S_ISFIFO(mode)) return T::fifo;
  if (S_ISSOCK(mode)) return T::socket;
  if (S_ISBLK(mode)) return T::block;
  if (S_ISCHR(mode)) return T::character;
  return T::unknown;
}

// The whole file at `path`, or a reason. Opened without blocking (a FIFO would wait for a writer)
// and read only when it is a regular file.
bool readRegularFile(const std::string& path, std::vector<std::uint8_t>* bytes, std::string* reason) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) {
    *reason = std::string("cannot open (") + std::strerror(errno) + ")";
    return false;
  }
  struct stat st {};
  bool ok = ::fstat(fd, &st) == 0;
  if (!ok) {
    *reason = std::string("cannot examine (") + std::strerror(errno) + ")";
  } else if (!S_ISREG(st.st_mode)) {
    *reason = fileTypeName(typeOf(st.st_mode)) + ", not an image file";
    ok = false;
  }
  bytes->clear();
  if (ok) bytes->reserve(static_cast<std::size_t>(st.st_size));
  std::uint8_t chunk[1 << 16];
  while (ok) {
    const ssize_t n = ::read(fd, chunk, sizeof chunk);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) {
      *reason = std::string("read error (") + std::strerror(errno) + ")";
      ok = false;
    } else if (n == 0) {
      break;
    } else {
      bytes->insert(bytes->end(), chunk, chunk + n);
    }
  }
  ::close(fd);
  return ok;
}

}  // namespace

std::string fileTypeName(std::filesystem::file_type t) {
  using T = std::filesystem::file_type;
  switch (t) {
    case T::regular:
      return "a regular file";
    case T::directory:
      return "a directory";
    case T::fifo:
      return "a FIFO (named pipe)";
    case T::socket:
      return "a socket";
    case T::block:
      return "a block device";
    case T::character:
      return "a character device";
    case T::symlink:
      return "a symbolic link";
    case T::not_found:
      return "missing";
    default:
      return "not a regular file";
  }
}

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
  std::vector<std::uint8_t> bytes;
  std::string reason;
  if (!readRegularFile(path, &bytes, &reason)) return refuse(reason);
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
