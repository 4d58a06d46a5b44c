#include "uw_multislam/core/frontend/enhancement.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>
#include <utility>
#include <vector>

namespace uw_multislam {
namespace core {

namespace {

// Fraction of the pixels, brightest in the dark channel, that define the veiling light A.
constexpr double kVeilingLightFraction = 0.001;
// Floor on each channel of A, so that I / A (H3) never divides by zero (all-black frames).
constexpr double kMinVeilingLight = 1.0 / 255.0;
// Bins of the histogram that finds the stretch percentiles of the recovered radiance.
constexpr int kStretchBins = 1024;
// Below this range (intensities in [0, 1]) an image is constant and is not stretched.
constexpr double kMinStretchRange = 1e-6;

struct ModeName {
  EnhancementMode mode;
  const char* name;
};
constexpr ModeName kModeNames[] = {
    {EnhancementMode::kNone, "none"},
    {EnhancementMode::kClahe, "clahe"},
    {EnhancementMode::kDehaze, "dehaze"},
    {EnhancementMode::kDehazeClahe, "dehaze_clahe"},
};

bool usesClahe(EnhancementMode mode) {
  return mode == EnhancementMode::kClahe || mode == EnhancementMode::kDehazeClahe;
}

bool usesDehaze(EnhancementMode mode) {
  return mode == EnhancementMode::kDehaze || mode == EnhancementMode::kDehazeClahe;
}

void checkInput(const cv::Mat& image) {
  if (image.empty()) throw std::invalid_argument("image enhancement: empty image");
  if (image.type() != CV_8UC1 && image.type() != CV_8UC3) {
    throw std::invalid_argument("image enhancement: unsupported image type " + cv::typeToString(image.type()) +
                                " (expected CV_8UC1 grey or CV_8UC3 BGR)");
  }
}

cv::Mat toGrey(const cv::Mat& image) {
  if (image.channels() == 1) return image.clone();
  cv::Mat grey;
  cv::cvtColor(image, grey, cv::COLOR_BGR2GRAY);
  return grey;
}

}  // namespace

// Scratch of the per-pixel minimum over the channels, one per image depth so that no buffer
// changes type between calls (which would reallocate it).
struct ChannelMinScratch {
  std::vector<cv::Mat> channels;
  cv::Mat channel_min;
};

struct DehazeWorkspace {
  cv::Mat patch_kernel;                      // all-ones patch Ω for the min filter
  ChannelMinScratch scratch8, scratch32;     // 8-bit input, float I / A
  cv::Mat dark8, hist8, mask;                // veiling light
  cv::Mat image01, grey01;                   // input scaled to [0, 1] and its grey
  cv::Mat normalised, dark, t_raw, t;        // I / A, dark(I / A), t before and after refinement
  cv::Mat mean_i, mean_p, mean_ii, mean_ip;  // guided filter
  cv::Mat a, b, product;
  cv::Mat radiance, hist_stretch;  // recovered scene, its histogram for the stretch
};

namespace {

// (H2): minimum over the channels, then over the patch Ω (a min filter is an erosion), into
// `dark`. The default constant border of cv::erode leaves pixels outside the image out of the
// minimum.
void darkChannel(const cv::Mat& image, const cv::Mat& patch_kernel, ChannelMinScratch* scratch, cv::Mat* dark) {
  const cv::Mat* channel_min = &image;
  if (image.channels() > 1) {
    std::vector<cv::Mat>& channels = scratch->channels;
    cv::split(image, channels);
    cv::min(channels[0], channels[1], scratch->channel_min);
    for (size_t c = 2; c < channels.size(); ++c) cv::min(scratch->channel_min, channels[c], scratch->channel_min);
    channel_min = &scratch->channel_min;
  }
  cv::erode(*channel_min, *dark, patch_kernel);
}

// Veiling light A, per channel in [kMinVeilingLight, 1]: the mean colour of the pixels of the
// brightest 0.1 % of the 8-bit dark channel (He et al. take the brightest input pixel among
// them; the mean is less sensitive to noise and marine snow). Ties at the threshold are kept.
cv::Scalar veilingLight(const cv::Mat& image8, DehazeWorkspace* ws) {
  darkChannel(image8, ws->patch_kernel, &ws->scratch8, &ws->dark8);
  const int hist_size = 256;
  const float range[] = {0.0f, 256.0f};
  const float* ranges[] = {range};
  const int channel = 0;
  cv::calcHist(&ws->dark8, 1, &channel, cv::Mat(), ws->hist8, 1, &hist_size, ranges);
  const double wanted = std::max(1.0, std::ceil(kVeilingLightFraction * static_cast<double>(image8.total())));
  int threshold = hist_size - 1;
  for (double count = 0.0; threshold > 0; --threshold) {
    count += ws->hist8.at<float>(threshold);
    if (count >= wanted) break;
  }
  cv::compare(ws->dark8, threshold, ws->mask, cv::CMP_GE);
  cv::Scalar a = cv::mean(image8, ws->mask);
  for (int c = 0; c < image8.channels(); ++c) a[c] = std::max(a[c] / 255.0, kMinVeilingLight);
  return a;
}

// Box-filter guided filter (He, Sun & Tang, ECCV 2010, Algorithm 1) of `src` (CV_32FC1) with
// the guide ws->grey01, into `out` (not `src`): the output is locally a linear function of the
// guide, so the blocky patch transmission follows the image's edges.
void guidedFilter(const cv::Mat& src, int radius, double eps, DehazeWorkspace* ws, cv::Mat* out) {
  const cv::Size box(2 * radius + 1, 2 * radius + 1);
  const cv::Mat& guide = ws->grey01;
  cv::boxFilter(guide, ws->mean_i, CV_32F, box);
  cv::boxFilter(src, ws->mean_p, CV_32F, box);
  cv::multiply(guide, guide, ws->product);
  cv::boxFilter(ws->product, ws->mean_ii, CV_32F, box);
  cv::multiply(guide, src, ws->product);
  cv::boxFilter(ws->product, ws->mean_ip, CV_32F, box);
  // var(I) + eps into mean_ii, cov(I, p) into mean_ip.
  cv::multiply(ws->mean_i, ws->mean_i, ws->product);
  cv::subtract(ws->mean_ii, ws->product, ws->mean_ii);
  cv::add(ws->mean_ii, eps, ws->mean_ii);
  cv::multiply(ws->mean_i, ws->mean_p, ws->product);
  cv::subtract(ws->mean_ip, ws->product, ws->mean_ip);
  // a = cov / (var + eps), b = mean(p) - a mean(I); q = mean(a) I + mean(b).
  cv::divide(ws->mean_ip, ws->mean_ii, ws->a);
  cv::multiply(ws->a, ws->mean_i, ws->product);
  cv::subtract(ws->mean_p, ws->product, ws->b);
  cv::boxFilter(ws->a, ws->mean_i, CV_32F, box);
  cv::boxFilter(ws->b, ws->mean_p, CV_32F, box);
  cv::multiply(ws->mean_i, guide, *out);
  cv::add(*out, ws->mean_p, *out);
}

// Transmission (H3) into ws->t, refined by the guided filter and clamped to [t0, 1] for (H4).
void transmission(const cv::Scalar& a, const EnhancementOptions& options, DehazeWorkspace* ws) {
  cv::Scalar inverse_a;
  for (int c = 0; c < ws->image01.channels(); ++c) inverse_a[c] = 1.0 / a[c];
  cv::multiply(ws->image01, inverse_a, ws->normalised);
  darkChannel(ws->normalised, ws->patch_kernel, &ws->scratch32, &ws->dark);
  ws->dark.convertTo(ws->t_raw, CV_32F, -options.dehaze_omega, 1.0);  // t = 1 - ω dark(I / A)
  if (options.guided_filter_radius_px > 0) {
    guidedFilter(ws->t_raw, options.guided_filter_radius_px, options.guided_filter_eps, ws, &ws->t);
  } else {
    ws->t_raw.copyTo(ws->t);
  }
  cv::max(ws->t, options.dehaze_t0, ws->t);
  cv::min(ws->t, 1.0, ws->t);
}

// Index of the histogram bin in which the cumulative count first exceeds `fraction` of the
// pixels.
int percentileBin(const cv::Mat& hist, double fraction) {
  const double wanted = fraction * cv::sum(hist)[0];
  double count = 0.0;
  for (int i = 0; i < hist.rows; ++i) {
    count += hist.at<float>(i);
    if (count > wanted) return i;
  }
  return hist.rows - 1;
}

// Paper 003's contrast stretch: the low/high percentiles of `radiance` (CV_32FC1, any range)
// go to 0 and 255, values beyond them saturate. A constant image keeps its level.
cv::Mat stretchToGrey8(const cv::Mat& radiance, double low_percentile, double high_percentile, cv::Mat* hist) {
  double min_v = 0.0;
  double max_v = 0.0;
  cv::minMaxLoc(radiance, &min_v, &max_v);
  cv::Mat out;
  if (max_v - min_v < kMinStretchRange) {
    radiance.convertTo(out, CV_8U, 255.0);
    return out;
  }
  const double bin_width = (max_v - min_v) / kStretchBins;
  const float range[] = {static_cast<float>(min_v), static_cast<float>(max_v + bin_width)};
  const float* ranges[] = {range};
  const int channel = 0;
  const int bins = kStretchBins + 1;
  cv::calcHist(&radiance, 1, &channel, cv::Mat(), *hist, 1, &bins, ranges);
  // The low level is its bin's lower edge, the high level its bin's upper edge.
  double lo = min_v + bin_width * percentileBin(*hist, low_percentile / 100.0);
  double hi = min_v + bin_width * (percentileBin(*hist, high_percentile / 100.0) + 1);
  if (hi - lo < kMinStretchRange) {  // most pixels share one level: stretch the full range
    lo = min_v;
    hi = max_v;
  }
  const double scale = 255.0 / (hi - lo);
  radiance.convertTo(out, CV_8U, scale, -lo * scale);
  return out;
}

// Dark-channel-prior dehazing of an 8-bit BGR or grey image, then the contrast stretch, as grey.
cv::Mat dehazeToGrey(const cv::Mat& image, const EnhancementOptions& options, DehazeWorkspace* ws) {
  image.convertTo(ws->image01, CV_32F, 1.0 / 255.0);
  const cv::Scalar a = veilingLight(image, ws);
  double a_grey = a[0];
  if (image.channels() == 3) {
    cv::cvtColor(ws->image01, ws->grey01, cv::COLOR_BGR2GRAY);
    a_grey = 0.114 * a[0] + 0.587 * a[1] + 0.299 * a[2];  // the weights of COLOR_BGR2GRAY
  } else {
    ws->image01.copyTo(ws->grey01);
  }
  transmission(a, options, ws);
  // (H4) on the grey image: t is shared by the channels and the grey conversion is linear, so
  // grey(J) = (grey(I) - grey(A)) / t + grey(A) is exact and a third of the work.
  cv::subtract(ws->grey01, a_grey, ws->radiance);
  cv::divide(ws->radiance, ws->t, ws->radiance);
  cv::add(ws->radiance, a_grey, ws->radiance);
  return stretchToGrey8(ws->radiance, options.stretch_low_percentile, options.stretch_high_percentile,
                        &ws->hist_stretch);
}

}  // namespace

std::string enhancementName(EnhancementMode mode) {
  for (const auto& m : kModeNames) {
    if (m.mode == mode) return m.name;
  }
  return "unknown";
}

bool parseEnhancement(const std::string& name, EnhancementMode* mode) {
  if (mode == nullptr) return false;
  for (const auto& m : kModeNames) {
    if (name == m.name) {
      *mode = m.mode;
      return true;
    }
  }
  return false;
}

std::string EnhancementOptions::validate() const {
  std::ostringstream os;
  if (enhancementName(mode) == "unknown") {
    os << "enhancement mode " << static_cast<int>(mode) << " is not one of none, clahe, dehaze, dehaze_clahe";
  } else if (!(clahe_clip_limit > 0.0) || !std::isfinite(clahe_clip_limit)) {
    os << "clahe_clip_limit must be > 0, got " << clahe_clip_limit;
  } else if (clahe_tile_grid < 1 || clahe_tile_grid > 64) {
    os << "clahe_tile_grid must be in 1..64, got " << clahe_tile_grid;
  } else if (dark_channel_patch_px < 1 || dark_channel_patch_px > 255) {
    os << "dark_channel_patch_px must be in 1..255, got " << dark_channel_patch_px;
  } else if (!(dehaze_omega > 0.0 && dehaze_omega <= 1.0)) {
    os << "dehaze_omega must be in (0, 1], got " << dehaze_omega;
  } else if (!(dehaze_t0 > 0.0 && dehaze_t0 < 1.0)) {
    os << "dehaze_t0 must be in (0, 1), got " << dehaze_t0;
  } else if (guided_filter_radius_px < 0 || guided_filter_radius_px > 1000) {
    os << "guided_filter_radius_px must be in 0..1000, got " << guided_filter_radius_px;
  } else if (!(guided_filter_eps > 0.0) || !std::isfinite(guided_filter_eps)) {
    os << "guided_filter_eps must be > 0, got " << guided_filter_eps;
  } else if (!(stretch_low_percentile >= 0.0 && stretch_low_percentile < stretch_high_percentile &&
               stretch_high_percentile <= 100.0)) {
    os << "stretch percentiles must satisfy 0 <= low < high <= 100, got low " << stretch_low_percentile << " and high "
       << stretch_high_percentile;
  }
  return os.str();
}

FeatureImageEnhancer::FeatureImageEnhancer(const EnhancementOptions& options) : options_(options) {
  const std::string error = options_.validate();
  if (!error.empty()) throw std::invalid_argument("image enhancement options: " + error);
  if (usesClahe(options_.mode)) {
    clahe_ = cv::createCLAHE(options_.clahe_clip_limit, cv::Size(options_.clahe_tile_grid, options_.clahe_tile_grid));
  }
  if (usesDehaze(options_.mode)) {
    workspace_ = std::make_unique<DehazeWorkspace>();
    const int patch = options_.dark_channel_patch_px;
    workspace_->patch_kernel = cv::getStructuringElement(cv::MORPH_RECT, cv::Size(patch, patch));
  }
}

FeatureImageEnhancer::~FeatureImageEnhancer() = default;
FeatureImageEnhancer::FeatureImageEnhancer(FeatureImageEnhancer&&) noexcept = default;
// Written out, not "= default": GCC 9 refuses a defaulted noexcept whose implicit specification
// differs, and OpenCV before 4.6 does not declare cv::Ptr's move assignment noexcept (it is).
FeatureImageEnhancer& FeatureImageEnhancer::operator=(FeatureImageEnhancer&& other) noexcept {
  options_ = std::move(other.options_);
  clahe_ = std::move(other.clahe_);
  workspace_ = std::move(other.workspace_);
  return *this;
}

cv::Mat FeatureImageEnhancer::enhance(const cv::Mat& image) {
  checkInput(image);
  const cv::Mat grey = workspace_ ? dehazeToGrey(image, options_, workspace_.get()) : toGrey(image);
  if (!clahe_) return grey;
  cv::Mat out;
  clahe_->apply(grey, out);
  return out;
}

cv::Mat enhanceForFeatures(const cv::Mat& image, const EnhancementOptions& options) {
  return FeatureImageEnhancer(options).enhance(image);
}

}  // namespace core
}  // namespace uw_multislam
