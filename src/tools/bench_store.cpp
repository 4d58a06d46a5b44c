// bench_store: the session store's numbers (doc/session_store.md): bytes per keyframe
// on disk, write time per keyframe (one transaction each, synchronous=FULL), and the time to
// reload a session of N keyframes into a back-end and a loop detector (every keyframe's
// features and hash). Synthetic keyframes: n SIFT-sized features with random coordinates and
// descriptors (incompressible, as real ones nearly are), a 96 px JPEG-sized thumbnail.
// Then the keyframe image the store keeps (config `store`): for each longest
// side and JPEG quality, the bytes it adds per keyframe on disk, its encode and write times, on
// real-looking frames (the survey simulator's seabed through its water model, 1280 x 960, or the
// frames of a dataset folder given with --images), so that the default is chosen from them.
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <limits>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "cli.h"

#include "uw_multislam/core/loops/loop_detector.h"
#include "uw_multislam/core/session/session_manager.h"
#include "uw_multislam/core/store/keyframe_image.h"
#include "uw_multislam/core/store/map_persistence.h"
#include "uw_multislam/core/store/session_store.h"
#include "uw_multislam/sim/seabed_world.h"
#include "uw_multislam/sim/water_model.h"

namespace core = uw_multislam::core;
namespace fs = std::filesystem;
namespace po = boost::program_options;
namespace tools = uw_multislam::tools;

namespace {

const char* kUsage = R"(usage: bench_store [--keyframes N ...] [--features n] [--dir DIR] [--images DATASET_DIR]
                   [--image-keyframes N] [--no-images] [--images-only]
       bench_store --index-steps [--dir DIR]

--index-steps: the store's growth per keyframe message when the keyframe index steps by 1, by
max_keyframe_gap + 1 (the largest gap bridged), 1000, 100000 and 2^20 (a corrupt or hostile
sender), and by 1000 once then 1 (ids that really jumped: a new session from the jump), through
the session manager as the back-end uses it (default options), 10 messages of 500 features
each; prints the bytes the store (database, WAL and shared memory files) grew per message, the
largest single message's growth and its ratio to a real keyframe (step 1's mean in the same
run), then the bound: the largest growth of any one message.

Writes one session of N keyframes (default: 1000 and 10000) into a fresh store in DIR (default:
the system temporary directory; removed afterwards) and prints bytes per keyframe, write ms per
keyframe and the reload time into a back-end and a loop detector.

Then the keyframe image (config store.image_max_side_px / image_jpeg_quality): for longest sides
96, 160, 320, 640, 960 and qualities 75 and 90, a store of --image-keyframes keyframes (default
200) each with its image, and prints the image's mean JPEG bytes, its PSNR against the same resize
without JPEG, the store's bytes per keyframe
(and the image's share of them, against the same store without images), encode ms and write ms
per keyframe. The frames: a dataset
folder's images (--images, cycled), else 20 views of the simulator's procedural seabed through
its water model at 1280 x 960 (2 mm ground pixel).)";

double msSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

// One synthetic keyframe as the store benchmarks write it (features random, incompressible).
core::StoredKeyframe syntheticKeyframe(std::int64_t session, int k, int features, std::mt19937& rng) {
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  core::StoredKeyframe kf;
  kf.session = session;
  kf.keyframe = k;
  kf.frame_index = k;
  kf.stamp_s = k;
  kf.altitude_m = 2.0;
  kf.image_size = cv::Size(320, 240);
  for (int i = 0; i < features; ++i) kf.points.emplace_back(320 * u(rng), 240 * u(rng));
  kf.descriptors = cv::Mat(features, 128, CV_8U);
  cv::randu(kf.descriptors, 0, 256);
  kf.hash = Eigen::VectorXf::Random(core::HalocProjections::kHashSize) * 0.1f;
  return kf;
}

// Frames for the image table: a dataset folder's, or rendered seabed views.
std::vector<cv::Mat> benchFrames(const std::string& dataset_dir) {
  std::vector<cv::Mat> frames;
  if (!dataset_dir.empty()) {
    const core::Dataset d = core::loadDataset(dataset_dir);
    for (const core::FrameRecord& f : d.frames) {
      cv::Mat img = cv::imread(d.imagePath(f), cv::IMREAD_COLOR);
      if (!img.empty()) frames.push_back(img);
      if (frames.size() >= 50) break;
    }
    if (frames.empty()) throw std::runtime_error(dataset_dir + ": no readable image");
    return frames;
  }
  core::ProceduralSeabedOptions po;
  po.width_m = 8.0;
  po.height_m = 4.0;
  po.metres_per_px = 0.0016;  // 0.8 x the camera's 2 mm ground pixel, as make_survey does
  const core::SeabedWorld world = core::SeabedWorld::procedural(po);
  const core::CameraIntrinsics cam{1280, 960, 1000.0, 1000.0, 639.5, 479.5};
  const core::WaterOptions water;
  for (int i = 0; i < 20; ++i) {
    const core::Pose2 pose(1.5 + 0.25 * i, 2.0, 0.05 * i);
    core::WaterFrame wf;
    wf.index = i;
    wf.altitude_m = 2.0;
    cv::RNG rng(1000 + i);
    frames.push_back(core::applyWater(world.render(pose, 2.0, cam), water, wf, rng));
  }
  return frames;
}

struct ImageCost {
  double jpeg_bytes = 0.0, store_bytes = 0.0, encode_ms = 0.0, write_ms = 0.0;
  double psnr_db = 0.0;  // decoded image against the same resize without JPEG: what the quality costs
  cv::Size size;
};

// A store of n keyframes with the images of `options` (max_side_px 0: none): bytes per keyframe on
// disk, encode and write ms per keyframe.
ImageCost imageCost(const std::string& dir, const std::vector<cv::Mat>& frames,
                    const core::KeyframeImageOptions& options, int n, int features) {
  const std::string path = (fs::path(dir) / "bench_store_images.db").string();
  for (const char* suffix : {"", "-wal", "-shm"}) fs::remove(path + suffix);
  ImageCost cost;
  std::mt19937 rng(1);
  {
    core::SessionStore store(path);
    const std::int64_t s = store.addSession("bench", core::CameraIntrinsics{320, 240, 300.0, 300.0, 159.5, 119.5}, 0.0);
    const core::UncertainPose2 m(core::Pose2(0.3, 0.01, 0.001), Eigen::Matrix3d::Identity() * 1e-4);
    for (int k = 0; k < n; ++k) {
      core::StoredKeyframe kf = syntheticKeyframe(s, k, features, rng);
      auto t0 = std::chrono::steady_clock::now();
      kf.thumbnail = core::encodeKeyframeImage(frames[k % frames.size()], options);
      cost.encode_ms += msSince(t0);
      cost.jpeg_bytes += kf.thumbnail.size();
      if (!kf.thumbnail.empty() && k < static_cast<int>(frames.size())) {
        const cv::Mat decoded = cv::imdecode(kf.thumbnail, cv::IMREAD_GRAYSCALE);
        cv::Mat grey, resized;
        cv::cvtColor(frames[k], grey, cv::COLOR_BGR2GRAY);
        cv::resize(grey, resized, decoded.size(), 0, 0, cv::INTER_AREA);
        cost.size = decoded.size();
        cost.psnr_db += cv::PSNR(decoded, resized) / static_cast<double>(std::min<std::size_t>(frames.size(), n));
      }
      std::vector<core::StoredLoop> loops;
      t0 = std::chrono::steady_clock::now();
      store.addKeyframe(kf, k > 0 ? &m : nullptr, &loops);
      cost.write_ms += msSince(t0);
    }
    store.endSession(s, n);
    store.checkpoint();
  }
  cost.store_bytes = static_cast<double>(fs::file_size(path)) / n;
  cost.jpeg_bytes /= n;
  cost.encode_ms /= n;
  cost.write_ms /= n;
  for (const char* suffix : {"", "-wal", "-shm"}) fs::remove(path + suffix);
  return cost;
}

void printImageTable(const std::string& dir, const std::string& dataset_dir, int n, int features) {
  const std::vector<cv::Mat> frames = benchFrames(dataset_dir);
  std::printf("\nkeyframe image (config store), %d keyframes of %d features, frames %d x %d from %s:\n", n, features,
              frames.front().cols, frames.front().rows, dataset_dir.empty() ? "the simulator" : dataset_dir.c_str());
  std::printf(
      "| image_max_side_px | image_jpeg_quality | stored size | JPEG bytes | PSNR dB | store bytes per keyframe | "
      "image share | encode ms | write ms per keyframe |\n");
  std::printf("|---|---|---|---|---|---|---|---|---|\n");
  core::KeyframeImageOptions none;
  none.max_side_px = 0;
  const ImageCost base = imageCost(dir, frames, none, n, features);
  std::printf("| 0 (none) | - | - | 0 | - | %.0f | 0 %% | 0 | %.2f |\n", base.store_bytes, base.write_ms);
  std::fflush(stdout);
  for (int side : {96, 160, 320, 640, 960}) {
    for (int quality : {75, 90}) {
      core::KeyframeImageOptions o;
      o.max_side_px = side;
      o.jpeg_quality = quality;
      const ImageCost c = imageCost(dir, frames, o, n, features);
      std::printf("| %d | %d | %d x %d | %.0f | %.1f | %.0f | %.0f %% | %.2f | %.2f |\n", side, quality, c.size.width,
                  c.size.height, c.jpeg_bytes, c.psnr_db, c.store_bytes,
                  100.0 * (c.store_bytes - base.store_bytes) / c.store_bytes, c.encode_ms, c.write_ms);
      std::fflush(stdout);
    }
  }
}

struct Arguments {
  std::vector<int> sizes;  // empty: 1000 and 10000
  int features = 500;
  std::string dir = fs::temp_directory_path().string();
  std::string dataset_dir;
  int image_keyframes = 200;
  bool images = true, images_only = false;
  bool index_steps = false;
};

std::string parseKeyframes(const std::string& text, int* n) {
  long long v = 0;
  if (!tools::parseInteger(text, 0, std::numeric_limits<int>::max(), &v)) return "bad --keyframes '%value%'";
  *n = static_cast<int>(v);
  return "";
}

std::optional<int> parseArguments(int argc, char** argv, Arguments* a) {
  bool no_images = false;
  tools::CommandLine cli("bench_store", kUsage);
  auto option = cli.add();
  option("keyframes", tools::checkedEach(&a->sizes, parseKeyframes));
  option("features", tools::integer(&a->features));
  option("dir", po::value(&a->dir));
  option("images", po::value(&a->dataset_dir));
  option("image-keyframes", tools::integer(&a->image_keyframes));
  option("no-images", tools::flag(&no_images));
  option("images-only", tools::flag(&a->images_only));
  option("index-steps", tools::flag(&a->index_steps));
  if (const auto status = cli.parse(argc, argv)) return status;
  a->images = !no_images;
  if (a->image_keyframes < 1 || a->features < 1) return cli.bad("--image-keyframes and --features must be at least 1");
  return std::nullopt;
}

// The store's files together: SQLite's WAL holds what a checkpoint has not moved yet.
std::uintmax_t storeBytes(const std::string& path) {
  std::uintmax_t total = 0;
  for (const std::string& f : {path, path + "-wal", path + "-shm"}) {
    std::error_code ec;
    const std::uintmax_t n = fs::file_size(f, ec);
    if (!ec) total += n;
  }
  return total;
}

// Keyframe messages whose index steps by `step` (`jump_once`: by `step` once, then by 1, as
// an odometry whose ids really moved on): what each one costs the store.
struct StepRow {
  long long step = 1;
  bool jump_once = false;
  int accepted = 0, refused = 0, sessions = 0, kept = 0;  // kept: keyframes in the sessions, lost ones included
  double mean = 0.0;                                      // bytes per message
  std::uintmax_t largest = 0;
};

StepRow measureSteps(const std::string& dir, long long step, bool jump_once) {
  const std::string path = (fs::path(dir) / ("bench_store_steps_" + std::to_string(step) + ".db")).string();
  for (const std::string& f : {path, path + "-wal", path + "-shm", path + ".lock"}) fs::remove(f);
  std::mt19937 rng(1);
  core::SessionManagerOptions o;
  o.store_path = path;
  StepRow row;
  row.step = step;
  row.jump_once = jump_once;
  const int messages = 10;
  std::uintmax_t first = 0, last = 0;
  {
    core::SessionManager m(o);
    long long index = 0;
    for (int i = 0; i <= messages; ++i) {  // message 0: the session's origin, not counted
      if (i > 0) index += jump_once && i > 1 ? 1 : step;
      core::KeyframeInput k;
      k.session = 0;
      k.keyframe = static_cast<int>(std::min<long long>(index, std::numeric_limits<int>::max()));
      k.frame_index = k.keyframe;
      k.stamp_s = i;
      k.altitude_m = 2.0;
      k.camera.width = 320;
      k.camera.height = 240;
      k.camera.fx = k.camera.fy = 300;
      k.camera.cx = 160;
      k.camera.cy = 120;
      const core::StoredKeyframe synthetic = syntheticKeyframe(0, k.keyframe, o.num_features, rng);
      for (const cv::Point2f& p : synthetic.points) k.features.keypoints.emplace_back(p, 1.0f);
      k.features.descriptors = synthetic.descriptors;
      k.features.image_size = synthetic.image_size;
      k.motion = core::UncertainPose2(core::Pose2(0.3, 0, 0), Eigen::Matrix3d::Identity() * 1e-4);
      k.odometry_pose = core::Pose2(0.3 * i, 0, 0);
      const std::uintmax_t before = storeBytes(path);
      const core::Status st = m.addKeyframe(k);
      const std::uintmax_t after = storeBytes(path);
      if (i == 0) {
        if (!st.ok()) throw std::runtime_error("the origin was refused: " + st.message);
        first = after;
        continue;
      }
      (st.ok() ? row.accepted : row.refused) += 1;
      row.largest = std::max(row.largest, after > before ? after - before : 0);
      last = after;
    }
    row.sessions = static_cast<int>(m.view().list().size());
    for (const auto& s : m.view().list()) row.kept += s.keyframes;
  }
  row.mean = static_cast<double>(last > first ? last - first : 0) / messages;
  for (const std::string& f : {path, path + "-wal", path + "-shm", path + ".lock"}) fs::remove(f);
  return row;
}

int benchIndexSteps(const std::string& dir) {
  std::printf(
      "| index step | messages | accepted | refused | sessions | keyframes kept | store bytes per message (mean) | "
      "largest message | largest / a real keyframe |\n");
  std::printf("|---|---|---|---|---|---|---|---|---|\n");
  const long long bridged = core::SessionManagerOptions().max_keyframe_gap + 1LL;
  std::vector<StepRow> rows;
  for (const long long step : {1LL, bridged, 1000LL, 100000LL, 1LL << 20})
    rows.push_back(measureSteps(dir, step, false));
  rows.push_back(measureSteps(dir, 1000, true));
  const double real = rows[0].mean;  // a real keyframe (500 features) in this run
  std::uintmax_t worst = 0;
  for (const StepRow& r : rows) {
    worst = std::max(worst, r.largest);
    std::printf("| %lld%s | %d | %d | %d | %d | %d | %.0f | %ju | %.2f |\n", r.step, r.jump_once ? " once, then 1" : "",
                r.accepted + r.refused, r.accepted, r.refused, r.sessions, r.kept, r.mean, r.largest,
                real > 0 ? static_cast<double>(r.largest) / real : 0.0);
  }
  // The bound the fault matrix checks: any one message, whatever its index, against a real
  // keyframe's mean cost measured in the same run.
  std::printf("bound: one keyframe message grew the store by at most %ju bytes = %.2f x a real keyframe (%.0f bytes)\n",
              worst, real > 0 ? static_cast<double>(worst) / real : 0.0, real);
  std::fflush(stdout);
  return 0;
}

int bench(Arguments a) {
  if (a.index_steps) {
    try {
      return benchIndexSteps(a.dir);
    } catch (const std::exception& e) {
      std::fprintf(stderr, "bench_store: %s\n", e.what());
      return 1;
    }
  }
  std::vector<int>& sizes = a.sizes;
  const int features = a.features, image_keyframes = a.image_keyframes;
  const std::string &dir = a.dir, &dataset_dir = a.dataset_dir;
  const bool images = a.images, images_only = a.images_only;
  if (sizes.empty()) sizes = {1000, 10000};
  if (images_only) sizes.clear();
  if (!sizes.empty())
    std::printf(
        "| keyframes | features | bytes per keyframe | write ms per keyframe | reload ms (back-end + detector) | "
        "reload ms (back-end only) |\n");
  if (!sizes.empty()) std::printf("|---|---|---|---|---|---|\n");
  try {
    for (int n : sizes) {
      const std::string path = (fs::path(dir) / ("bench_store_" + std::to_string(n) + ".db")).string();
      fs::remove(path);
      fs::remove(path + "-wal");
      fs::remove(path + "-shm");
      std::mt19937 rng(1);
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
        store.checkHashSettings(
            {lo.global.hash_mode, lo.global.projection_seed, features, hasher.projections().toText()});
        const std::int64_t s = store.addSession("bench", cam, 0.0);
        for (int k = 0; k < n; ++k) {
          core::StoredKeyframe kf = syntheticKeyframe(s, k, features, rng);
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
        if (r.keyframes != n || static_cast<int>(detector.size()) != n)
          throw std::runtime_error("reload lost keyframes");
      }
      {
        const auto t0 = std::chrono::steady_clock::now();
        core::SessionStore store(path);
        core::BackendOptions bo;
        core::MultiSessionBackend backend(bo);
        core::restoreStore(store, &backend, nullptr, nullptr);
        reload_backend = msSince(t0);
      }
      std::printf("| %d | %d | %.0f | %.2f | %.0f | %.0f |\n", n, features, bytes, write_ms / n, reload_full,
                  reload_backend);
      std::fflush(stdout);
      fs::remove(path);
    }
    if (images) printImageTable(dir, dataset_dir, image_keyframes, features);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_store: %s\n", e.what());
    return 1;
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  Arguments arguments;
  if (const auto status = parseArguments(argc, argv, &arguments)) return *status;
  return bench(std::move(arguments));
}
