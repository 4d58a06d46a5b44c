// bench_export: export_survey's cost on a large map: writes a store with one session of
// N keyframes on a lawnmower (SIFT-sized random features, as bench_store; the thumbnails, altitude
// and camera of a real store's keyframes, cycled), then loads it as export_survey does and draws
// its mosaic, printing the times, the mosaic's size and the process's peak resident memory.
#include <sys/resource.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "cli.h"

#include "uw_multislam/core/export/mosaic.h"
#include "uw_multislam/core/export/survey_export.h"
#include "uw_multislam/core/store/session_store.h"

namespace core = uw_multislam::core;
namespace fs = std::filesystem;
namespace po = boost::program_options;
namespace tools = uw_multislam::tools;

namespace {

const char* kUsage =
    R"(usage: bench_export --from STORE [--keyframes N] [--features n] [--resolution M] [--blend B] [--dir DIR]

Writes one session of N keyframes (default 10000; n features each, default 500) on a lawnmower
(legs of 50 m, 1.5 m apart, a keyframe every 0.3 m) into a fresh store in DIR (default: the system
temporary directory; removed afterwards), with the thumbnails, altitudes and camera of the first
session of STORE cycled; then loads it (loadSurveyExport) and writes its mosaic (writeMosaic,
thumbnails; --resolution M m/px, default automatic; --blend as export_survey). Prints the times,
the mosaic's size and the peak resident memory (getrusage) after each step.)";

double msSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

double peakMb() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return u.ru_maxrss / 1024.0;  // kB on Linux
}

struct Arguments {
  int n = 10000, features = 500;
  std::string from, dir = fs::temp_directory_path().string();
  core::MosaicOptions options;
};

std::string parseBlend(const std::string& text, core::MosaicBlend* blend) {
  return core::parseMosaicBlend(text, blend) ? "" : "bad --blend '%value%': multiband, feather or none";
}

std::optional<int> parseArguments(int argc, char** argv, Arguments* a) {
  tools::CommandLine cli("bench_export", kUsage);
  auto option = cli.add();
  option("from", po::value(&a->from));
  option("keyframes", tools::integer(&a->n));
  option("features", tools::integer(&a->features));
  option("resolution", po::value(&a->options.resolution_m));
  option("blend", tools::checked(&a->options.blend, parseBlend));
  option("dir", po::value(&a->dir));
  if (const auto status = cli.parse(argc, argv)) return status;
  if (a->from.empty() || a->n < 2 || a->features < 0)
    return cli.bad("--from STORE is required, --keyframes at least 2");
  return std::nullopt;
}

int bench(const Arguments& a) {
  const int n = a.n, features = a.features;
  const std::string &from = a.from, &dir = a.dir;
  const core::MosaicOptions& options = a.options;
  const std::string path = (fs::path(dir) / ("bench_export_" + std::to_string(n) + ".db")).string();
  try {
    std::vector<std::vector<std::uint8_t>> thumbs;
    std::vector<double> altitudes;
    core::CameraIntrinsics camera;
    {
      const core::SessionStore source(from, core::StoreAccess::kReadOnly);
      const std::vector<core::StoredSession> sessions = source.sessions();
      if (sessions.empty()) throw core::StoreError(from + ": no session");
      camera = sessions.front().camera;
      thumbs = source.thumbnails(sessions.front().id);
      for (const core::StoredKeyframe& k : source.keyframes(sessions.front().id, false))
        altitudes.push_back(k.altitude_m);
    }
    fs::remove(path);
    auto t0 = std::chrono::steady_clock::now();
    {
      core::SessionStore store(path);
      const std::int64_t s = store.addSession("bench", camera, 0.0);
      std::mt19937 rng(1);
      std::uniform_real_distribution<float> u(0.0f, 1.0f);
      const int per_leg = 167;  // 50 m / 0.3 m
      core::Pose2 previous;
      for (int k = 0; k < n; ++k) {
        const int leg = k / per_leg, along = k % per_leg;
        const double x = leg % 2 == 0 ? 0.3 * along : 0.3 * (per_leg - 1 - along);
        const core::Pose2 pose(x, 1.5 * leg, leg % 2 == 0 ? 0.0 : M_PI);
        core::StoredKeyframe kf;
        kf.session = s;
        kf.keyframe = k;
        kf.frame_index = k;
        kf.stamp_s = k;
        kf.altitude_m = altitudes[k % altitudes.size()];
        kf.image_size = cv::Size(camera.width, camera.height);
        for (int i = 0; i < features; ++i) kf.points.emplace_back(camera.width * u(rng), camera.height * u(rng));
        kf.descriptors = cv::Mat(features, 128, CV_8U);
        cv::randu(kf.descriptors, 0, 256);
        kf.hash = Eigen::VectorXf::Random(core::HalocProjections::kHashSize) * 0.1f;
        kf.thumbnail = thumbs[k % thumbs.size()];
        const core::UncertainPose2 m(core::between(previous, pose), Eigen::Matrix3d::Identity() * 1e-5);
        std::vector<core::StoredLoop> loops;
        store.addKeyframe(kf, k > 0 ? &m : nullptr, &loops);
        previous = pose;
      }
      store.endSession(s, n);
      store.checkpoint();
    }
    std::printf("store: %d keyframes, %.0f MB, written in %.1f s\n", n, fs::file_size(path) / 1e6, msSince(t0) / 1e3);
    std::printf("peak RSS before the export: %.0f MB\n", peakMb());
    t0 = std::chrono::steady_clock::now();
    const core::SurveyExport survey = core::loadSurveyExport(path);
    std::printf("loadSurveyExport: %.1f s, peak RSS %.0f MB\n", msSince(t0) / 1e3, peakMb());
    const core::MosaicImages images;
    const std::string png = (fs::path(dir) / ("bench_export_" + std::to_string(n) + ".png")).string();
    const core::MosaicResult r = core::writeMosaic(survey.maps.front(), survey, images, options, png, nullptr, "");
    std::printf(
        "writeMosaic (%s, thumbnails): %d x %d px at %.4f m/px, %d tiles, %.1f s, seam ratio %.3f, peak RSS %.0f MB\n",
        core::mosaicBlendName(options.blend), r.width, r.height, r.resolution_m, r.tiles, r.ms / 1e3, r.seam_ratio,
        peakMb());
    fs::remove(path);
    fs::remove(png);
    fs::path world(png);
    fs::remove(world.replace_extension(".pgw"));
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_export: %s\n", e.what());
    fs::remove(path);
    return 1;
  }
}

}  // namespace

int main(int argc, char** argv) {
  Arguments arguments;
  if (const auto status = parseArguments(argc, argv, &arguments)) return *status;
  return bench(arguments);
}
