// Image enhancement before feature extraction: output type, what each mode does to synthetic
// hazy and low-contrast images, degenerate inputs and option checks.
#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "uw_multislam/core/frontend/enhancement.h"

namespace uw_multislam {
namespace core {
namespace {

const std::vector<EnhancementMode> kAllModes = {EnhancementMode::kNone, EnhancementMode::kClahe,
                                                EnhancementMode::kDehaze, EnhancementMode::kDehazeClahe};

EnhancementOptions optionsFor(EnhancementMode mode) {
  EnhancementOptions o;
  o.mode = mode;
  return o;
}

// Seabed-like texture in [0, 1] (CV_32FC1): blurred noise, stretched to the full range.
cv::Mat texture(cv::Size size, int seed) {
  cv::Mat noise(size, CV_32F);
  cv::RNG rng(seed);
  rng.fill(noise, cv::RNG::UNIFORM, 0.0, 1.0);
  cv::GaussianBlur(noise, noise, cv::Size(0, 0), 2.0);
  cv::normalize(noise, noise, 0.0, 1.0, cv::NORM_MINMAX);
  return noise;
}

// A clear scene J (CV_32FC3, BGR in [0, 1]) of slightly different channel gains.
cv::Mat clearScene(cv::Size size) {
  const cv::Mat t = texture(size, 7);
  std::vector<cv::Mat> bgr = {0.85 * t + 0.05, 0.9 * t + 0.05, 0.7 * t + 0.03};
  cv::Mat scene;
  cv::merge(bgr, scene);
  return scene;
}

// The haze model I = J t + A (1 - t) with a bright bluish veiling light A, quantised to 8 bits.
// `transmission` is CV_32FC1.
cv::Mat haze(const cv::Mat& scene, const cv::Mat& transmission) {
  const cv::Scalar veil(0.95, 0.85, 0.55);  // BGR
  cv::Mat t3;
  cv::merge(std::vector<cv::Mat>(3, transmission), t3);
  cv::Mat ones(scene.size(), CV_32FC3, cv::Scalar::all(1.0));
  cv::Mat veil_img(scene.size(), CV_32FC3, veil);
  const cv::Mat hazy = scene.mul(t3) + veil_img.mul(ones - t3);
  cv::Mat out;
  hazy.convertTo(out, CV_8U, 255.0);
  return out;
}

cv::Mat to8(const cv::Mat& image01) {
  cv::Mat out;
  image01.convertTo(out, CV_8U, 255.0);
  return out;
}

cv::Mat grey(const cv::Mat& bgr8) {
  cv::Mat out;
  cv::cvtColor(bgr8, out, cv::COLOR_BGR2GRAY);
  return out;
}

double meanAbsError(const cv::Mat& a, const cv::Mat& b) { return cv::norm(a, b, cv::NORM_L1) / a.total(); }

// The contrast stretch written independently of the library: the `low`/`high` percentiles of
// an 8-bit grey image go to 0 and 255. What a perfect dehazing of a scene followed by the
// stretch would give.
cv::Mat stretchedReference(const cv::Mat& grey8, double low, double high) {
  std::vector<uchar> v(grey8.begin<uchar>(), grey8.end<uchar>());
  std::sort(v.begin(), v.end());
  const double lo = v[static_cast<size_t>(low / 100.0 * (v.size() - 1))];
  const double hi = v[static_cast<size_t>(high / 100.0 * (v.size() - 1))];
  cv::Mat out;
  grey8.convertTo(out, CV_8U, 255.0 / (hi - lo), -lo * 255.0 / (hi - lo));
  return out;
}

double stdDev(const cv::Mat& image) {
  cv::Scalar mean, stddev;
  cv::meanStdDev(image, mean, stddev);
  return stddev[0];
}

double laplacianStdDev(const cv::Mat& grey8) {
  cv::Mat lap;
  cv::Laplacian(grey8, lap, CV_32F);
  return stdDev(lap);
}

double correlation(const cv::Mat& a, const cv::Mat& b) {
  cv::Mat fa, fb;
  a.convertTo(fa, CV_64F);
  b.convertTo(fb, CV_64F);
  fa -= cv::mean(fa)[0];
  fb -= cv::mean(fb)[0];
  return fa.dot(fb) / (cv::norm(fa) * cv::norm(fb));
}

bool isConstant(const cv::Mat& image) {
  double lo = 0.0, hi = 0.0;
  cv::minMaxLoc(image, &lo, &hi);
  return lo == hi;
}

// Expects `f` to throw std::invalid_argument whose message contains `needle`.
template <typename F>
void expectInvalid(F f, const std::string& needle) {
  try {
    f();
    FAIL() << "no exception, expected one containing '" << needle << "'";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
  }
}

// ---------------------------------------------------------------------------------------------
// Names and options.

TEST(EnhancementNames, RoundTrip) {
  for (EnhancementMode m : kAllModes) {
    EnhancementMode parsed = m == EnhancementMode::kNone ? EnhancementMode::kClahe : EnhancementMode::kNone;
    ASSERT_TRUE(parseEnhancement(enhancementName(m), &parsed)) << enhancementName(m);
    EXPECT_EQ(parsed, m);
  }
  EXPECT_EQ(enhancementName(EnhancementMode::kDehazeClahe), "dehaze_clahe");
}

TEST(EnhancementNames, RejectsUnknownNamesAndKeepsTheMode) {
  for (const std::string bad : {"", "Dehaze", "haze", "clahe ", "dehaze-clahe"}) {
    EnhancementMode m = EnhancementMode::kClahe;
    EXPECT_FALSE(parseEnhancement(bad, &m)) << "'" << bad << "'";
    EXPECT_EQ(m, EnhancementMode::kClahe);
  }
  EXPECT_FALSE(parseEnhancement("none", nullptr));
}

TEST(EnhancementOptions, DefaultsAreValidAndModeIsNone) {
  const EnhancementOptions o;
  EXPECT_EQ(o.validate(), "");
  EXPECT_EQ(o.mode, EnhancementMode::kNone);
}

TEST(EnhancementOptions, ValidateNamesTheBadValue) {
  struct Case {
    const char* field;
    void (*set)(EnhancementOptions*);
  };
  const std::vector<Case> cases = {
      {"clahe_clip_limit", [](EnhancementOptions* o) { o->clahe_clip_limit = -1.0; }},
      {"clahe_clip_limit", [](EnhancementOptions* o) { o->clahe_clip_limit = 0.0; }},
      {"clahe_clip_limit", [](EnhancementOptions* o) { o->clahe_clip_limit = std::nan(""); }},
      {"clahe_tile_grid", [](EnhancementOptions* o) { o->clahe_tile_grid = 0; }},
      {"dark_channel_patch_px", [](EnhancementOptions* o) { o->dark_channel_patch_px = 0; }},
      {"dehaze_omega", [](EnhancementOptions* o) { o->dehaze_omega = 0.0; }},
      {"dehaze_omega", [](EnhancementOptions* o) { o->dehaze_omega = 1.01; }},
      {"dehaze_t0", [](EnhancementOptions* o) { o->dehaze_t0 = 0.0; }},
      {"dehaze_t0", [](EnhancementOptions* o) { o->dehaze_t0 = 1.0; }},
      {"guided_filter_radius_px", [](EnhancementOptions* o) { o->guided_filter_radius_px = -1; }},
      {"guided_filter_eps", [](EnhancementOptions* o) { o->guided_filter_eps = 0.0; }},
      {"percentiles", [](EnhancementOptions* o) { o->stretch_low_percentile = 99.6; }},  // above high 99.5
      {"percentiles", [](EnhancementOptions* o) { o->stretch_high_percentile = 0.2; }},  // below low 0.5
      {"percentiles", [](EnhancementOptions* o) { o->stretch_low_percentile = -1.0; }},
      {"percentiles", [](EnhancementOptions* o) { o->stretch_high_percentile = 100.5; }},
      {"percentiles", [](EnhancementOptions* o) { o->stretch_low_percentile = o->stretch_high_percentile; }},
      {"mode", [](EnhancementOptions* o) { o->mode = static_cast<EnhancementMode>(17); }},
  };
  for (const Case& c : cases) {
    EnhancementOptions o;
    c.set(&o);
    const std::string error = o.validate();
    EXPECT_NE(error.find(c.field), std::string::npos) << c.field << ": '" << error << "'";
  }
  EnhancementOptions edge;
  edge.dehaze_omega = 1.0;
  edge.stretch_low_percentile = 0.0;
  edge.stretch_high_percentile = 100.0;
  edge.guided_filter_radius_px = 0;
  EXPECT_EQ(edge.validate(), "");
}

TEST(EnhancementOptions, EnhancerAndFreeFunctionRejectBadOptions) {
  EnhancementOptions o = optionsFor(EnhancementMode::kClahe);
  o.clahe_clip_limit = -2.0;
  expectInvalid([&] { FeatureImageEnhancer e(o); }, "clahe_clip_limit");
  const cv::Mat image(8, 8, CV_8UC1, cv::Scalar(10));
  expectInvalid([&] { enhanceForFeatures(image, o); }, "clahe_clip_limit");
}

// ---------------------------------------------------------------------------------------------
// Output type and size, bad inputs.

class EnhancementModeTest : public ::testing::TestWithParam<EnhancementMode> {};

TEST_P(EnhancementModeTest, GreySameSizeForBgrAndGreyInputOfAnySize) {
  FeatureImageEnhancer enhancer(optionsFor(GetParam()));
  const std::vector<cv::Size> sizes = {{320, 240}, {680, 512}, {3, 3}, {1, 1}, {17, 2}, {2, 17}};
  for (const cv::Size& size : sizes) {
    const cv::Mat bgr = haze(clearScene(size), cv::Mat(size, CV_32F, cv::Scalar(0.4)));
    for (const cv::Mat& input : {bgr, grey(bgr)}) {
      const cv::Mat out = enhancer.enhance(input);
      EXPECT_EQ(out.type(), CV_8UC1) << size << " channels " << input.channels();
      EXPECT_EQ(out.size(), size) << " channels " << input.channels();
    }
  }
}

TEST_P(EnhancementModeTest, ConstantImagesGiveConstantImages) {
  FeatureImageEnhancer enhancer(optionsFor(GetParam()));
  const std::vector<cv::Scalar> colours = {cv::Scalar::all(0), cv::Scalar::all(255), cv::Scalar::all(128),
                                           cv::Scalar(200, 120, 30)};
  for (const cv::Size& size : {cv::Size(64, 48), cv::Size(3, 3)}) {
    for (const cv::Scalar& colour : colours) {
      const cv::Mat bgr(size, CV_8UC3, colour);
      for (const cv::Mat& input : {bgr, grey(bgr)}) {
        const cv::Mat out = enhancer.enhance(input);
        ASSERT_EQ(out.type(), CV_8UC1);
        EXPECT_TRUE(isConstant(out)) << colour << " " << size << " channels " << input.channels();
        if (GetParam() == EnhancementMode::kNone || GetParam() == EnhancementMode::kDehaze) {
          // Nothing to stretch: the level is kept (within the rounding of the grey conversion).
          EXPECT_NEAR(out.at<uchar>(0, 0), grey(bgr).at<uchar>(0, 0), 1.0) << colour;
        }
      }
    }
  }
}

TEST_P(EnhancementModeTest, EmptyAndWrongTypesThrowWithTheTypeNamed) {
  FeatureImageEnhancer enhancer(optionsFor(GetParam()));
  expectInvalid([&] { enhancer.enhance(cv::Mat()); }, "empty image");
  expectInvalid([&] { enhanceForFeatures(cv::Mat(0, 5, CV_8UC3), optionsFor(GetParam())); }, "empty image");
  for (int type : {CV_16UC1, CV_16UC3, CV_32FC1, CV_32FC3, CV_64FC1, CV_8UC4, CV_8UC2, CV_8SC1}) {
    const cv::Mat image(4, 4, type, cv::Scalar::all(1));
    expectInvalid([&] { enhancer.enhance(image); }, cv::typeToString(type));
  }
}

TEST_P(EnhancementModeTest, EnhancerReuseMatchesTheFreeFunction) {
  FeatureImageEnhancer enhancer(optionsFor(GetParam()));
  std::vector<cv::Mat> kept, expected;
  for (int seed : {1, 2, 3, 4}) {
    const cv::Size size(seed <= 2 ? 112 : 144, 64);  // two of a size, then two of another
    const cv::Mat input = to8(texture(size, seed) * 0.3 + 0.3);
    expected.push_back(enhanceForFeatures(input, optionsFor(GetParam())).clone());
    kept.push_back(enhancer.enhance(input));
    EXPECT_EQ(cv::norm(kept.back(), expected.back(), cv::NORM_INF), 0.0) << seed;
  }
  // Earlier results must not share the enhancer's scratch memory.
  for (size_t i = 0; i < kept.size(); ++i) EXPECT_EQ(cv::norm(kept[i], expected[i], cv::NORM_INF), 0.0) << i;
  FeatureImageEnhancer moved(std::move(enhancer));
  const cv::Mat input = to8(texture({80, 60}, 9) * 0.3 + 0.3);
  EXPECT_EQ(cv::norm(moved.enhance(input), enhanceForFeatures(input, optionsFor(GetParam())), cv::NORM_INF), 0.0);
}

INSTANTIATE_TEST_SUITE_P(AllModes, EnhancementModeTest, ::testing::ValuesIn(kAllModes),
                         [](const ::testing::TestParamInfo<EnhancementMode>& info) {
                           return enhancementName(info.param);
                         });

// ---------------------------------------------------------------------------------------------
// What the modes do.

TEST(Enhancement, NoneIsThePlainGreyConversion) {
  const cv::Mat bgr = haze(clearScene({160, 120}), cv::Mat(120, 160, CV_32F, cv::Scalar(0.6)));
  const EnhancementOptions none = optionsFor(EnhancementMode::kNone);
  EXPECT_EQ(cv::norm(enhanceForFeatures(bgr, none), grey(bgr), cv::NORM_INF), 0.0);
  const cv::Mat g = grey(bgr);
  const cv::Mat out = enhanceForFeatures(g, none);
  EXPECT_EQ(cv::norm(out, g, cv::NORM_INF), 0.0);
  EXPECT_NE(out.data, g.data) << "the output must not alias the caller's image";
}

TEST(Enhancement, ClaheRaisesLocalContrastOfALowContrastImage) {
  const cv::Mat flat = to8(texture({320, 240}, 3) * 0.12 + 0.42);  // about 107..138
  const cv::Mat out = enhanceForFeatures(flat, optionsFor(EnhancementMode::kClahe));
  EXPECT_GT(stdDev(out), 1.5 * stdDev(flat));
  EXPECT_GT(laplacianStdDev(out), 1.5 * laplacianStdDev(flat));
  EXPECT_GT(correlation(out, flat), 0.8) << "the structure must be kept";
}

TEST(Enhancement, DehazeRecoversAUniformlyHazyScene) {
  const cv::Size size(320, 240);
  const cv::Mat scene = clearScene(size);
  const cv::Mat clear_grey = grey(to8(scene));
  const cv::Mat hazy = haze(scene, cv::Mat(size, CV_32F, cv::Scalar(0.4)));
  for (const cv::Mat& input : {hazy, grey(hazy)}) {
    const cv::Mat out = enhanceForFeatures(input, optionsFor(EnhancementMode::kDehaze));
    const double hazy_error = meanAbsError(grey(hazy), clear_grey);
    const double dehazed_error = meanAbsError(out, clear_grey);
    EXPECT_LT(dehazed_error, 0.5 * hazy_error) << "channels " << input.channels();
    EXPECT_GT(stdDev(out), 2.0 * stdDev(grey(hazy))) << "channels " << input.channels();
    EXPECT_GT(correlation(out, clear_grey), 0.98) << "channels " << input.channels();
    double lo = 0.0, hi = 0.0;
    cv::minMaxLoc(out, &lo, &hi);
    EXPECT_LE(lo, 5.0) << "the stretch maps the low percentile to 0";
    EXPECT_GE(hi, 250.0) << "the stretch maps the high percentile to 255";
  }
}

TEST(Enhancement, DehazeUndoesUnevenHaze) {
  // Haze thickening from left (t = 0.8) to right (t = 0.2): the hazy grey image is no longer an
  // affine function of the scene, so neither the correlation nor a contrast stretch alone can
  // undo it; only a per-pixel transmission can.
  const cv::Size size(320, 240);
  const cv::Mat scene = clearScene(size);
  const cv::Mat clear_grey = grey(to8(scene));
  cv::Mat ramp(1, size.width, CV_32F);
  for (int u = 0; u < size.width; ++u) ramp.at<float>(u) = 0.8f - 0.6f * u / (size.width - 1);
  const cv::Mat hazy = haze(scene, cv::repeat(ramp, size.height, 1));
  const cv::Mat out = enhanceForFeatures(hazy, optionsFor(EnhancementMode::kDehaze));
  const double hazy_corr = correlation(grey(hazy), clear_grey);
  EXPECT_GT(correlation(out, clear_grey), hazy_corr + 0.1) << "hazy correlation " << hazy_corr;
  const cv::Mat ideal = stretchedReference(clear_grey, 0.5, 99.5);
  const double stretch_only_error = meanAbsError(stretchedReference(grey(hazy), 0.5, 99.5), ideal);
  EXPECT_LT(meanAbsError(out, ideal), 0.75 * stretch_only_error);
}

TEST(Enhancement, DehazeThenClaheAddsLocalContrast) {
  const cv::Size size(320, 240);
  const cv::Mat hazy = haze(clearScene(size), cv::Mat(size, CV_32F, cv::Scalar(0.3)));
  const cv::Mat dehazed = enhanceForFeatures(hazy, optionsFor(EnhancementMode::kDehaze));
  const cv::Mat both = enhanceForFeatures(hazy, optionsFor(EnhancementMode::kDehazeClahe));
  EXPECT_GT(laplacianStdDev(dehazed), 2.0 * laplacianStdDev(grey(hazy)));
  EXPECT_NE(cv::norm(both, dehazed, cv::NORM_INF), 0.0) << "CLAHE must act after dehazing";
  EXPECT_GT(correlation(both, dehazed), 0.8);
}

TEST(Enhancement, GuidedFilterRemovesPatchArtifacts) {
  // Without refinement the transmission is blocky (constant over each patch's minimum), which
  // leaves patch-sized errors in the recovered scene; the guided filter makes it follow the image.
  const cv::Size size(320, 240);
  const cv::Mat clear_grey = grey(to8(clearScene(size)));
  const cv::Mat hazy = haze(clearScene(size), cv::Mat(size, CV_32F, cv::Scalar(0.4)));
  const cv::Mat ideal = stretchedReference(clear_grey, 0.5, 99.5);
  EnhancementOptions raw = optionsFor(EnhancementMode::kDehaze);
  raw.guided_filter_radius_px = 0;
  const cv::Mat unrefined = enhanceForFeatures(hazy, raw);
  const cv::Mat refined = enhanceForFeatures(hazy, optionsFor(EnhancementMode::kDehaze));
  EXPECT_LT(meanAbsError(refined, ideal), 0.75 * meanAbsError(unrefined, ideal));
  EXPECT_LT(meanAbsError(unrefined, clear_grey), 0.6 * meanAbsError(grey(hazy), clear_grey))
      << "even unrefined, dehazing must help";
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
