// The SLAM configuration's loader refuses, by key, the values a fuzzing pass over every key of
// config/slam.yaml found taken silently or crashing the run (2026-11-26): infinities, values past
// what any setting means (a SIFT sigma of 1000 built kernels for minutes, 2^31 as KLT border
// crashed OpenCV, 1e308 as a sigma overflowed a covariance), limits no frame can meet, and files
// whose extra content was ignored.
#include <gtest/gtest.h>

#include <string>
#include <utility>
#include <vector>

#include "uw_multislam/core/session/slam_config.h"

using uw_multislam::core::SlamConfig;
using uw_multislam::core::slamConfigFromYaml;
using uw_multislam::core::slamConfigToYaml;

namespace {

std::string refusal(const std::string& yaml) {
  try {
    slamConfigFromYaml(yaml);
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "(accepted)";
}

}  // namespace

TEST(SlamConfig, RefusesValuesThatCrashOrSilentlyRuinTheRunByKey) {
  for (const auto& [yaml, words] : std::vector<std::pair<std::string, std::string>>{
           // Crashes and hangs.
           {"odometry: {klt: {enabled: true, border_px: 2147483647}}",
            "odometry.klt: border_px 2147483647 must be in [0, 1000]"},
           {"odometry: {klt: {corner_min_distance_px: 1e308}}", "corner_min_distance_px 1e+308 must be in [0, 1000]"},
           {"odometry: {features: {sigma: 1000}}", "odometry.features: sigma 1000 must be in (0, 10]"},
           {"odometry: {features: {octave_layers: 100000}}", "octave_layers 100000 must be in [1, 10]"},
           // A covariance that overflows (the run ended at the first fallback or nav motion).
           {"odometry: {fallback: {min_sigma_m: 1e308}}", "odometry.fallback: min_sigma_m must be in (0, 1000]"},
           {"odometry: {ransac: {min_noise_px: 1e308}}", "odometry.ransac: min_noise_px 1e+308 must be in [0, 100]"},
           {"nav: {inflation: 1e308}", "nav.inflation 1e+308 must be in [1, 1e6]"},
           {"nav: {min_sigma_m: 1e154}", "nav.min_sigma_m must be in (0, 1000]"},
           // Runs that did nothing, without a word.
           {"odometry: {features: {edge_threshold: 1e308}}", "edge_threshold 1e+308 must be in (1, 1000]"},
           {"odometry: {ransac: {inlier_threshold_px: 1000}}", "inlier_threshold_px 1000 must be in (0, 100]"},
           {"tracking: {min_features: 501}",
            "tracking.min_features 501 is more than odometry.features.num_features 500"},
           {"odometry: {ransac: {min_inliers: 501}}",
            "odometry.ransac: min_inliers 501 is more than features.num_features 500"},
           {"backend: {sparse: {function_tolerance: 1}}", "backend.sparse.function_tolerance must be in (0, 1)"},
           {"loops: {local: {min_inliers: 2147483647}}",
            "loops.local.min_inliers 2147483647 is more than odometry.features.num_features 500"},
           {"loops: {global: {min_inliers: 501}}", "loops.global.min_inliers 501 is more than"},
           // Infinity where 0 is "off": refused for every number, with the key.
           {"odometry: {keyframes: {max_rotation_rad: .inf}}",
            "bad value for 'max_rotation_rad' (not a finite number)"},
           {"loops: {local: {max_radius_m: -.inf}}", "bad value for 'max_radius_m' (not a finite number)"},
           // Messages naming the key as the file spells it.
           {"backend: {iekf: {max_iterations: 0}}", "backend.iekf.max_iterations must be >= 1"},
           {"backend: {sparse: {max_iterations: 0}}", "backend.sparse.max_iterations must be >= 1"},
           {"backend: {consistency: {confidence: 0.2}}", "backend.consistency.confidence must be in (0.5, 1)"},
           {"backend: {iekf: {max_keyframes: 1}}", "backend.iekf.max_keyframes must be >= 2"},
           {"odometry: {features: {grid_cols: 0}}", "odometry.features: grid_rows 4 x grid_cols 0 must be"},
           // Files: a second document was ignored, a list as a key said only "bad conversion".
           {"odometry: {max_altitude_m: 50}\n---\nodometry: {max_altitude_m: 100}\n", "2 documents"},
           {"? [a, b]\n: 1\n", "config: a key that is not a word"},
       }) {
    const std::string why = refusal(yaml);
    EXPECT_NE(why.find(words), std::string::npos) << yaml << "\n  gave: " << why;
  }
}

TEST(SlamConfig, TheBoundsThemselvesAreAcceptedAndRoundTrip) {
  const SlamConfig c = slamConfigFromYaml(
      "odometry:\n"
      "  features: {sigma: 10, octave_layers: 10, edge_threshold: 1000, border_px: 1000}\n"
      "  klt: {border_px: 1000, corner_min_distance_px: 1000}\n"
      "  fallback: {min_sigma_m: 1000, relative_sigma: 1000, sigma_yaw_rad: 10}\n"
      "  ransac: {inlier_threshold_px: 100, min_noise_px: 100, min_inliers: 500}\n"
      "tracking: {min_features: 500}\n"
      "loops: {local: {min_inliers: 500}, global: {min_inliers: 500}}\n"
      "nav: {inflation: 1e6, min_sigma_m: 1000, min_sigma_rad: 10}\n"
      "backend: {sparse: {function_tolerance: 0.999}}\n");
  EXPECT_EQ(c.odometry.features.sigma, 10.0);
  EXPECT_EQ(c.odometry.klt.border_px, 1000);
  EXPECT_EQ(c.tracking.min_features, 500);
  EXPECT_EQ(c.odometry.nav.inflation, 1e6);
  EXPECT_EQ(slamConfigToYaml(slamConfigFromYaml(slamConfigToYaml(c))), slamConfigToYaml(c));
  // The shipped defaults, one document with a leading '---', load.
  EXPECT_EQ(slamConfigToYaml(slamConfigFromYaml("---\n" + slamConfigToYaml(SlamConfig()))),
            slamConfigToYaml(SlamConfig()));
}

// odometry.features.sift_backend: auto is the build's default (OpenCV's SIFT where it runs, else
// VLFeat's) and the dump shows the one chosen; a backend this build cannot run is refused by key,
// a word that names none too. Both outcomes are checked for each backend: which one a build gets
// depends on its OpenCV and VLFeat.
TEST(SlamConfig, SiftBackendAutoResolvesAndAnUnavailableOneIsRefusedByKey) {
  using uw_multislam::core::defaultSiftBackend;
  using uw_multislam::core::SiftBackend;
  using uw_multislam::core::siftBackendName;
  using uw_multislam::core::siftBackendUnavailable;
  const SlamConfig automatic = slamConfigFromYaml("odometry: {features: {sift_backend: auto}}");
  EXPECT_EQ(automatic.odometry.features.sift_backend, defaultSiftBackend());
  EXPECT_EQ(SlamConfig().odometry.features.sift_backend, defaultSiftBackend());
  EXPECT_NE(slamConfigToYaml(automatic).find("sift_backend: " + siftBackendName(defaultSiftBackend())),
            std::string::npos);
  EXPECT_EQ(siftBackendUnavailable(defaultSiftBackend()), "");
  for (SiftBackend b : {SiftBackend::kOpenCv, SiftBackend::kVlfeat}) {
    const std::string yaml = "odometry: {features: {sift_backend: " + siftBackendName(b) + "}}";
    if (siftBackendUnavailable(b).empty()) {
      EXPECT_EQ(slamConfigFromYaml(yaml).odometry.features.sift_backend, b);
    } else {
      EXPECT_NE(refusal(yaml).find("odometry.features: sift_backend " + siftBackendName(b) + ": "), std::string::npos)
          << refusal(yaml);
    }
    // With ORB features the SIFT backend is not used, and not refused.
    EXPECT_EQ(slamConfigFromYaml("odometry: {features: {type: orb, sift_backend: " + siftBackendName(b) + "}}")
                  .odometry.features.sift_backend,
              b);
  }
  EXPECT_NE(
      refusal("odometry: {features: {sift_backend: cuda}}").find("unknown sift_backend 'cuda' (auto, opencv, vlfeat)"),
      std::string::npos)
      << refusal("odometry: {features: {sift_backend: cuda}}");
}
