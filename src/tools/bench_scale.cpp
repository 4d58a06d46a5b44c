// bench_scale: what a store of N keyframes costs a vehicle that restarts on it.
//
// It builds a store of N synthetic keyframes (sessions of --per-session keyframes; n random
// SIFT-sized descriptors and keypoints, a random hash of the real size, a thumbnail-sized blob,
// an odometry motion each; no images), then runs itself again in a child process on that store
// (a fresh process, so that nothing the build left in the heap hides or inflates the growth) and
// the child loads it the way offline_slam --db does (SessionManager, then every stored session
// into a LoopDetector: loadStoredSessions) and prints one line:
//
//   bench_scale keyframes=N ram_per_stored_keyframe_kB=X reload_s=Y hash_query_ms=Z verify_ms=W
//
//  - X: VmRSS (/proc/self/status) after the load minus before it (the detector already built,
//    the store not yet opened), over N, in kB (1024 bytes);
//  - Y: the load's wall time (open, check, restore the back-end, hand the keyframes over);
//  - Z: the median time of one global hash query (best_k of every stored keyframe) for random
//    hashes;
//  - W: the median time to verify one candidate (read its features if they are not in RAM,
//    match, RANSAC) against a random new keyframe, candidates drawn uniformly over the store (as
//    most hash candidates are, unrelated: the verification rejects them).
#include <sys/wait.h>
#include <unistd.h>

#include <sqlite3.h>
#include <opencv2/core.hpp>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <deque>
#include <filesystem>
#include <fstream>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "cli.h"

#include "uw_multislam/core/session/pipeline.h"
#include "uw_multislam/core/session/session_manager.h"
#include "uw_multislam/core/session/slam_config.h"
#include "uw_multislam/core/store/session_store.h"

namespace core = uw_multislam::core;
namespace fs = std::filesystem;
namespace po = boost::program_options;
namespace tools = uw_multislam::tools;

namespace {

const char* kUsage = R"(usage: bench_scale --keyframes N [--per-session K] [--features n] [--config FILE]
                   [--queries Q] [--dir DIR] [--keep]

Builds a store of N synthetic keyframes in sessions of K (default 1000) keyframes of n (default:
the configuration's) features in DIR (default: the system temporary directory; removed
afterwards unless --keep), loads it in a child process as offline_slam --db does and prints

  bench_scale keyframes=N ram_per_stored_keyframe_kB=X reload_s=Y hash_query_ms=Z verify_ms=W

(RSS growth per stored keyframe, load time, median hash query, median verification of one
candidate including its read from disk). Q (default 200) queries and verifications are timed.
  --load DB   (internal) the child's part, on an existing store)";

struct Args {
  int keyframes = 0;
  int per_session = 1000;
  int features = -1;
  int queries = 200;
  std::string config_path;
  std::string dir = fs::temp_directory_path().string();
  std::string load;
  bool keep = false;
};

double msSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

long rssKb() {
  std::ifstream in("/proc/self/status");
  std::string line;
  while (std::getline(in, line))
    if (line.rfind("VmRSS:", 0) == 0) return std::atol(line.c_str() + 6);
  throw std::runtime_error("no VmRSS in /proc/self/status");
}

double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

core::CameraIntrinsics benchCamera() {
  core::CameraIntrinsics cam;
  cam.width = 320;
  cam.height = 240;
  cam.fx = cam.fy = 300;
  cam.cx = 160;
  cam.cy = 120;
  return cam;
}

// n random features as the extractor gives them (pixel positions, 8-bit SIFT values).
void randomFeatures(int n, std::mt19937* rng, std::vector<cv::Point2f>* points, cv::Mat* descriptors) {
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  points->clear();
  for (int i = 0; i < n; ++i) points->emplace_back(320 * u(*rng), 240 * u(*rng));
  *descriptors = cv::Mat(n, 128, CV_8U);
  cv::theRNG().state = (*rng)();
  cv::randu(*descriptors, 0, 256);
}

Eigen::VectorXf randomHash(std::mt19937* rng) {
  // Sorted-DCT hashes lie within about [-0.06, 0.16] (loop_detector.cpp): values of that spread.
  std::normal_distribution<float> g(0.0f, 0.05f);
  Eigen::VectorXf h(core::HalocProjections::kHashSize);
  for (int i = 0; i < h.size(); ++i) h[i] = g(*rng);
  return h;
}

void build(const Args& a, const core::SlamConfig& config, const std::string& path) {
  core::SessionStore store(path);
  // The build is not what is measured: one fsync per keyframe (synchronous=FULL) would make 100 k
  // keyframes take minutes for nothing.
  sqlite3_exec(store.handle(), "PRAGMA synchronous=OFF", nullptr, nullptr, nullptr);
  const core::GlobalLoopOptions& g = config.loops.global;
  const core::ImageHasher hasher(g.hash_mode, a.features, g.projection_seed);
  store.checkHashSettings({g.hash_mode, g.projection_seed, a.features, hasher.projections().toText()});
  std::mt19937 rng(1);
  const core::UncertainPose2 motion(core::Pose2(0.3, 0.01, 0.001), Eigen::Matrix3d::Identity() * 1e-4);
  std::int64_t session = -1;
  int keyframe = 0;
  for (int k = 0; k < a.keyframes; ++k) {
    if (k % a.per_session == 0) {
      if (session >= 0) store.endSession(session, k);
      session = store.addSession("bench_" + std::to_string(k / a.per_session), benchCamera(), k);
      keyframe = 0;
    }
    core::StoredKeyframe kf;
    kf.session = session;
    kf.keyframe = keyframe;
    kf.frame_index = keyframe;
    kf.stamp_s = k;
    kf.altitude_m = 2.0;
    kf.image_size = cv::Size(320, 240);
    randomFeatures(a.features, &rng, &kf.points, &kf.descriptors);
    kf.hash = randomHash(&rng);
    kf.thumbnail.resize(1400);  // a 96 px JPEG's size
    for (auto& b : kf.thumbnail) b = static_cast<std::uint8_t>(rng());
    store.addKeyframe(kf, keyframe > 0 ? &motion : nullptr, nullptr);
    ++keyframe;
  }
  if (session >= 0) store.endSession(session, a.keyframes);
  store.checkpoint();
}

// The child: load the store as offline_slam --db does, measure, print the line.
int measure(const Args& a, const core::SlamConfig& config) {
  std::error_code ec;
  if (!fs::is_regular_file(a.load, ec) || fs::file_size(a.load, ec) == 0)
    throw std::invalid_argument(a.load + ": no such store (the session manager would create an empty one)");
  core::LoopDetector detector(config.loops, config.odometry.matching, config.odometry.ransac, a.features);
  std::mt19937 rng(7);
  std::vector<cv::Point2f> points;
  core::FrameFeatures now_features;
  randomFeatures(a.features, &rng, &points, &now_features.descriptors);
  for (const cv::Point2f& p : points) now_features.keypoints.emplace_back(p, 1.0f);
  now_features.image_size = cv::Size(320, 240);
  now_features.descriptors.convertTo(now_features.descriptors, CV_32F);
  const core::CameraIntrinsics camera = benchCamera();
  const core::View now{&now_features, 2.0, &camera};

  const long rss0 = rssKb();
  const auto t0 = std::chrono::steady_clock::now();
  core::SessionManager manager(core::sessionManagerOptions(config, a.load));
  const double manager_s = msSince(t0) / 1e3;
  std::deque<core::CameraIntrinsics> cameras;
  const int loaded = core::loadStoredSessions(&manager, &detector, &cameras);
  const double reload_s = msSince(t0) / 1e3;
  std::fprintf(stderr,
               "bench_scale: reload %.3f s: session manager (back-end, keyframe frame data) %.3f s, keyframes "
               "into the loop detector %.3f s\n",
               reload_s, manager_s, reload_s - manager_s);
  const long rss1 = rssKb();
  if (loaded <= 0) throw std::runtime_error(a.load + ": no keyframes loaded");

  const int new_session = manager.view().nextId();
  std::vector<double> query_ms, verify_ms;
  for (int q = 0; q < a.queries; ++q) {
    const Eigen::VectorXf h = randomHash(&rng);
    const auto tq = std::chrono::steady_clock::now();
    const std::vector<core::HashCandidate>& c = detector.globalCandidates(h, new_session);
    query_ms.push_back(msSince(tq));
    if (c.empty()) throw std::runtime_error("a hash query found no candidate");
  }
  std::uniform_int_distribution<int> any(0, static_cast<int>(detector.size()) - 1);
  std::vector<core::HashCandidate> drawn;
  for (int q = 0; q < a.queries; ++q) drawn.push_back({any(rng), 0.0f});
  for (const core::HashCandidate& c : drawn) {
    core::Loop loop;
    const auto tv = std::chrono::steady_clock::now();
    detector.verifyCandidate(c, now, &loop);
    verify_ms.push_back(msSince(tv));
  }
  // The same candidates again: now in the cache (when it holds them), so without the read.
  std::vector<double> again_ms;
  for (const core::HashCandidate& c : drawn) {
    core::Loop loop;
    const auto tv = std::chrono::steady_clock::now();
    detector.verifyCandidate(c, now, &loop);
    again_ms.push_back(msSince(tv));
  }
  std::fprintf(stderr, "bench_scale: the same candidates verified again: median %.3f ms\n", median(again_ms));
  const core::StageStats read = detector.times().get("feature_read");
  if (const core::FeatureCache* cache = detector.featureCache())
    std::fprintf(
        stderr,
        "bench_scale: features read from the store %ld times, %.3f ms mean; cache %ld hits, %zu entries, %.1f MB\n",
        cache->stats().misses, read.meanMs(), cache->stats().hits, cache->size(),
        static_cast<double>(cache->bytes()) / 1e6);
  std::printf(
      "bench_scale keyframes=%d ram_per_stored_keyframe_kB=%.2f reload_s=%.3f hash_query_ms=%.3f verify_ms=%.3f\n",
      loaded, static_cast<double>(rss1 - rss0) / loaded, reload_s, median(query_ms), median(verify_ms));
  std::fflush(stdout);
  return 0;
}

int runChild(const std::vector<std::string>& args) {
  std::vector<char*> argv;
  for (const std::string& s : args) argv.push_back(const_cast<char*>(s.c_str()));
  argv.push_back(nullptr);
  std::fflush(stdout);
  const pid_t pid = fork();
  if (pid < 0) throw std::runtime_error("fork failed");
  if (pid == 0) {
    execv("/proc/self/exe", argv.data());
    std::perror("bench_scale: exec /proc/self/exe");
    _exit(127);
  }
  int status = 0;
  if (waitpid(pid, &status, 0) != pid) throw std::runtime_error("waitpid failed");
  if (WIFEXITED(status)) return WEXITSTATUS(status);
  return 128 + (WIFSIGNALED(status) ? WTERMSIG(status) : 0);
}

std::optional<int> parseArguments(int argc, char** argv, Args* a) {
  tools::CommandLine cli("bench_scale", kUsage);
  auto option = cli.add();
  option("keyframes", tools::integer(&a->keyframes));
  option("per-session", tools::integer(&a->per_session));
  option("features", tools::integer(&a->features));
  option("config", po::value(&a->config_path));
  option("queries", tools::integer(&a->queries));
  option("dir", po::value(&a->dir));
  option("keep", tools::flag(&a->keep));
  option("load", po::value(&a->load));
  return cli.parse(argc, argv);
}

int bench(Args a) {
  try {
    const core::SlamConfig config = a.config_path.empty() ? core::SlamConfig() : core::loadSlamConfig(a.config_path);
    if (a.features < 0) a.features = config.odometry.features.num_features;
    if (a.features < 1 || a.queries < 1) throw std::invalid_argument("--features and --queries must be >= 1");
    if (!a.load.empty()) return measure(a, config);
    if (a.keyframes < 1 || a.per_session < 1)
      throw std::invalid_argument("--keyframes and --per-session must be >= 1 (see --help)");
    const std::string path = (fs::path(a.dir) / ("bench_scale_" + std::to_string(a.keyframes) + ".db")).string();
    for (const std::string& p : {path, path + "-wal", path + "-shm", path + ".lock"}) fs::remove(p);
    const auto t0 = std::chrono::steady_clock::now();
    build(a, config, path);
    std::fprintf(stderr, "bench_scale: built %s (%d keyframes, %.0f MB) in %.1f s\n", path.c_str(), a.keyframes,
                 static_cast<double>(fs::file_size(path)) / 1e6, msSince(t0) / 1e3);
    std::vector<std::string> child = {"bench_scale",
                                      "--load",
                                      path,
                                      "--features",
                                      std::to_string(a.features),
                                      "--queries",
                                      std::to_string(a.queries)};
    if (!a.config_path.empty()) child.insert(child.end(), {"--config", a.config_path});
    const int rc = runChild(child);
    if (!a.keep)
      for (const std::string& p : {path, path + "-wal", path + "-shm", path + ".lock"}) fs::remove(p);
    if (rc != 0) std::fprintf(stderr, "bench_scale: the measuring child failed (status %d)\n", rc);
    return rc;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_scale: %s\n", e.what());
    return 1;
  }
}

}  // namespace

int main(int argc, char** argv) {
  Args arguments;
  if (const auto status = parseArguments(argc, argv, &arguments)) return *status;
  return bench(std::move(arguments));
}
