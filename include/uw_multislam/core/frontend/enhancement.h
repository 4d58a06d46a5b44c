// Optional image enhancement before SIFT feature extraction.
//
// Turbid water lowers contrast and adds a veiling light (backscatter), so fewer and weaker
// features are found. Paper 003 (UW-SLAM, §3) enhances every frame before feature detection with
// the dark-channel-prior haze removal of He, Sun & Tang (its ref. [33]) "followed by a contrast
// stretching". Paper 003 itself gives no equations for this step (its (1)-(5) are projection and
// pose), so the code cites He et al.'s model by the labels below:
//   (H1) haze model    I(x) = J(x) t(x) + A (1 - t(x))
//   (H2) dark channel  dark(J)(x) = min_{y in Ω(x)} min_c J_c(y), close to 0 for a clear scene
//   (H3) transmission  t(x) = 1 - ω dark(I / A)(x)
//   (H4) recovery      J(x) = (I(x) - A) / max(t(x), t0) + A
// A (the veiling light) is estimated from the brightest 0.1 % of dark(I), and t is refined by
// the guided filter (He, Sun & Tang, "Guided Image Filtering", ECCV 2010) instead of the soft
// matting of the 2009 paper. CLAHE (contrast-limited adaptive histogram equalisation) is offered
// as the cheaper alternative and as a stage after dehazing.
//
// The output is always the 8-bit grey image SIFT consumes, of the input's size.
#pragma once

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include <memory>
#include <string>

namespace uw_multislam {
namespace core {

enum class EnhancementMode {
  kNone,         // grey conversion only
  kClahe,        // CLAHE on the grey image
  kDehaze,       // dark-channel-prior dehazing + percentile contrast stretch (paper 003 §3)
  kDehazeClahe,  // kDehaze, then CLAHE
};

/// "none", "clahe", "dehaze", "dehaze_clahe".
std::string enhancementName(EnhancementMode mode);
/// Parses one of the names above (exact, lower case). Returns false and leaves *mode unchanged
/// for any other string or a null `mode`.
bool parseEnhancement(const std::string& name, EnhancementMode* mode);

struct EnhancementOptions {
  EnhancementMode mode = EnhancementMode::kNone;

  // --- CLAHE (kClahe, kDehazeClahe) ---
  double clahe_clip_limit = 2.0;  // histogram clip limit per tile, > 0 (OpenCV's unit: multiples of the mean bin)
  int clahe_tile_grid = 8;        // tiles per image side, 1..64

  // --- dark-channel-prior dehazing (kDehaze, kDehazeClahe) ---
  int dark_channel_patch_px = 15;         // side of the square patch Ω of the min filter (He: 15 px), >= 1
  double dehaze_omega = 0.95;             // ω in (0, 1]: haze kept for depth perception (He: 0.95)
  double dehaze_t0 = 0.1;                 // lower bound t0 on the transmission, in (0, 1) (He: 0.1)
  int guided_filter_radius_px = 20;       // radius r of the guided filter refining t (box of 2r+1); 0 = no refinement
  double guided_filter_eps = 1e-3;        // guided filter regulariser ε (intensities in [0, 1]), > 0
  double stretch_low_percentile = 0.5;    // grey level mapped to 0 after dehazing, percent of pixels
  double stretch_high_percentile = 99.5;  // grey level mapped to 255; 0 <= low < high <= 100

  /// Empty when usable, else a sentence naming the bad value. Every field is checked,
  /// whichever mode is selected.
  std::string validate() const;
};

/// Scratch images of the dehazing, kept between frames (defined in enhancement.cpp).
struct DehazeWorkspace;

/// Turns camera frames into SIFT input. Holds the CLAHE object and the dehazing scratch images,
/// so that a stream of same-sized frames allocates only the returned image: fresh large
/// allocations cost page faults, which measured as half the dehazing time at 680x512.
/// Movable, not copyable. Not thread-safe (the scratch images and cv::CLAHE's buffers are
/// shared between calls): use one enhancer per thread.
class FeatureImageEnhancer {
 public:
  /// Throws std::invalid_argument with validate()'s message when the options are bad.
  explicit FeatureImageEnhancer(const EnhancementOptions& options);
  ~FeatureImageEnhancer();
  FeatureImageEnhancer(FeatureImageEnhancer&&) noexcept;
  FeatureImageEnhancer& operator=(FeatureImageEnhancer&&) noexcept;

  /// `image`: 8-bit BGR (CV_8UC3) or grey (CV_8UC1). Returns a new CV_8UC1 image of the same
  /// size (never sharing the input's or the enhancer's memory). Throws std::invalid_argument on
  /// an empty image or any other type (named in the message). A constant image gives a
  /// constant image.
  cv::Mat enhance(const cv::Mat& image);

  const EnhancementOptions& options() const { return options_; }

 private:
  EnhancementOptions options_;
  cv::Ptr<cv::CLAHE> clahe_;                    // null unless the mode uses CLAHE
  std::unique_ptr<DehazeWorkspace> workspace_;  // null unless the mode dehazes
};

/// Convenience: FeatureImageEnhancer(options).enhance(image). Builds the CLAHE object and the
/// scratch images on every call; keep a FeatureImageEnhancer for a stream of frames.
cv::Mat enhanceForFeatures(const cv::Mat& image, const EnhancementOptions& options);

}  // namespace core
}  // namespace uw_multislam
