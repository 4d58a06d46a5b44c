#include "uw_multislam/sim/water_model.h"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <sstream>

namespace uw_multislam {
namespace core {

namespace {

// Per-channel ratio of the attenuation coefficient (B, G, R): red attenuates fastest in water.
const Eigen::Vector3d kAttenuationRatio(0.7, 0.85, 1.5);

// Multiplicative light pattern V(u, v) (vignetting and the artificial light cone).
cv::Mat lightPattern(cv::Size size, const WaterOptions& o) {
  cv::Mat v(size, CV_32F);
  const double cx = (size.width - 1) / 2.0, cy = (size.height - 1) / 2.0;
  const double r_corner = std::hypot(cx, cy), diag = std::hypot(size.width, size.height);
  const double lx = cx + o.light_cone_offset.x() * size.width, ly = cy + o.light_cone_offset.y() * size.height;
  const double sigma = std::max(1e-6, o.light_cone_width * diag);
  for (int y = 0; y < size.height; ++y) {
    float* row = v.ptr<float>(y);
    for (int x = 0; x < size.width; ++x) {
      const double r = std::hypot(x - cx, y - cy) / r_corner;
      const double vignette = 1.0 - o.vignetting * std::pow(r, 4);
      const double d2 = (x - lx) * (x - lx) + (y - ly) * (y - ly);
      const double cone = 1.0 - o.light_cone * (1.0 - std::exp(-d2 / (2 * sigma * sigma)));
      row[x] = static_cast<float>(std::max(0.0, vignette * cone));
    }
  }
  return v;
}

cv::Mat threeChannels(const cv::Mat& single) {
  cv::Mat out;
  cv::merge(std::vector<cv::Mat>{single, single, single}, out);
  return out;
}

void motionBlur(cv::Mat& img, const Eigen::Vector2d& shift_px) {
  const double len = shift_px.norm();
  if (len < 1.0) return;
  const int k = 2 * static_cast<int>(std::ceil(len / 2)) + 1;
  cv::Mat kernel = cv::Mat::zeros(k, k, CV_32F);
  const Eigen::Vector2d d = shift_px / len;
  const cv::Point2d c(k / 2.0 - 0.5, k / 2.0 - 0.5);
  cv::line(kernel, cv::Point(cvRound(c.x - d.x() * len / 2), cvRound(c.y - d.y() * len / 2)),
           cv::Point(cvRound(c.x + d.x() * len / 2), cvRound(c.y + d.y() * len / 2)), cv::Scalar(1.0), 1, cv::LINE_AA);
  kernel /= cv::sum(kernel)[0];
  cv::filter2D(img, img, -1, kernel, cv::Point(-1, -1), 0, cv::BORDER_REFLECT);
}

void marineSnow(cv::Mat& img, double mean_count, cv::RNG& rng) {
  if (mean_count <= 0) return;
  // Poisson count via exponential gaps.
  int n = 0;
  for (double t = 0; (t += -std::log(std::max(1e-12, rng.uniform(0.0, 1.0)))) < mean_count;) ++n;
  cv::Mat layer = cv::Mat::zeros(img.size(), CV_32F);
  for (int i = 0; i < n; ++i) {
    // One draw per declarator, y first, as x86-64 took them (C++ leaves the order of a call's
    // arguments unspecified; aarch64 took x first and rendered other frames for the same seed).
    const int cy = rng.uniform(0, img.rows), cx = rng.uniform(0, img.cols);
    const cv::Point c(cx, cy);
    const bool near = rng.uniform(0.0, 1.0) < 0.15;  // close to the lens: large and defocused
    const int r = near ? rng.uniform(4, 10) : rng.uniform(1, 3);
    cv::circle(layer, c, r, cv::Scalar(near ? rng.uniform(0.15, 0.35) : rng.uniform(0.4, 0.9)), cv::FILLED,
               cv::LINE_AA);
  }
  cv::GaussianBlur(layer, layer, cv::Size(5, 5), 1.2);
  const cv::Mat a = threeChannels(layer);
  img = img + (cv::Scalar::all(1.0) - img).mul(a);
}

void occluder(cv::Mat& img, cv::RNG& rng) {
  // As in marineSnow: one draw per declarator, in the order x86-64 took them.
  const int cy = rng.uniform(img.rows / 3, 2 * img.rows / 3), cx = rng.uniform(img.cols / 3, 2 * img.cols / 3);
  const int ay = rng.uniform(img.rows / 2, img.rows), ax = rng.uniform(img.cols / 2, img.cols);
  const cv::Point c(cx, cy);
  const cv::Size axes(ax, ay);
  cv::ellipse(img, c, axes, rng.uniform(0.0, 180.0), 0, 360, cv::Scalar(0.05, 0.06, 0.05), cv::FILLED, cv::LINE_AA);
}

}  // namespace

std::string WaterOptions::validate() const {
  std::ostringstream os;
  if (!(illumination > 0 && illumination <= 4))
    os << "illumination " << illumination << " must be in (0, 4]";
  else if (!(colour_gain_bgr.minCoeff() >= 0 && colour_gain_bgr.maxCoeff() <= 4))
    os << "colour_gain_bgr must be in [0, 4]";
  else if (!(vignetting >= 0 && vignetting <= 1))
    os << "vignetting " << vignetting << " must be in [0, 1]";
  else if (!(light_cone >= 0 && light_cone <= 1))
    os << "light_cone " << light_cone << " must be in [0, 1]";
  else if (!(light_cone_width > 0))
    os << "light_cone_width must be positive";
  else if (!(turbidity_per_m >= 0 && turbidity_per_m <= 5))
    os << "turbidity_per_m " << turbidity_per_m << " must be in [0, 5]";
  else if (!(backscatter_bgr.minCoeff() >= 0 && backscatter_bgr.maxCoeff() <= 1))
    os << "backscatter_bgr must be in [0, 1]";
  else if (!(motion_blur_exposure_s >= 0 && motion_blur_exposure_s <= 1))
    os << "motion_blur_exposure_s must be in [0, 1]";
  else if (!(marine_snow_per_frame >= 0 && marine_snow_per_frame <= 5000))
    os << "marine_snow_per_frame must be in [0, 5000]";
  else if (!(noise_sigma >= 0 && noise_sigma <= 100))
    os << "noise_sigma must be in [0, 100]";
  for (const auto& s : stretches) {
    if (os.tellp() == 0 && (s.first_frame < 0 || s.num_frames <= 0)) {
      os << "a blank/occluded stretch needs first_frame >= 0 and num_frames > 0";
    }
  }
  return os.str();
}

const FrameStretch* WaterOptions::stretchAt(int frame) const {
  for (const auto& s : stretches) {
    if (frame >= s.first_frame && frame < s.first_frame + s.num_frames) return &s;
  }
  return nullptr;
}

cv::Mat applyWater(const cv::Mat& clean, const WaterOptions& o, const WaterFrame& f, cv::RNG& rng) {
  const FrameStretch* stretch = o.stretchAt(f.index);
  cv::Mat j;
  clean.convertTo(j, CV_32FC3, 1.0 / 255.0);
  const cv::Mat v3 = threeChannels(lightPattern(clean.size(), o));
  const Eigen::Vector3d gain = o.illumination * o.colour_gain_bgr;
  cv::multiply(j, cv::Scalar(gain[0], gain[1], gain[2]), j);
  j = j.mul(v3);
  if (stretch && stretch->kind == FrameStretch::Kind::kOccluded) occluder(j, rng);

  // Turbidity: transmission per channel over the light's path down and back.
  Eigen::Vector3d t;
  for (int k = 0; k < 3; ++k) t[k] = std::exp(-o.turbidity_per_m * kAttenuationRatio[k] * 2.0 * f.altitude_m);
  if (stretch && stretch->kind == FrameStretch::Kind::kBlank) t.setZero();
  cv::Mat veil;
  const Eigen::Vector3d b = o.illumination * o.backscatter_bgr.cwiseProduct(Eigen::Vector3d::Ones() - t);
  cv::multiply(v3, cv::Scalar(b[0], b[1], b[2]), veil);
  cv::multiply(j, cv::Scalar(t[0], t[1], t[2]), j);
  j += veil;

  motionBlur(j, f.image_velocity_px_s * o.motion_blur_exposure_s);
  marineSnow(j, o.marine_snow_per_frame, rng);
  if (o.noise_sigma > 0) {
    cv::Mat noise(j.size(), CV_32FC3);
    rng.fill(noise, cv::RNG::NORMAL, 0.0, o.noise_sigma / 255.0);
    j += noise;
  }
  cv::Mat out;
  j.convertTo(out, CV_8UC3, 255.0);  // saturates to [0, 255]
  return out;
}

}  // namespace core
}  // namespace uw_multislam
