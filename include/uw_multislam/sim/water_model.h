// Water and light for the survey generator, applied to a clean rendered view, per session.
//
// Image formation, in this order (values in [0, 1] per BGR channel):
//   1. light:     J' = J * illumination * colour_gain * V(u, v), where V combines vignetting
//                 (1 - vignetting * (r / r_corner)^4) and an artificial light cone (a Gaussian
//                 spot of width light_cone_width times the image diagonal, offset by
//                 light_cone_offset; V = 1 - light_cone * (1 - spot)).
//   2. turbidity: I = J' * T + B * (1 - T), T = exp(-c_k * 2 * altitude) per channel with
//                 c_k = turbidity_per_m * (0.7, 0.85, 1.5) for (B, G, R): red is lost first, and
//                 the light travels down and back. B is the backscatter (veiling light) colour
//                 times the illumination and V.
//   3. motion blur along the image-plane motion over the exposure time.
//   4. marine snow: bright, soft particles in front of the camera (not on the seabed, so
//      they do not move with it).
//   5. sensor noise: Gaussian, noise_sigma grey levels.
// Frames inside a blank stretch show only backscatter (lost sight of the bottom, lamp
// failure); inside an occluded stretch a dark object covers most of the view.
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include <string>
#include <vector>

namespace uw_multislam {
namespace core {

struct FrameStretch {
  enum class Kind { kBlank, kOccluded };
  int first_frame = 0;
  int num_frames = 0;
  Kind kind = Kind::kBlank;
};

struct WaterOptions {
  double illumination = 1.0;  // overall gain (dimmer < 1)
  Eigen::Vector3d colour_gain_bgr = Eigen::Vector3d::Ones();
  double vignetting = 0.15;                                        // brightness lost in the corners, 0..1
  double light_cone = 0.0;                                         // strength of the artificial light falloff, 0..1
  double light_cone_width = 0.45;                                  // spot sigma as a fraction of the image diagonal
  Eigen::Vector2d light_cone_offset = Eigen::Vector2d(0.0, -0.1);  // spot centre offset, fraction of width/height
  double turbidity_per_m = 0.02;                                   // attenuation coefficient c (1/m)
  Eigen::Vector3d backscatter_bgr = Eigen::Vector3d(0.45, 0.40, 0.15);  // veiling light colour, 0..1
  double motion_blur_exposure_s = 0.0;                                  // exposure time for motion blur
  double marine_snow_per_frame = 0.0;                                   // mean number of particles
  double noise_sigma = 1.5;                                             // grey levels (0..255 scale)
  std::vector<FrameStretch> stretches;                                  // blank / occluded frame ranges

  /// Empty when usable, else a sentence naming the bad value.
  std::string validate() const;
  /// The stretch containing `frame`, or nullptr.
  const FrameStretch* stretchAt(int frame) const;
};

/// What the water model needs to know about one frame.
struct WaterFrame {
  int index = 0;
  double altitude_m = 2.5;
  /// Motion of the seabed in the image during the exposure, pixels per second.
  Eigen::Vector2d image_velocity_px_s = Eigen::Vector2d::Zero();
};

/// Applies the water and light model to a clean BGR 8-bit view. `rng` drives snow, noise and
/// occluders; seed it per frame for reproducible output.
cv::Mat applyWater(const cv::Mat& clean, const WaterOptions& options, const WaterFrame& frame, cv::RNG& rng);

}  // namespace core
}  // namespace uw_multislam
