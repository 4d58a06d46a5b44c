// bench_store: the session store's numbers for the closing note of issue 8: bytes per keyframe
// on disk, write time per keyframe (one transaction each, synchronous=FULL), and the time to
// reload a session of N keyframes into a back-end and a loop detector (every keyframe's
// features and hash). Synthetic keyframes: n SIFT-sized features with random coordinates and
// descriptors (incompressible, as real ones nearly are), a 96 px JPEG-sized thumbnail.
#include <opencv2/core.hpp>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include "uw_multislam/core/loops/loop_detector.h"
#include "uw_multislam/core/session/map_persistence.h"
#include "uw_multislam/core/session/session_store.h"

namespace core = uw_multislam::core;
namespace fs = std::filesystem;

namespace {

const char* kUsage = R"(usage: bench_store [--keyframes N ...] [--features n] [--dir DIR]

Writes one session of N keyframes (default: 1000 and 10000) into a fresh store in DIR (default:
the system temporary directory; removed afterwards) and prints bytes per keyframe, write ms per
keyframe and the reload time into a back-end and a loop detector.)";

double msSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<int> sizes;
  int features = 500;
  std::string dir = fs::temp_directory_path().string();
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--keyframes" && i + 1 < argc) sizes.push_back(std::atoi(argv[++i]));
    else if (a == "--features" && i + 1 < argc) features = std::atoi(argv[++i]);
    else if (a == "--dir" && i + 1 < argc) dir = argv[++i];
    else {
      std::puts(kUsage);
      return a == "-h" || a == "--help" ? 0 : 2;
    }
  }
  if (sizes.empty()) sizes = {1000, 10000};
  std::printf("| keyframes | features | bytes per keyframe | write ms per keyframe | reload ms (back-end + detector) | reload ms (back-end only) |\n");
  std::printf("|---|---|---|---|---|---|\n");
  try {
    for (int n : sizes) {
      const std::string path = (fs::path(dir) / ("bench_store_" + std::to_string(n) + ".db")).string();
      fs::remove(path);
      fs::remove(path + "-wal");
      fs::remove(path + "-shm");
      std::mt19937 rng(1);
      std::uniform_real_distribution<float> u(0.0f, 1.0f);
      core::CameraIntrinsics cam;
      cam.width = 320;
      cam.height = 240;
      cam.fx = cam.fy = 300;
      cam.cx = 160;
      cam.cy = 120;
      core::LoopOptions lo;
      const core::ImageHasher hasher(lo.global.hash_mode, features, lo.global.projection_seed);
      double write_ms = 0.0;
      {
        core::SessionStore store(path);
        store.checkHashSettings({lo.global.hash_mode, lo.global.projection_seed, features, hasher.projections().toText()});
        const std::int64_t s = store.addSession("bench", cam, 0.0);
        for (int k = 0; k < n; ++k) {
          core::StoredKeyframe kf;
          kf.session = s;
          kf.keyframe = k;
          kf.frame_index = k;
          kf.stamp_s = k;
          kf.altitude_m = 2.0;
          kf.image_size = cv::Size(320, 240);
          for (int i = 0; i < features; ++i) kf.points.emplace_back(320 * u(rng), 240 * u(rng));
          kf.descriptors = cv::Mat(features, 128, CV_8U);
          cv::randu(kf.descriptors, 0, 256);
          kf.hash = Eigen::VectorXf::Random(core::HalocProjections::kHashSize) * 0.1f;
          kf.thumbnail.resize(2500);
          for (auto& b : kf.thumbnail) b = static_cast<std::uint8_t>(rng());
          const core::UncertainPose2 m(core::Pose2(0.3, 0.01, 0.001), Eigen::Matrix3d::Identity() * 1e-4);
          std::vector<core::StoredLoop> loops;
          if (k > 10 && k % 10 == 0) {
            core::StoredLoop l;
            l.session_a = s;
            l.keyframe_a = k - 10;
            l.session_b = s;
            l.keyframe_b = k;
            l.inliers = 40;
            l.z = core::UncertainPose2(core::Pose2(3.0, 0.1, 0.01), Eigen::Matrix3d::Identity() * 1e-4);
            loops.push_back(l);
          }
          const auto t0 = std::chrono::steady_clock::now();
          store.addKeyframe(kf, k > 0 ? &m : nullptr, &loops);
          write_ms += msSince(t0);
        }
        store.endSession(s, n);
        store.checkpoint();
      }
      const double bytes = static_cast<double>(fs::file_size(path)) / n;
      double reload_full = 0.0, reload_backend = 0.0;
      {
        const auto t0 = std::chrono::steady_clock::now();
        core::SessionStore store(path);
        core::BackendOptions bo;
        core::MultiSessionBackend backend(bo);
        core::LoopDetector detector(lo, core::MatchOptions(), core::RansacOptions(), features);
        std::vector<std::unique_ptr<core::CameraIntrinsics>> cameras;
        const core::RestoredStore r = core::restoreStore(store, &backend, &detector, &cameras);
        reload_full = msSince(t0);
        if (r.keyframes != n || static_cast<int>(detector.size()) != n) throw std::runtime_error("reload lost keyframes");
      }
      {
        const auto t0 = std::chrono::steady_clock::now();
        core::SessionStore store(path);
        core::BackendOptions bo;
        core::MultiSessionBackend backend(bo);
        core::restoreStore(store, &backend, nullptr, nullptr);
        reload_backend = msSince(t0);
      }
      std::printf("| %d | %d | %.0f | %.2f | %.0f | %.0f |\n", n, features, bytes, write_ms / n, reload_full, reload_backend);
      std::fflush(stdout);
      fs::remove(path);
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_store: %s\n", e.what());
    return 1;
  }
  return 0;
}
