#include "uw_multislam/sim/seabed_world.h"

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>

namespace uw_multislam {
namespace core {

namespace {

// Smooth noise in [0, 1] with features of about `scale_px` pixels: a coarse uniform grid
// upsampled with bicubic interpolation.
cv::Mat smoothNoise(cv::Size size, double scale_px, cv::RNG& rng) {
  const int gw = std::max(2, static_cast<int>(std::ceil(size.width / scale_px)) + 3);
  const int gh = std::max(2, static_cast<int>(std::ceil(size.height / scale_px)) + 3);
  cv::Mat grid(gh, gw, CV_32F);
  rng.fill(grid, cv::RNG::UNIFORM, 0.0f, 1.0f);
  cv::Mat up;
  cv::resize(grid, up, cv::Size(static_cast<int>(gw * scale_px), static_cast<int>(gh * scale_px)), 0, 0,
             cv::INTER_CUBIC);
  return up(cv::Rect(static_cast<int>(scale_px), static_cast<int>(scale_px), size.width, size.height)).clone();
}

// The value below which `fraction` of the field lies.
float quantile(const cv::Mat& field, double fraction) {
  cv::Mat sorted = field.reshape(1, 1).clone();
  cv::sort(sorted, sorted, cv::SORT_ASCENDING);
  const int i = std::clamp(static_cast<int>(fraction * (sorted.cols - 1)), 0, sorted.cols - 1);
  return sorted.at<float>(0, i);
}

// A soft mask (0..1) of the `fraction` of the area where `field` is highest.
cv::Mat softMask(const cv::Mat& field, double fraction, double edge_px) {
  cv::Mat mask;
  if (fraction <= 0.0) return cv::Mat::zeros(field.size(), CV_32F);
  const float t = quantile(field, 1.0 - fraction);
  cv::threshold(field, mask, t, 1.0, cv::THRESH_BINARY);
  const int k = std::max(3, static_cast<int>(edge_px) | 1);
  cv::GaussianBlur(mask, mask, cv::Size(k, k), edge_px / 3.0);
  return mask;
}

// dst = dst * (1 - a) + src * a, per pixel, with a in [0, 1] (CV_32F) and 3-channel float images.
cv::Mat threeChannels(const cv::Mat& single) {
  cv::Mat out;
  cv::merge(std::vector<cv::Mat>{single, single, single}, out);
  return out;
}

void blend(cv::Mat& dst, const cv::Mat& src, const cv::Mat& alpha) {
  const cv::Mat diff = src - dst;
  dst = dst + diff.mul(threeChannels(alpha));
}

// A 3-channel float image: the single-channel shade times a BGR colour.
cv::Mat tinted(const cv::Mat& shade, const cv::Scalar& bgr) {
  cv::Mat out;
  cv::multiply(threeChannels(shade), bgr, out);
  return out;
}

// A colour varied in brightness by up to +-amount and in hue by a fifth of that.
// Random draws here are one per declarator, never two in one call's arguments: C++ leaves their
// order unspecified, GCC evaluates them right to left on x86-64 and left to right on aarch64, so a
// seed gave another world on an arm64 vehicle (scripts/arm64_check.sh). They are taken in the order
// x86-64 took them (last argument first): the worlds of every seed stay what they were there.
cv::Scalar jitter(const cv::Scalar& c, double amount, cv::RNG& rng) {
  const double b = 1 + rng.uniform(-amount, amount), h = amount / 5;
  const double h2 = rng.uniform(-h, h), h1 = rng.uniform(-h, h), h0 = rng.uniform(-h, h);
  return cv::Scalar(c[0] * b * (1 + h0), c[1] * b * (1 + h1), c[2] * b * (1 + h2));
}

std::vector<cv::Point> rockOutline(cv::Point2d centre, double radius_px, cv::RNG& rng) {
  const int n = rng.uniform(7, 14);
  const double elong = rng.uniform(0.55, 1.0), rot = rng.uniform(0.0, CV_PI);
  std::vector<cv::Point> pts;
  for (int i = 0; i < n; ++i) {
    const double a = 2 * CV_PI * i / n + rng.uniform(-0.2, 0.2);
    const double r = radius_px * rng.uniform(0.7, 1.15);
    const double x = r * std::cos(a), y = r * elong * std::sin(a);
    pts.emplace_back(cvRound(centre.x + x * std::cos(rot) - y * std::sin(rot)),
                     cvRound(centre.y + x * std::sin(rot) + y * std::cos(rot)));
  }
  return pts;
}

}  // namespace

std::string ProceduralSeabedOptions::validate() const {
  std::ostringstream os;
  if (!(width_m > 0 && height_m > 0)) {
    os << "world size " << width_m << " x " << height_m << " m must be positive";
  } else if (!(metres_per_px >= 0.0005 && metres_per_px <= 0.1)) {
    os << "metres_per_px " << metres_per_px << " must be within [0.0005, 0.1]";
  } else if (width_m * height_m / (metres_per_px * metres_per_px) > 150e6) {
    os << "world raster of " << width_m / metres_per_px << " x " << height_m / metres_per_px
       << " px is over 150 Mpx: make the world smaller or metres_per_px larger";
  } else if (!(featureless_fraction >= 0 && featureless_fraction <= 0.8)) {
    os << "featureless_fraction " << featureless_fraction << " must be within [0, 0.8]";
  } else if (!(seagrass_fraction >= 0 && seagrass_fraction <= 0.8)) {
    os << "seagrass_fraction " << seagrass_fraction << " must be within [0, 0.8]";
  } else if (!(rock_density_per_m2 >= 0 && rock_density_per_m2 <= 50)) {
    os << "rock_density_per_m2 " << rock_density_per_m2 << " must be within [0, 50]";
  } else if (!(pebble_density_per_m2 >= 0 && pebble_density_per_m2 <= 500)) {
    os << "pebble_density_per_m2 " << pebble_density_per_m2 << " must be within [0, 500]";
  }
  return os.str();
}

SeabedWorld::SeabedWorld(cv::Mat bgr, double metres_per_px, const Eigen::Vector2d& origin_px, cv::Mat valid)
    : image_(std::move(bgr)), valid_(std::move(valid)), metres_per_px_(metres_per_px), origin_px_(origin_px) {
  if (image_.empty() || image_.type() != CV_8UC3) throw DatasetError("seabed world: raster must be 8-bit BGR");
  if (!(metres_per_px_ > 0.0) || !std::isfinite(metres_per_px_)) {
    throw DatasetError("seabed world: metres per pixel must be positive");
  }
  if (!valid_.empty() && (valid_.size() != image_.size() || valid_.type() != CV_8U)) {
    throw DatasetError("seabed world: valid mask must be CV_8U of the raster's size");
  }
}

SeabedWorld SeabedWorld::procedural(const ProceduralSeabedOptions& o) {
  const std::string bad = o.validate();
  if (!bad.empty()) throw DatasetError("procedural seabed: " + bad);
  const double mpp = o.metres_per_px;
  const cv::Size size(static_cast<int>(std::ceil(o.width_m / mpp)), static_cast<int>(std::ceil(o.height_m / mpp)));
  const auto px = [mpp](double metres) { return metres / mpp; };
  cv::RNG rng(o.seed * 0x9E3779B97F4A7C15ULL + 12345);

  // Sand: a tan base modulated at 3 m, 0.8 m and 0.2 m, with ripples in some areas.
  const cv::Mat n3 = smoothNoise(size, px(3.0), rng), n08 = smoothNoise(size, px(0.8), rng),
                n02 = smoothNoise(size, px(0.2), rng);
  cv::Mat shade = 0.78 + 0.30 * n3 + 0.16 * n08 + 0.10 * n02;
  const cv::Mat ripple_area = softMask(smoothNoise(size, px(4.0), rng), 0.35, px(0.8));
  const cv::Mat warp = smoothNoise(size, px(1.0), rng);
  const double ripple_angle = rng.uniform(0.0, CV_PI), wavelength = px(rng.uniform(0.09, 0.16));
  cv::Mat ripples(size, CV_32F);
  for (int y = 0; y < size.height; ++y) {
    float* r = ripples.ptr<float>(y);
    const float* w = warp.ptr<float>(y);
    for (int x = 0; x < size.width; ++x) {
      const double d = x * std::cos(ripple_angle) + y * std::sin(ripple_angle);
      r[x] = static_cast<float>(std::sin(2 * CV_PI * d / wavelength + 6.0 * w[x]));
    }
  }
  shade += 0.10 * ripples.mul(ripple_area);
  cv::Mat img = tinted(shade, cv::Scalar(140, 172, 192));  // BGR sand

  // Seagrass patches: a dark green-brown base; blades are drawn later.
  const cv::Mat featureless = softMask(smoothNoise(size, px(5.0), rng), o.featureless_fraction, px(0.6));
  cv::Mat seagrass = softMask(smoothNoise(size, px(3.5), rng), o.seagrass_fraction, px(0.4));
  seagrass = seagrass.mul(1.0 - featureless);
  blend(img, tinted(shade, cv::Scalar(58, 92, 74)), seagrass * 0.85);

  // Rocks, clustered where a 6 m noise field is high, each with a cast shadow and a highlight.
  const cv::Mat cluster = smoothNoise(size, px(6.0), rng);
  const double area = o.width_m * o.height_m;
  const int rocks = static_cast<int>(o.rock_density_per_m2 * area);
  for (int i = 0, placed = 0; placed < rocks && i < rocks * 20; ++i) {
    const double cy = rng.uniform(0.0, static_cast<double>(size.height)),
                 cx = rng.uniform(0.0, static_cast<double>(size.width));
    const cv::Point2d c(cx, cy);
    const cv::Point ci(std::min(size.width - 1, static_cast<int>(c.x)),
                       std::min(size.height - 1, static_cast<int>(c.y)));
    if (rng.uniform(0.0, 1.0) > std::pow(cluster.at<float>(ci), 2.0) * 1.6) continue;
    if (featureless.at<float>(ci) > 0.3) continue;
    ++placed;
    const double r = px(std::clamp(0.06 * std::exp(rng.gaussian(0.7)), 0.03, 0.45));
    const auto outline = rockOutline(c, r, rng);
    std::vector<cv::Point> shadow;
    for (const auto& p : outline) shadow.emplace_back(p.x + cvRound(0.18 * r), p.y + cvRound(0.18 * r));
    cv::fillPoly(img, std::vector<std::vector<cv::Point>>{shadow}, cv::Scalar(60, 70, 80), cv::LINE_AA);
    const cv::Scalar rock = jitter(cv::Scalar(112, 118, 125), 0.25, rng);
    cv::fillPoly(img, std::vector<std::vector<cv::Point>>{outline}, rock, cv::LINE_AA);
    std::vector<cv::Point> light;
    for (const auto& p : outline) {
      light.emplace_back(cvRound(c.x + 0.55 * (p.x - c.x) - 0.15 * r), cvRound(c.y + 0.55 * (p.y - c.y) - 0.15 * r));
    }
    cv::fillPoly(img, std::vector<std::vector<cv::Point>>{light}, rock * 1.25, cv::LINE_AA);
  }

  // Pebbles and shells: small light or dark ellipses.
  const int pebbles = static_cast<int>(o.pebble_density_per_m2 * area);
  for (int i = 0; i < pebbles; ++i) {
    const int cy = rng.uniform(0, size.height), cx = rng.uniform(0, size.width);
    const cv::Point c(cx, cy);
    if (featureless.at<float>(c) > 0.3) continue;
    const double r = px(rng.uniform(0.008, 0.03));
    const bool shell = rng.uniform(0.0, 1.0) < 0.5;
    const cv::Scalar colour =
        shell ? jitter(cv::Scalar(205, 215, 225), 0.1, rng) : jitter(cv::Scalar(70, 80, 95), 0.3, rng);
    const double angle = rng.uniform(0.0, 180.0), aspect = rng.uniform(0.4, 0.9);
    cv::ellipse(img, c, cv::Size(std::max(1, cvRound(r)), std::max(1, cvRound(r * aspect))), angle, 0, 360, colour,
                cv::FILLED, cv::LINE_AA);
  }

  // Seagrass blades, combed along a slowly varying direction.
  const cv::Mat flow = smoothNoise(size, px(2.0), rng);
  const double grass_area = cv::sum(seagrass)[0] * mpp * mpp;
  const int blades = static_cast<int>(grass_area * 450.0);
  for (int i = 0, tries = 0; i < blades && tries < blades * 6; ++tries) {
    const int cy = rng.uniform(0, size.height), cx = rng.uniform(0, size.width);
    const cv::Point c(cx, cy);
    if (rng.uniform(0.0f, 1.0f) > seagrass.at<float>(c)) continue;
    ++i;
    const double angle = 4.0 * flow.at<float>(c) + rng.gaussian(0.35), len = px(rng.uniform(0.05, 0.2));
    const cv::Point e(cvRound(c.x + len * std::cos(angle)), cvRound(c.y + len * std::sin(angle)));
    const cv::Scalar green = jitter(cv::Scalar(50, 110, 80), 0.35, rng);
    cv::line(img, c, e, green, std::max(1, cvRound(px(rng.uniform(0.004, 0.012)))), cv::LINE_AA);
  }

  // Sand grain: 2-3 px blobs, stable under resampling, everywhere but on featureless sand.
  cv::Mat grain(size, CV_32F);
  rng.fill(grain, cv::RNG::NORMAL, 0.0, 1.0);
  cv::GaussianBlur(grain, grain, cv::Size(5, 5), 1.0);
  const cv::Mat grain_gain = 1.0 + 0.35 * grain.mul(1.0 - featureless);
  img = img.mul(threeChannels(grain_gain));

  // Featureless sand: only a faint large-scale shading survives.
  const cv::Mat smooth_shade = 0.92 + 0.06 * n3;
  blend(img, tinted(smooth_shade, cv::Scalar(150, 180, 198)), featureless);

  cv::Mat out;
  img.convertTo(out, CV_8UC3);
  return SeabedWorld(out, mpp, Eigen::Vector2d::Zero());
}

SeabedWorld SeabedWorld::fromMosaic(const std::string& image_path, const std::string& georef_path, int black_level) {
  cv::Mat img = cv::imread(image_path, cv::IMREAD_COLOR);
  if (img.empty()) throw DatasetError(image_path + ": cannot read the mosaic image");
  std::ifstream in(georef_path);
  if (!in) throw DatasetError(georef_path + ": cannot open");
  double mpp = 0.0, ou = NAN, ov = NAN;
  std::string line;
  while (std::getline(in, line)) {
    std::istringstream ls(line);
    std::string key;
    ls >> key;
    if (key == "m_per_px") ls >> mpp;
    if (key == "origin_px") ls >> ou >> ov;
  }
  if (!(mpp > 0.0) || !std::isfinite(mpp)) throw DatasetError(georef_path + ": missing or bad 'm_per_px'");
  if (!std::isfinite(ou) || !std::isfinite(ov)) throw DatasetError(georef_path + ": missing or bad 'origin_px U V'");
  // Valid seabed: not black; small dark holes inside are closed, the border of the imaged
  // area is eroded so that JPEG fringes never enter a frame.
  std::vector<cv::Mat> ch;
  cv::split(img, ch);
  cv::Mat mx = cv::max(cv::max(ch[0], ch[1]), ch[2]);
  cv::Mat valid = mx > black_level;
  const cv::Mat k = cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(9, 9));
  cv::morphologyEx(valid, valid, cv::MORPH_CLOSE, k);
  cv::erode(valid, valid, k);
  return SeabedWorld(img, mpp, Eigen::Vector2d(ou, ov), valid);
}

Eigen::Vector2d SeabedWorld::worldToPixel(const Eigen::Vector2d& w) const { return origin_px_ + w / metres_per_px_; }

Eigen::Vector2d SeabedWorld::pixelToWorld(const Eigen::Vector2d& px) const {
  return (px - origin_px_) * metres_per_px_;
}

cv::Matx23d SeabedWorld::cameraToRaster(const Pose2& pose, double altitude_m, const CameraIntrinsics& cam) const {
  // Camera pixel (u, v) sees the seabed point p_c = ((u - cx) a / fx, (v - cy) a / fy) in the
  // camera's image axes; in the world it is R(yaw) p_c + t, in the raster origin + that / mpp.
  Eigen::Matrix2d a = pose.rotation() * Eigen::Vector2d(altitude_m / cam.fx, altitude_m / cam.fy).asDiagonal();
  a /= metres_per_px_;
  const Eigen::Vector2d b = worldToPixel(pose.translation()) - a * Eigen::Vector2d(cam.cx, cam.cy);
  return cv::Matx23d(a(0, 0), a(0, 1), b.x(), a(1, 0), a(1, 1), b.y());
}

cv::Mat SeabedWorld::render(const Pose2& pose, double altitude_m, const CameraIntrinsics& cam) const {
  const cv::Matx23d m = cameraToRaster(pose, altitude_m, cam);
  // Raster pixels per camera pixel; supersample so that each output pixel averages them.
  const double footprint_px = std::max(std::hypot(m(0, 0), m(1, 0)), std::hypot(m(0, 1), m(1, 1)));
  const int s = std::clamp(static_cast<int>(std::ceil(footprint_px - 1e-6)), 1, 4);
  cv::Mat out;
  if (s == 1) {
    cv::warpAffine(image_, out, m, cv::Size(cam.width, cam.height), cv::INTER_LINEAR | cv::WARP_INVERSE_MAP,
                   cv::BORDER_CONSTANT, cv::Scalar::all(0));
    return out;
  }
  // Supersampled pixel (us, vs) is camera pixel u = (us + 0.5) / s - 0.5.
  const double f = 1.0 / s, o = 0.5 * f - 0.5;
  const cv::Matx33d sub(f, 0, o, 0, f, o, 0, 0, 1);
  const cv::Matx33d m3(m(0, 0), m(0, 1), m(0, 2), m(1, 0), m(1, 1), m(1, 2), 0, 0, 1);
  const cv::Matx33d ms = m3 * sub;
  cv::Mat big;
  cv::warpAffine(image_, big, cv::Matx23d(ms(0, 0), ms(0, 1), ms(0, 2), ms(1, 0), ms(1, 1), ms(1, 2)),
                 cv::Size(cam.width * s, cam.height * s), cv::INTER_LINEAR | cv::WARP_INVERSE_MAP, cv::BORDER_CONSTANT,
                 cv::Scalar::all(0));
  cv::resize(big, out, cv::Size(cam.width, cam.height), 0, 0, cv::INTER_AREA);
  return out;
}

bool SeabedWorld::viewIsValid(const Pose2& pose, double altitude_m, const CameraIntrinsics& cam) const {
  const cv::Matx23d m = cameraToRaster(pose, altitude_m, cam);
  // The view's corners must be inside the raster (bilinear reads need one pixel of margin).
  for (const cv::Point2d c : {cv::Point2d(-0.5, -0.5), cv::Point2d(cam.width - 0.5, -0.5),
                              cv::Point2d(-0.5, cam.height - 0.5), cv::Point2d(cam.width - 0.5, cam.height - 0.5)}) {
    const double u = m(0, 0) * c.x + m(0, 1) * c.y + m(0, 2), v = m(1, 0) * c.x + m(1, 1) * c.y + m(1, 2);
    if (u < 1.0 || v < 1.0 || u > image_.cols - 2.0 || v > image_.rows - 2.0) return false;
  }
  if (valid_.empty()) return true;
  cv::Mat view;
  cv::warpAffine(valid_, view, m, cv::Size(cam.width, cam.height), cv::INTER_NEAREST | cv::WARP_INVERSE_MAP,
                 cv::BORDER_CONSTANT, cv::Scalar::all(0));
  return cv::countNonZero(view) == cam.width * cam.height;
}

}  // namespace core
}  // namespace uw_multislam
