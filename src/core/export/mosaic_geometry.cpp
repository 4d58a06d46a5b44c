#include "uw_multislam/core/export/mosaic_geometry.h"

#include <algorithm>
#include <cmath>

namespace uw_multislam {
namespace core {

CameraIntrinsics cameraScaledTo(const CameraIntrinsics& c, const cv::Size& size) {
  CameraIntrinsics s = c;
  const double kx = static_cast<double>(size.width) / c.width, ky = static_cast<double>(size.height) / c.height;
  s.width = size.width;
  s.height = size.height;
  s.fx *= kx;
  s.cx = (c.cx + 0.5) * kx - 0.5;  // pixel centres: the resize maps edge to edge
  s.fy *= ky;
  s.cy = (c.cy + 0.5) * ky - 0.5;
  return s;
}

cv::Matx23d groundFromPixel(const Pose2& pose, double altitude_m, const CameraIntrinsics& cam) {
  const double tx = pose.x(), ty = pose.y(), psi = pose.yaw();
  const double c = std::cos(psi), s = std::sin(psi), a = altitude_m / cam.fx, b = altitude_m / cam.fy;
  return {c * a, -s * b, tx - c * a * cam.cx + s * b * cam.cy, s * a, c * b, ty - s * a * cam.cx - c * b * cam.cy};
}

cv::Rect2d warpedFootprint(const cv::Matx23d& m, const cv::Size& size) {
  double x_lo = 1e300, x_hi = -1e300, y_lo = 1e300, y_hi = -1e300;
  for (const cv::Point2d p : {cv::Point2d(-0.5, -0.5), cv::Point2d(size.width - 0.5, -0.5),
                              cv::Point2d(-0.5, size.height - 0.5), cv::Point2d(size.width - 0.5, size.height - 0.5)}) {
    const double x = m(0, 0) * p.x + m(0, 1) * p.y + m(0, 2), y = m(1, 0) * p.x + m(1, 1) * p.y + m(1, 2);
    x_lo = std::min(x_lo, x);
    x_hi = std::max(x_hi, x);
    y_lo = std::min(y_lo, y);
    y_hi = std::max(y_hi, y);
  }
  return {x_lo, y_lo, x_hi - x_lo, y_hi - y_lo};
}

cv::Rect pixelBox(const cv::Rect2d& r) {
  const int x = static_cast<int>(std::floor(r.x)), y = static_cast<int>(std::floor(r.y));
  return {x, y, static_cast<int>(std::ceil(r.x + r.width)) - x + 1,
          static_cast<int>(std::ceil(r.y + r.height)) - y + 1};
}

}  // namespace core
}  // namespace uw_multislam
