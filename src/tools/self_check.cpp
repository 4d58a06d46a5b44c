// self_check: exercises the core library on a built-in survey pattern and prints what it finds.
// It is the README's demo until the full SLAM pipeline exists. Exit status 0 when every check
// holds, 1 otherwise.
//
// The pattern: a lawnmower survey of `legs` legs of `leg_length` metres, 0.5 m between
// keyframes, every motion with the same small covariance. Checks: the survey's end pose equals
// the one computed independently with homogeneous matrices; going out and back gives the
// identity; the yaw variance is exactly additive; the first-order end-pose covariance matches
// a 2000-run Monte-Carlo simulation of the noisy survey within 10 % in every standard deviation.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <string>

#include "uw_multislam/core/trajectory.h"

namespace core = uw_multislam::core;

namespace {

int usage(const char* argv0, int code) {
  std::fprintf(code ? stderr : stdout,
               "usage: %s [--legs N] [--leg-length METRES]\n"
               "Runs the uw_multislam core self-check on a built-in lawnmower survey.\n"
               "  --legs N             number of survey legs (default 6, 1..1000)\n"
               "  --leg-length METRES  length of each leg (default 20, 0.5..10000)\n",
               argv0);
  return code;
}

bool parseNumber(const char* s, double lo, double hi, double* out) {
  char* end = nullptr;
  const double v = std::strtod(s, &end);
  if (end == s || *end != '\0' || !std::isfinite(v) || v < lo || v > hi) return false;
  *out = v;
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  double legs = 6, leg_length = 20.0;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--help" || a == "-h") return usage(argv[0], 0);
    if (i + 1 >= argc) return usage(argv[0], 2);
    if (a == "--legs" && parseNumber(argv[i + 1], 1, 1000, &legs) && legs == std::floor(legs)) {
      ++i;
    } else if (a == "--leg-length" && parseNumber(argv[i + 1], 0.5, 10000, &leg_length)) {
      ++i;
    } else {
      std::fprintf(stderr, "self_check: bad argument '%s %s'\n", argv[i], argv[i + 1]);
      return usage(argv[0], 2);
    }
  }

  const double step = 0.5;
  const int steps_per_leg = static_cast<int>(std::lround(leg_length / step));
  Eigen::Matrix3d motion_cov = Eigen::Vector3d(0.01 * 0.01, 0.01 * 0.01, 0.002 * 0.002).asDiagonal();

  core::Trajectory t;
  Eigen::Matrix3d brute = Eigen::Matrix3d::Identity();
  auto add = [&](const core::Pose2& m) {
    t.append(core::UncertainPose2(m, motion_cov));
    brute = brute * m.matrix();
  };
  for (int leg = 0; leg < static_cast<int>(legs); ++leg) {
    for (int s = 0; s < steps_per_leg; ++s) add(core::Pose2(step, 0.0, 0.0));
    if (leg + 1 < static_cast<int>(legs)) {
      const double turn = (leg % 2 == 0) ? M_PI / 2 : -M_PI / 2;  // U-turn: two quarter turns
      add(core::Pose2(0.0, 0.0, turn));
      add(core::Pose2(step * 4, 0.0, turn));
    }
  }

  const std::size_t last = t.numKeyframes() - 1;
  const core::UncertainPose2 end = t.absolute(last);
  const core::Pose2 brute_end(brute(0, 2), brute(1, 2), std::atan2(brute(1, 0), brute(0, 0)));
  const double end_error = core::poseError(end.mean, brute_end).head<2>().norm();
  const core::Pose2 round_trip = core::compose(t.relative(0, last).mean, t.relative(last, 0).mean);

  // Yaw composes additively, so its variance after k motions is exactly k * sigma_yaw^2.
  const double yaw_var_expected = static_cast<double>(last) * motion_cov(2, 2);
  const double yaw_var_error = std::abs(end.covariance(2, 2) - yaw_var_expected) / yaw_var_expected;

  // Monte-Carlo: re-run the survey with noisy motions and compare the spread of the end pose
  // with the first-order prediction (standard error of a sample std with n runs ~ 1/sqrt(2n)).
  const int runs = 2000;
  std::mt19937_64 rng(2026);
  std::normal_distribution<double> noise(0.0, 1.0);
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  Eigen::Matrix3d sum_sq = Eigen::Matrix3d::Zero();
  const Eigen::Vector3d sigma(std::sqrt(motion_cov(0, 0)), std::sqrt(motion_cov(1, 1)), std::sqrt(motion_cov(2, 2)));
  for (int r = 0; r < runs; ++r) {
    core::Pose2 p;
    for (std::size_t k = 1; k <= last; ++k) {
      const Eigen::Vector3d n(noise(rng), noise(rng), noise(rng));
      p = core::compose(p, core::Pose2::fromVector(t.motion(k).mean.vector() + sigma.cwiseProduct(n)));
    }
    const Eigen::Vector3d e = core::poseError(p, end.mean);
    sum += e;
    sum_sq += e * e.transpose();
  }
  const Eigen::Vector3d mc_mean = sum / runs;
  const Eigen::Matrix3d mc_cov = (sum_sq - runs * mc_mean * mc_mean.transpose()) / (runs - 1);
  double worst_sigma_ratio = 0.0;
  for (int i = 0; i < 3; ++i) {
    const double ratio = std::sqrt(mc_cov(i, i) / end.covariance(i, i));
    worst_sigma_ratio = std::max(worst_sigma_ratio, std::abs(ratio - 1.0));
  }

  std::printf("uw_multislam core self-check: lawnmower survey, %d legs of %.1f m, %zu keyframes\n",
              static_cast<int>(legs), leg_length, t.numKeyframes());
  std::printf("  end pose            x=%.3f m  y=%.3f m  yaw=%.4f rad\n", end.mean.x(), end.mean.y(), end.mean.yaw());
  std::printf("  end 1-sigma         x=%.3f m  y=%.3f m  yaw=%.4f rad (odometry only, no loops)\n",
              std::sqrt(end.covariance(0, 0)), std::sqrt(end.covariance(1, 1)), std::sqrt(end.covariance(2, 2)));
  std::printf("  chain vs matrices   %.2e m\n", end_error);
  std::printf("  out-and-back        |X_0^t (+) X_t^0| = %.2e m\n", round_trip.translation().norm());
  std::printf("  yaw variance        %.3e rad^2 (expected %.3e, relative error %.1e)\n", end.covariance(2, 2),
              yaw_var_expected, yaw_var_error);
  std::printf(
      "  Monte-Carlo, %d runs: 1-sigma x=%.3f m  y=%.3f m  yaw=%.4f rad (worst deviation from "
      "prediction %.1f %%)\n",
      runs, std::sqrt(mc_cov(0, 0)), std::sqrt(mc_cov(1, 1)), std::sqrt(mc_cov(2, 2)), 100 * worst_sigma_ratio);

  const bool ok = end_error < 1e-6 && round_trip.translation().norm() < 1e-6 && std::abs(round_trip.yaw()) < 1e-9 &&
                  yaw_var_error < 1e-9 && worst_sigma_ratio < 0.10 && end.mean.isFinite();
  std::printf("%s\n", ok ? "self-check passed" : "self-check FAILED");
  return ok ? 0 : 1;
}
