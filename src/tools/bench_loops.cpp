// bench_loops: loop detection benchmark (paper 000 §7, (6)-(9)). Prints markdown tables:
//   1. HashStore::query speed with 1k / 10k / 100k stored hashes and the store's memory;
//   2. best-k hash candidates + RANSAC, for each hash mode (--hash-mode: the default sorted_dct,
//      the paper's HALOC, or both), against brute-force RANSAC over every keyframe, per
//      two-session mission: loops accepted, correct against ground truth, recall, time;
//   3. negatives: unrelated images (Posidonia) queried against every mission keyframe.
// A benchmark, not a test: it asserts nothing about the numbers. One core (cv::setNumThreads(1)).
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include <malloc.h>
#include <algorithm>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <optional>
#include <random>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include "cli.h"

#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/frontend/enhancement.h"
#include "uw_multislam/core/frontend/features.h"
#include "uw_multislam/core/frontend/odometry.h"
#include "uw_multislam/core/frontend/pair_motion.h"
#include "uw_multislam/core/geometry/se2.h"
#include "uw_multislam/core/loops/haloc.h"
#include "uw_multislam/core/loops/loop_detector.h"

namespace core = uw_multislam::core;
namespace fs = std::filesystem;
namespace po = boost::program_options;
namespace tools = uw_multislam::tools;
using Clock = std::chrono::steady_clock;

namespace {

const char* kUsage = R"(usage: bench_loops --session A --session B [--session A --session B ...] [options]

Loop detection benchmark over dataset folders (frames.csv, camera.yaml, images). Sessions come
in pairs, one pair per mission: A is the earlier session, B the later one whose keyframes look
for loops in A. Ground truth (optional) is read from world_gt.csv and loops_gt.csv one level
above the folders (make_survey and ../shared/data/flights write them). Prints markdown tables:
  1. HashStore::query time for each store size (best k = 10), bytes per stored hash;
  2. per mission: each hash mode (best k = 5, 10, 20 by hash, RANSAC-verified) against brute
     force (RANSAC against every keyframe of A): loops accepted, correct, recall, time per keyframe;
  3. with --posidonia: each image of DIR as a single-frame view (altitude 2 m, fx = fy = 400,
     principal point at the image centre) queried against every mission keyframe; a loop
     accepted there is a false loop.
Everything runs on one core (cv::setNumThreads(1)); the odometry, matching and RANSAC options
are the defaults of offline_slam (verification matching: loops.ratio), a loop needs
loops.global.min_inliers RANSAC inliers.

options:
  --session DIR       a dataset folder (an even number of them: A B per mission)
  --posidonia DIR     a folder of unrelated images (jpg/png) for the negatives
  --sizes N,N,...     store sizes for the query timing (default 1000,10000,100000)
  --hash-mode MODE    sorted_dct (the pipeline's default), haloc (the paper's) or both (default both:
                      the first listed mode also hashes the timing section's frames)
  -h, --help          this text

Exit status 0 on success, 2 on bad arguments, 1 with a one-line reason on bad input.)";

constexpr int kQueryK = 10;                         // the default best_k (GlobalLoopOptions)
constexpr int kTimedQueries = 200;                  // queries timed per store size
constexpr int kEntriesPerSession = 1000;            // synthetic stores: missions of this many keyframes
constexpr double kPerturbation = 0.1;               // replica noise, fraction of the hash values' std
constexpr float kQuantStep = 2.0f * 0.5f / 255.0f;  // HashStore's default range
constexpr double kPosidoniaAltitude = 2.0;
constexpr double kPosidoniaFocal = 400.0;
const std::vector<int> kBestK = {5, 10, 20};

struct Args {
  std::vector<std::string> sessions;
  std::string posidonia;
  std::vector<int> sizes = {1000, 10000, 100000};
  std::vector<core::HashMode> modes = {core::HashMode::kSortedDct, core::HashMode::kHaloc};
};

// ---------------------------------------------------------------------------------------------
// Small helpers.

double msSince(Clock::time_point t0) { return std::chrono::duration<double, std::milli>(Clock::now() - t0).count(); }

std::string fmt(double v, int precision) {
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.*f", precision, v);
  return buf;
}

std::string ratio(int num, int den) { return den > 0 ? fmt(static_cast<double>(num) / den, 3) : "n/a"; }

void printTable(const std::vector<std::string>& header, const std::vector<std::vector<std::string>>& rows) {
  auto line = [](const std::vector<std::string>& cells) {
    std::string s = "|";
    for (const auto& c : cells) s += " " + c + " |";
    std::puts(s.c_str());
  };
  line(header);
  line(std::vector<std::string>(header.size(), "---"));
  for (const auto& r : rows) line(r);
  std::puts("");
}

double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const std::size_t m = v.size() / 2;
  return v.size() % 2 ? v[m] : 0.5 * (v[m - 1] + v[m]);
}

/// Bytes the process holds from malloc (glibc: brk arena in use + mmapped blocks).
double heapBytes() {
#if __GLIBC__ > 2 || (__GLIBC__ == 2 && __GLIBC_MINOR__ >= 33)
  const struct mallinfo2 m = mallinfo2();
#else
  // glibc before 2.33 (Ubuntu 20.04, Debian 11) has only mallinfo, whose int fields wrap past 2 GiB.
  const struct mallinfo m = mallinfo();
#endif
  return static_cast<double>(m.uordblks) + static_cast<double>(m.hblkhd);
}

// --sizes N,N,...: store sizes in [1, 10^7].
std::string parseSizes(const std::string& text, std::vector<int>* sizes) {
  sizes->clear();  // the default replaced
  std::stringstream ss(text);
  std::string tok;
  while (std::getline(ss, tok, ',')) {
    long long n = 0;
    if (!tools::parseInteger(tok, 1, 10000000, &n)) return "bad --sizes value '" + tok + "'";
    sizes->push_back(static_cast<int>(n));
  }
  if (sizes->empty()) return "--sizes needs at least one size";
  return "";
}

// --hash-mode sorted_dct|haloc|both.
std::string parseModes(const std::string& name, std::vector<core::HashMode>* modes) {
  core::HashMode mode;
  if (name == "both") {
    *modes = {core::HashMode::kSortedDct, core::HashMode::kHaloc};
  } else if (core::parseHashMode(name, &mode)) {
    *modes = {mode};
  } else {
    return "--hash-mode '" + name + "': sorted_dct, haloc or both";
  }
  return "";
}

std::optional<int> parseArguments(int argc, char** argv, Args* a) {
  tools::CommandLine cli("bench_loops", kUsage);
  auto option = cli.add();
  option("session", po::value(&a->sessions));
  option("posidonia", po::value(&a->posidonia));
  option("sizes", tools::checked(&a->sizes, parseSizes));
  option("hash-mode", tools::checked(&a->modes, parseModes));
  if (const auto status = cli.parse(argc, argv)) return status;
  if (a->sessions.empty() || a->sessions.size() % 2 != 0) {
    return cli.bad("sessions come in pairs: --session A --session B per mission (got " +
                   std::to_string(a->sessions.size()) + ")");
  }
  return std::nullopt;
}

// ---------------------------------------------------------------------------------------------
// The pipeline's pieces, with offline_slam's default configuration.

struct Pipeline {
  explicit Pipeline(const std::vector<core::HashMode>& hash_modes) : modes(hash_modes) {
    for (core::HashMode m : modes) hashers.emplace_back(m, odometry.features.num_features, global.projection_seed);
  }
  core::OdometryOptions odometry;
  core::GlobalLoopOptions global;
  /// The loop detector's verification matching (the loops' ratio).
  core::MatchOptions matching() const { return core::loopMatching(odometry.matching, core::LoopOptions()); }
  std::vector<core::HashMode> modes;  // the modes compared; hashes are kept in this order
  std::vector<core::ImageHasher> hashers;
  /// The keyframe hash of every mode, in the order of `modes`.
  std::vector<Eigen::VectorXf> hashes(const cv::Mat& descriptors) const {
    std::vector<Eigen::VectorXf> out;
    for (const auto& h : hashers) out.push_back(h.hash(descriptors));
    return out;
  }
  /// The store the loop detector uses for mode number `m` (its quantisation range).
  core::HashStore store(std::size_t m) const {
    return core::HashStore(modes[m] == core::HashMode::kSortedDct ? 0.25f : 0.5f);
  }
  std::string name(std::size_t m) const {
    return core::hashModeName(modes[m]) + (modes[m] == core::GlobalLoopOptions().hash_mode ? " (default)" : " (paper)");
  }
};

struct Keyframe {
  int frame_index = 0;
  double altitude_m = 0.0;
  core::FrameFeatures features;
  std::vector<Eigen::VectorXf> hashes;  // one per Pipeline::modes
};

struct Session {
  core::Dataset data;
  std::vector<Keyframe> keyframes;
  std::vector<Eigen::VectorXf> frame_hashes;  // every frame (query timing)
  core::OdometryStats stats;
  double odometry_ms = 0.0;
  double hash_ms = 0.0;  // the first mode's hash, summed over the frames
  fs::path truth_dir;    // where its world_gt.csv is (empty: none)
  int world_session = -1;
};

core::View viewOf(const Keyframe& k, const core::CameraIntrinsics& camera) {
  return {&k.features, k.altitude_m, &camera};
}

Eigen::VectorXf timedHash(const Pipeline& p, const core::FrameFeatures& f, double* ms) {
  const auto t0 = Clock::now();
  Eigen::VectorXf h = p.hashers.front().hash(f.descriptors);
  *ms += msSince(t0);
  return h;
}

/// Runs the odometry over the folder as offline_slam does and keeps its keyframes; every frame
/// is also hashed on its own (enhancement + extractor as the odometry) for the timing section.
void runSession(const Pipeline& p, Session* s) {
  core::Odometry odometry(s->data.camera, p.odometry);
  core::FeatureImageEnhancer enhancer(p.odometry.enhancement);
  const core::FeatureExtractor extractor(p.odometry.features);
  for (const auto& f : s->data.frames) {
    const cv::Mat image = cv::imread(s->data.imagePath(f), cv::IMREAD_COLOR);
    const auto t0 = Clock::now();
    odometry.process({f.index, f.stamp_s, f.altitude_m, image});
    s->odometry_ms += msSince(t0);
    for (const auto& kf : odometry.newKeyframes()) {
      const core::KeyframeInfo& info = odometry.keyframes()[kf.id];
      s->keyframes.push_back({info.frame_index, info.altitude_m, kf.features, p.hashes(kf.features.descriptors)});
    }
    if (!image.empty())
      s->frame_hashes.push_back(timedHash(p, extractor.extract(enhancer.enhance(image)), &s->hash_ms));
  }
  s->stats = odometry.stats();
}

// ---------------------------------------------------------------------------------------------
// Verification: the loop detector's rule (RANSAC success with >= min_inliers inliers).

struct Verdict {
  bool accepted = false;
  int inliers = 0;  // 0 when RANSAC failed
  int matches = 0;  // descriptor matches: an upper bound of any consensus
  core::Pose2 motion;
};

Verdict verify(const Pipeline& p, const core::View& a, const core::View& b) {
  const core::PairMotion m = core::estimatePairMotion(a, b, p.matching(), p.odometry.ransac);
  Verdict v;
  v.inliers = m.ransac.success ? static_cast<int>(m.ransac.inliers.size()) : 0;
  v.accepted = m.ransac.success && v.inliers >= p.global.min_inliers;
  v.matches = m.matches;
  v.motion = m.ransac.motion;
  return v;
}

/// The best RANSAC consensus of a rejected pair (a failed RANSAC reports none): the same
/// estimate with the inlier minimum lowered to 3. Diagnostic only, never an acceptance rule.
int consensus(const Pipeline& p, const core::View& a, const core::View& b, const Verdict& v) {
  if (v.inliers > 0) return v.inliers;
  core::RansacOptions relaxed = p.odometry.ransac;
  relaxed.min_inliers = 3;
  const core::PairMotion m = core::estimatePairMotion(a, b, p.matching(), relaxed);
  return m.ransac.success ? static_cast<int>(m.ransac.inliers.size()) : 0;
}

// ---------------------------------------------------------------------------------------------
// Ground truth: world_gt.csv and loops_gt.csv one level above the dataset folders.

using FrameKey = std::pair<int, int>;  // (world session, frame index)

struct WorldTruth {
  std::map<FrameKey, core::Pose2> poses;
  std::set<std::pair<FrameKey, FrameKey>> loops;  // unordered pairs stored with first < second
  bool has_loops = false;
};

std::vector<std::vector<double>> readCsv(const fs::path& path, const std::string& header, std::size_t columns) {
  std::ifstream in(path);
  std::string line;
  auto next = [&in, &line]() {  // one line, CRLF or LF
    if (!std::getline(in, line)) return false;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    return true;
  };
  if (!next() || line != header) throw core::DatasetError(path.string() + ": header is not " + header);
  std::vector<std::vector<double>> rows;
  for (int n = 2; next(); ++n) {
    if (line.empty()) continue;
    std::vector<double> row;
    std::stringstream ss(line);
    for (std::string cell; std::getline(ss, cell, ',');) {
      char* end = nullptr;
      row.push_back(std::strtod(cell.c_str(), &end));
      if (cell.empty() || *end != '\0')
        throw core::DatasetError(path.string() + ":" + std::to_string(n) + ": bad number");
    }
    if (row.size() != columns)
      throw core::DatasetError(path.string() + ":" + std::to_string(n) + ": wrong column count");
    rows.push_back(row);
  }
  return rows;
}

std::pair<FrameKey, FrameKey> unordered(FrameKey a, FrameKey b) {
  return a < b ? std::make_pair(a, b) : std::make_pair(b, a);
}

bool loadWorldTruth(const fs::path& dir, WorldTruth* w) {
  if (!fs::exists(dir / "world_gt.csv")) return false;
  for (const auto& r : readCsv(dir / "world_gt.csv", "session,index,x_m,y_m,yaw_rad", 5)) {
    w->poses[{static_cast<int>(r[0]), static_cast<int>(r[1])}] = core::Pose2(r[2], r[3], r[4]);
  }
  w->has_loops = fs::exists(dir / "loops_gt.csv");
  if (!w->has_loops) return true;
  for (const auto& r : readCsv(dir / "loops_gt.csv", "session_a,index_a,session_b,index_b", 4)) {
    w->loops.insert(
        unordered({static_cast<int>(r[0]), static_cast<int>(r[1])}, {static_cast<int>(r[2]), static_cast<int>(r[3])}));
  }
  return true;
}

/// The world_gt.csv session whose poses, seen from its first frame, are the folder's gt.csv.
int findWorldSession(const core::Dataset& d, const WorldTruth& w) {
  if (d.ground_truth.empty()) return -1;
  std::set<int> ids;
  for (const auto& kv : w.poses) ids.insert(kv.first.first);
  for (int id : ids) {
    const auto origin = w.poses.find({id, d.ground_truth.front().index});
    bool same = origin != w.poses.end();
    for (std::size_t i = 0; same && i < d.ground_truth.size(); ++i) {
      const auto it = w.poses.find({id, d.ground_truth[i].index});
      same = it != w.poses.end() &&
             core::approxEqual(core::between(origin->second, it->second), d.ground_truth[i].pose, 2e-3, 2e-3);
    }
    if (same) return id;
  }
  return -1;
}

// ---------------------------------------------------------------------------------------------
// Section 1: query speed of the hash store.

/// Replicas of the real hashes with Gaussian noise of `sigma` per value, labelled as missions of
/// kEntriesPerSession keyframes (session ids from 1).
void fillStore(const std::vector<Eigen::VectorXf>& base, int size, float sigma, std::mt19937* rng,
               core::HashStore* store) {
  std::normal_distribution<float> noise(0.0f, sigma);
  store->reserve(size);
  for (int i = 0; i < size; ++i) {
    Eigen::VectorXf h = base[i % base.size()];
    if (i >= static_cast<int>(base.size())) {
      for (int j = 0; j < h.size(); ++j) h[j] += noise(*rng);
    }
    store->add({1 + i / kEntriesPerSession, i}, h);
  }
}

float hashValueStd(const std::vector<Eigen::VectorXf>& hashes) {
  double sum = 0.0, sum2 = 0.0, n = 0.0;
  for (const auto& h : hashes) {
    sum += h.cast<double>().sum();
    sum2 += h.cast<double>().squaredNorm();
    n += h.size();
  }
  return static_cast<float>(std::sqrt(std::max(0.0, sum2 / n - (sum / n) * (sum / n))));
}

std::vector<std::string> timeQueries(const std::vector<Eigen::VectorXf>& base, int size, float sigma) {
  std::mt19937 rng(size);
  const double heap0 = heapBytes();
  core::HashStore store;
  fillStore(base, size, sigma, &rng, &store);
  const double heap1 = heapBytes();
  std::normal_distribution<float> noise(0.0f, sigma);
  std::uniform_int_distribution<std::size_t> pick(0, base.size() - 1);
  std::vector<core::HashCandidate> out;
  std::vector<double> ms;
  const float inf = std::numeric_limits<float>::infinity();
  for (int q = -5; q < kTimedQueries; ++q) {  // 5 warm-up queries
    Eigen::VectorXf h = base[pick(rng)];
    for (int j = 0; j < h.size(); ++j) h[j] += noise(rng);
    const auto t0 = Clock::now();
    store.query(h, 0, kQueryK, inf, &out);  // session 0: the current mission, none of it stored
    if (q >= 0) ms.push_back(msSince(t0));
  }
  const double target = size == 10000 ? 1.0 : size == 100000 ? 10.0 : 0.0;
  const double layout = core::HalocProjections::kHashSize + sizeof(core::HashEntry);
  return {std::to_string(size),
          fmt(median(ms), 3),
          fmt(*std::max_element(ms.begin(), ms.end()), 3),
          target > 0 ? "<= " + fmt(target, 0) : "-",
          target > 0 ? (median(ms) <= target ? "yes" : "no") : "-",
          fmt(layout, 0),
          fmt((heap1 - heap0) / size, 0),
          fmt(size * layout / 1e6, 1)};
}

void benchQueries(const std::vector<Session>& sessions, const std::vector<Eigen::VectorXf>& extra,
                  const std::vector<int>& sizes, const std::string& mode) {
  std::vector<Eigen::VectorXf> base;
  double hash_ms = 0.0;
  for (const auto& s : sessions) {
    base.insert(base.end(), s.frame_hashes.begin(), s.frame_hashes.end());
    hash_ms += s.hash_ms;
  }
  const std::size_t hashed_frames = base.size();
  base.insert(base.end(), extra.begin(), extra.end());
  if (base.empty()) throw core::DatasetError("no readable image to hash");
  const float sigma = static_cast<float>(kPerturbation) * hashValueStd(base);
  std::printf("## 1. Hash query speed (HashStore::query, best k = %d, one core)\n\n", kQueryK);
  std::printf(
      "%zu real hashes (every frame of the --session folders: %zu, plus %zu --posidonia images), replicated with "
      "Gaussian noise of sigma %.4f per value (%.0f %% of the hash values' std %.4f, ~%.1f quantisation steps) to "
      "reach each size. Entries labelled as missions of %d keyframes; the query excludes session 0 (the current "
      "mission, not stored), so every entry is compared. %d timed queries (perturbed real hashes) after 5 warm-up. "
      "Bytes/entry: layout = 384 B code + %zu B HashEntry; heap = malloc'd bytes (glibc mallinfo2) the filled store "
      "added / entries. "
      "Hash (%s): %.3f ms per image (mean over %zu).\n\n",
      base.size(), hashed_frames, extra.size(), sigma, kPerturbation * 100, sigma / kPerturbation, sigma / kQuantStep,
      kEntriesPerSession, kTimedQueries, sizeof(core::HashEntry), mode.c_str(),
      hashed_frames ? hash_ms / hashed_frames : 0.0, hashed_frames);
  std::vector<std::vector<std::string>> rows;
  for (int size : sizes) rows.push_back(timeQueries(base, size, sigma));
  printTable({"entries", "median ms", "max ms", "target ms", "median within target", "bytes/entry (layout)",
              "bytes/entry (heap)", "store MB"},
             rows);
}

// ---------------------------------------------------------------------------------------------
// Section 2: HALOC against brute force on a two-session mission.

struct Loop {
  int a = 0, b = 0;  // keyframe positions in sessions A and B
  int inliers = 0;
  core::Pose2 motion;  // pose of B's keyframe in A's
};

struct MethodRun {
  std::string name;
  int k = 0;  // candidates per keyframe (0: all, brute force)
  long candidates = 0;
  double query_ms = 0.0, verify_ms = 0.0;
  std::vector<Loop> loops;
};

struct Mission {
  const Session* a;
  const Session* b;
  const WorldTruth* truth;  // null without world_gt.csv for both sessions
};

/// For every keyframe of B: the best k of A by the hash of mode number `mode`, each verified.
MethodRun runHash(const Pipeline& p, const Mission& m, std::size_t mode, int k) {
  core::HashStore store = p.store(mode);
  for (std::size_t i = 0; i < m.a->keyframes.size(); ++i)
    store.add({0, static_cast<int>(i)}, m.a->keyframes[i].hashes[mode]);
  MethodRun run{p.name(mode) + " k = " + std::to_string(k), k, 0, 0.0, 0.0, {}};
  std::vector<core::HashCandidate> cands;
  for (std::size_t j = 0; j < m.b->keyframes.size(); ++j) {
    const Keyframe& kb = m.b->keyframes[j];
    auto t0 = Clock::now();
    store.query(kb.hashes[mode], 1, k, std::numeric_limits<float>::infinity(), &cands);
    run.query_ms += msSince(t0);
    t0 = Clock::now();
    for (const auto& c : cands) {
      const Keyframe& ka = m.a->keyframes[store.entry(c.entry).keyframe];
      const Verdict v = verify(p, viewOf(ka, m.a->data.camera), viewOf(kb, m.b->data.camera));
      if (v.accepted) run.loops.push_back({store.entry(c.entry).keyframe, static_cast<int>(j), v.inliers, v.motion});
    }
    run.verify_ms += msSince(t0);
    run.candidates += static_cast<long>(cands.size());
  }
  return run;
}

/// For every keyframe of B: every keyframe of A, verified.
MethodRun runBruteForce(const Pipeline& p, const Mission& m) {
  MethodRun run{"brute force", 0, 0, 0.0, 0.0, {}};
  const auto t0 = Clock::now();
  for (std::size_t j = 0; j < m.b->keyframes.size(); ++j) {
    for (std::size_t i = 0; i < m.a->keyframes.size(); ++i) {
      const Verdict v =
          verify(p, viewOf(m.a->keyframes[i], m.a->data.camera), viewOf(m.b->keyframes[j], m.b->data.camera));
      if (v.accepted) run.loops.push_back({static_cast<int>(i), static_cast<int>(j), v.inliers, v.motion});
    }
  }
  run.candidates = static_cast<long>(m.a->keyframes.size() * m.b->keyframes.size());
  run.verify_ms = msSince(t0);
  return run;
}

double footprintHeight(const core::CameraIntrinsics& c, double altitude_m) { return c.height * altitude_m / c.fy; }

/// Error of a loop's measured pose against the ground truth: (translation m, |yaw| rad, limit m).
std::tuple<double, double, double> loopError(const Mission& m, const Loop& l) {
  const Keyframe& ka = m.a->keyframes[l.a];
  const Keyframe& kb = m.b->keyframes[l.b];
  const core::Pose2 truth = core::between(m.truth->poses.at({m.a->world_session, ka.frame_index}),
                                          m.truth->poses.at({m.b->world_session, kb.frame_index}));
  const double limit =
      0.5 * (footprintHeight(m.a->data.camera, ka.altitude_m) + footprintHeight(m.b->data.camera, kb.altitude_m));
  return {(l.motion.translation() - truth.translation()).norm(),
          std::abs(core::normalizeAngle(l.motion.yaw() - truth.yaw())), limit};
}

bool isCorrect(const Mission& m, const Loop& l) {
  const auto [dt, dyaw, footprint] = loopError(m, l);
  return dt < 0.1 * footprint && dyaw < 5.0 * M_PI / 180.0;
}

/// loops_gt.csv pairs between A and B whose two frames are keyframes, as (A position, B position).
std::set<std::pair<int, int>> truthPairs(const Mission& m) {
  std::set<std::pair<int, int>> pairs;
  if (!m.truth || !m.truth->has_loops) return pairs;
  for (std::size_t i = 0; i < m.a->keyframes.size(); ++i) {
    for (std::size_t j = 0; j < m.b->keyframes.size(); ++j) {
      const FrameKey ka{m.a->world_session, m.a->keyframes[i].frame_index};
      const FrameKey kb{m.b->world_session, m.b->keyframes[j].frame_index};
      if (m.truth->loops.count(unordered(ka, kb))) pairs.insert({static_cast<int>(i), static_cast<int>(j)});
    }
  }
  return pairs;
}

/// Brute-force correct loops that k candidates drawn at random from A would hit, on average.
double chanceFound(const Mission& m, int k, const std::set<std::pair<int, int>>& bf_correct) {
  const double n = static_cast<double>(m.a->keyframes.size());
  return static_cast<double>(bf_correct.size()) * std::min(static_cast<double>(k), n) / n;
}

std::vector<std::string> methodRow(const Mission& m, const MethodRun& r, const std::set<std::pair<int, int>>& gt,
                                   const std::set<std::pair<int, int>>& bf_correct) {
  const bool judged = m.truth != nullptr;
  int correct = 0, found = 0, of_bf = 0;
  std::set<int> with_loop;  // B keyframes with a correct (unjudged: an accepted) loop
  for (const Loop& l : r.loops) {
    const bool ok = judged && isCorrect(m, l);
    correct += ok;
    if (ok || !judged) with_loop.insert(l.b);
    if (gt.count({l.a, l.b})) ++found;
    if (bf_correct.count({l.a, l.b})) ++of_bf;
  }
  const int n = static_cast<int>(m.b->keyframes.size());
  const int accepted = static_cast<int>(r.loops.size());
  const bool has_gt = judged && m.truth->has_loops;
  return {r.name,
          std::to_string(r.candidates),
          std::to_string(accepted),
          judged ? std::to_string(correct) : "n/a",
          judged ? std::to_string(accepted - correct) : "n/a",
          judged ? ratio(correct, accepted) : "n/a",
          has_gt ? std::to_string(found) + " / " + std::to_string(gt.size()) : "n/a",
          has_gt ? ratio(found, static_cast<int>(gt.size())) : "n/a",
          judged ? std::to_string(of_bf) + " / " + std::to_string(bf_correct.size()) : "n/a",
          judged && r.k > 0 ? fmt(chanceFound(m, r.k, bf_correct), 1) : "-",
          std::to_string(with_loop.size()) + " / " + std::to_string(n),
          r.name == "brute force" ? "-" : fmt(r.query_ms / n, 3),
          fmt((r.query_ms + r.verify_ms) / n, 1),
          fmt(r.query_ms + r.verify_ms, 0)};
}

void printWrongLoops(const Mission& m, const std::vector<MethodRun>& runs) {
  std::vector<std::vector<std::string>> rows;
  for (const MethodRun& r : runs) {
    for (const Loop& l : r.loops) {
      if (isCorrect(m, l)) continue;
      const auto [dt, dyaw, footprint] = loopError(m, l);
      rows.push_back({r.name, std::to_string(m.a->keyframes[l.a].frame_index),
                      std::to_string(m.b->keyframes[l.b].frame_index), std::to_string(l.inliers), fmt(dt, 3),
                      fmt(dt / footprint * 100.0, 1), fmt(dyaw * 180.0 / M_PI, 2)});
    }
  }
  if (rows.empty()) {
    std::puts("Every accepted loop is within 10 % of the footprint height and 5 deg of the ground truth.\n");
    return;
  }
  std::puts("Loops outside the tolerance (frame indexes in frames.csv):\n");
  printTable({"method", "A frame", "B frame", "inliers", "error m", "error % footprint", "yaw error deg"}, rows);
}

std::string rankSummary(std::vector<int> ranks) {
  std::sort(ranks.begin(), ranks.end());
  auto within = [&ranks](int k) { return std::upper_bound(ranks.begin(), ranks.end(), k) - ranks.begin(); };
  std::ostringstream os;
  os << "median " << ranks[ranks.size() / 2] << ", within 5 / 10 / 20: " << within(5) << " / " << within(10) << " / "
     << within(20) << " of " << ranks.size();
  return os.str();
}

/// Where the correct brute-force loops rank by the hash of mode number `mode` among all of A's keyframes.
void printHashRanks(const Pipeline& p, const Mission& m, const std::set<std::pair<int, int>>& bf_correct,
                    std::size_t mode) {
  core::HashStore store = p.store(mode);
  for (std::size_t i = 0; i < m.a->keyframes.size(); ++i)
    store.add({0, static_cast<int>(i)}, m.a->keyframes[i].hashes[mode]);
  std::vector<core::HashCandidate> all;
  std::map<int, int> best;  // B keyframe -> best rank of its correct loops
  std::vector<int> ranks;
  for (const auto& [a, b] : bf_correct) {
    const float inf = std::numeric_limits<float>::infinity();
    store.query(m.b->keyframes[b].hashes[mode], 1, static_cast<int>(store.size()), inf, &all);
    const auto it =
        std::find_if(all.begin(), all.end(), [a = a](const core::HashCandidate& c) { return c.entry == a; });
    const int rank = static_cast<int>(it - all.begin()) + 1;
    ranks.push_back(rank);
    best[b] = best.count(b) ? std::min(best[b], rank) : rank;
  }
  std::vector<int> best_ranks;
  for (const auto& kv : best) best_ranks.push_back(kv.second);
  std::printf(
      "%s hash rank (1 = nearest of A's %zu keyframes by L1) of the correct brute-force loops: %s pairs; the best "
      "rank per B keyframe that has one: %s keyframes.\n\n",
      p.name(mode).c_str(), m.a->keyframes.size(), rankSummary(ranks).c_str(), rankSummary(best_ranks).c_str());
}

void benchMission(const Pipeline& p, const Mission& m, int number) {
  std::printf("### Mission %d: A = %s (%zu keyframes), B = %s (%zu keyframes)\n\n", number, m.a->data.directory.c_str(),
              m.a->keyframes.size(), m.b->data.directory.c_str(), m.b->keyframes.size());
  std::vector<MethodRun> runs;
  for (std::size_t mode = 0; mode < p.modes.size(); ++mode)
    for (int k : kBestK) runs.push_back(runHash(p, m, mode, k));
  runs.push_back(runBruteForce(p, m));
  const auto gt = truthPairs(m);
  std::set<std::pair<int, int>> bf_correct;
  for (const Loop& l : runs.back().loops) {
    if (m.truth && isCorrect(m, l)) bf_correct.insert({l.a, l.b});
  }
  std::vector<std::vector<std::string>> rows;
  for (const MethodRun& r : runs) rows.push_back(methodRow(m, r, gt, bf_correct));
  printTable({"method", "candidates verified", "accepted", "correct", "wrong", "precision", "gt pairs found", "recall",
              "brute-force correct found", "same with k random candidates", "B kf with a loop", "query ms/kf", "ms/kf",
              "total ms"},
             rows);
  if (m.truth) printWrongLoops(m, runs);
  for (std::size_t mode = 0; !bf_correct.empty() && mode < p.modes.size(); ++mode) {
    printHashRanks(p, m, bf_correct, mode);
  }
}

void benchMissions(const Pipeline& p, const std::vector<Session>& sessions, const std::vector<WorldTruth>& truths) {
  std::string names;
  for (std::size_t mode = 0; mode < p.modes.size(); ++mode) names += (mode ? ", " : "") + p.name(mode);
  std::printf("## 2. Hash best-k (%s) against brute force (loops from B's keyframes to A's)\n\n", names.c_str());
  std::printf(
      "Keyframes from the odometry (default OdometryOptions). A loop is accepted when RANSAC (the odometry's "
      "MatchOptions/RansacOptions) succeeds with >= %d inliers; it is correct when its measured pose of B's "
      "keyframe in A's is within 10 %% of the footprint height (image_height * altitude / fy, mean of the two) "
      "and 5 deg of the world_gt.csv relative pose. Recall: accepted pairs among the loops_gt.csv pairs between A "
      "and B whose two frames are keyframes. `brute-force correct found`: of the correct brute-force loops, those "
      "this method accepted too; `same with k random candidates`: the expected count if the k candidates were "
      "drawn at random from A's keyframes instead of by hash (chance level). `B kf with a loop`: B keyframes with "
      "at least one correct accepted loop. ms/kf: hash query + verification per keyframe of B, one core.\n\n",
      p.global.min_inliers);
  for (std::size_t i = 0; i + 1 < sessions.size(); i += 2) {
    const Session& a = sessions[i];
    const Session& b = sessions[i + 1];
    const bool judged = a.world_session >= 0 && b.world_session >= 0 && a.truth_dir == b.truth_dir;
    benchMission(p, {&a, &b, judged ? &truths[i] : nullptr}, static_cast<int>(i / 2) + 1);
  }
}

// ---------------------------------------------------------------------------------------------
// Section 3: negatives.

struct Negative {
  std::string name;
  core::CameraIntrinsics camera;
  Keyframe view;
};

std::vector<Negative> loadNegatives(const Pipeline& p, const std::string& dir) {
  std::vector<fs::path> files;
  for (const auto& e : fs::directory_iterator(dir)) {
    std::string ext = e.path().extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(), ::tolower);
    if (ext == ".jpg" || ext == ".jpeg" || ext == ".png") files.push_back(e.path());
  }
  if (files.empty()) throw core::DatasetError(dir + ": no jpg/png image");
  std::sort(files.begin(), files.end());
  core::FeatureImageEnhancer enhancer(p.odometry.enhancement);
  const core::FeatureExtractor extractor(p.odometry.features);
  std::vector<Negative> out;
  for (const auto& f : files) {
    const cv::Mat image = cv::imread(f.string(), cv::IMREAD_COLOR);
    if (image.empty()) throw core::DatasetError(f.string() + ": cannot decode image");
    Negative n;
    n.name = f.filename().string();
    n.camera = {image.cols, image.rows, kPosidoniaFocal, kPosidoniaFocal, image.cols / 2.0, image.rows / 2.0};
    n.view.altitude_m = kPosidoniaAltitude;
    n.view.features = extractor.extract(enhancer.enhance(image));
    n.view.hashes = p.hashes(n.view.features.descriptors);
    out.push_back(std::move(n));
  }
  return out;
}

struct NegativeRun {
  std::string name;
  long candidates = 0;
  double ms = 0.0;
  std::vector<std::string> accepted;  // "image / folder frame (inliers)"
  int best_rejected = 0;
  std::string best_pair;
  int most_matches = 0;  // among rejected candidates
};

struct StoredKeyframe {
  const Session* session;
  const Keyframe* keyframe;
};

void checkNegative(const Pipeline& p, const Negative& n, const StoredKeyframe& s, NegativeRun* run) {
  const core::View a = viewOf(*s.keyframe, s.session->data.camera);
  const core::View b = viewOf(n.view, n.camera);
  const Verdict v = verify(p, a, b);
  ++run->candidates;
  const std::string pair =
      n.name + " / " + s.session->data.directory + " frame " + std::to_string(s.keyframe->frame_index);
  if (v.accepted) {
    run->accepted.push_back(pair + " (" + std::to_string(v.inliers) + " inliers)");
    return;
  }
  run->most_matches = std::max(run->most_matches, v.matches);
  const int c = consensus(p, a, b, v);
  if (c > run->best_rejected) {
    run->best_rejected = c;
    run->best_pair = pair;
  }
}

void benchNegatives(const Pipeline& p, const std::vector<Session>& sessions, const std::vector<Negative>& negatives) {
  std::vector<StoredKeyframe> stored;
  std::set<std::string> seen;
  for (const Session& s : sessions) {
    if (!seen.insert(fs::weakly_canonical(s.data.directory).string()).second) continue;
    for (const Keyframe& k : s.keyframes) stored.push_back({&s, &k});
  }
  std::vector<NegativeRun> runs;
  std::vector<core::HashCandidate> cands;
  for (std::size_t mode = 0; mode < p.modes.size(); ++mode) {
    core::HashStore store = p.store(mode);
    for (std::size_t i = 0; i < stored.size(); ++i) {
      store.add({0, static_cast<int>(i)}, stored[i].keyframe->hashes[mode]);
    }
    runs.push_back({p.name(mode) + " k = " + std::to_string(kQueryK), 0, 0.0, {}, 0, "-"});
    for (const Negative& n : negatives) {
      const auto t0 = Clock::now();
      store.query(n.view.hashes[mode], 1, kQueryK, std::numeric_limits<float>::infinity(), &cands);
      for (const auto& c : cands) checkNegative(p, n, stored[c.entry], &runs.back());
      runs.back().ms += msSince(t0);
    }
  }
  runs.push_back({"brute force", 0, 0.0, {}, 0, "-"});
  for (const Negative& n : negatives) {
    const auto t0 = Clock::now();
    for (const auto& s : stored) checkNegative(p, n, s, &runs.back());
    runs.back().ms += msSince(t0);
  }
  std::printf("## 3. Negatives: %zu unrelated images against %zu mission keyframes\n\n", negatives.size(),
              stored.size());
  std::printf(
      "Each image is a single-frame view (altitude %.0f m, fx = fy = %.0f, principal point at the image centre), "
      "features and hash as the odometry's keyframes. Any accepted loop is false. `highest rejected`: the largest "
      "RANSAC consensus among rejected candidates (a failed RANSAC is re-run with the inlier minimum lowered to 3 "
      "to measure it; diagnostic only), against the %d-inlier threshold; `most matches`: the largest number of "
      "descriptor matches (ratio and mutual test) of a rejected candidate, a bound on any consensus. Time includes "
      "that diagnostic re-run.\n\n",
      kPosidoniaAltitude, kPosidoniaFocal, p.global.min_inliers);
  std::vector<std::vector<std::string>> rows;
  for (const NegativeRun* r = runs.data(); r != runs.data() + runs.size(); ++r) {
    rows.push_back({r->name, std::to_string(r->candidates), std::to_string(r->accepted.size()),
                    std::to_string(r->best_rejected), std::to_string(p.global.min_inliers - r->best_rejected),
                    r->best_pair, std::to_string(r->most_matches), fmt(r->ms / negatives.size(), 1)});
  }
  printTable({"method", "candidates verified", "accepted (false loops)", "highest rejected inliers",
              "margin to threshold", "highest rejected pair", "most matches (rejected)", "ms/query"},
             rows);
  for (const NegativeRun& r0 : runs) {
    const NegativeRun* r = &r0;
    for (const auto& a : r->accepted) std::printf("- false loop (%s): %s\n", r->name.c_str(), a.c_str());
  }
}

// ---------------------------------------------------------------------------------------------

void printSessions(const std::vector<Session>& sessions) {
  std::puts("## Sessions\n");
  std::vector<std::vector<std::string>> rows;
  for (std::size_t i = 0; i < sessions.size(); ++i) {
    const Session& s = sessions[i];
    rows.push_back({std::to_string(i), s.data.directory, std::to_string(s.stats.frames),
                    std::to_string(s.keyframes.size()), std::to_string(s.stats.fallbacks),
                    s.world_session >= 0 ? std::to_string(s.world_session) : "n/a",
                    fmt(s.odometry_ms / std::max(1, s.stats.frames), 1)});
  }
  printTable({"#", "folder", "frames", "keyframes", "fallbacks", "world_gt session", "odometry ms/frame"}, rows);
}

int run(const Args& args) {
  cv::setNumThreads(1);
  const Pipeline p(args.modes);
  // Check every input before any work.
  std::vector<Session> sessions(args.sessions.size());
  std::vector<WorldTruth> truths(args.sessions.size());
  for (std::size_t i = 0; i < args.sessions.size(); ++i) {
    sessions[i].data = core::loadDataset(args.sessions[i]);
    const fs::path dir = fs::path(args.sessions[i]).lexically_normal();
    const fs::path up = (dir.has_filename() ? dir : dir.parent_path()).parent_path();
    if (loadWorldTruth(up, &truths[i])) {
      sessions[i].truth_dir = up;
      sessions[i].world_session = findWorldSession(sessions[i].data, truths[i]);
    }
  }
  if (!args.posidonia.empty() && !fs::is_directory(args.posidonia)) {
    throw core::DatasetError(args.posidonia + ": not a directory");
  }
  const std::vector<Negative> negatives =
      args.posidonia.empty() ? std::vector<Negative>{} : loadNegatives(p, args.posidonia);
  for (std::size_t i = 0; i < sessions.size(); ++i) {
    std::fprintf(stderr, "bench_loops: odometry over %s\n", args.sessions[i].c_str());
    runSession(p, &sessions[i]);
  }
  std::puts("# bench_loops\n");
  printSessions(sessions);
  std::vector<Eigen::VectorXf> extra;
  for (const auto& n : negatives) extra.push_back(n.view.hashes.front());
  benchQueries(sessions, extra, args.sizes, p.name(0));
  benchMissions(p, sessions, truths);
  if (!negatives.empty()) benchNegatives(p, sessions, negatives);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  Args args;
  if (const auto status = parseArguments(argc, argv, &args)) return *status;
  try {
    return run(args);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_loops: %s\n", e.what());
    return 1;
  }
}
