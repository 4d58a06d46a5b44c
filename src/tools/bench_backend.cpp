// bench_backend: back-end benchmark (paper 000 §8, §9, its Table 3). A benchmark, not a test: it
// prints numbers and asserts nothing. Two modes:
//
//   --robustness --mission DIR   the paper's Table 3: the ground truth of a generated mission
//       (world_gt.csv, loops_gt.csv) with its odometry corrupted at five noise levels (2σ from
//       5 cm / 5° to 25 cm / 25° per motion), every ground-truth loop measured with 1 cm / 0.5°
//       noise, `--runs` seeds per level, joined with K = 1, 10, 20, 30 loops, by both optimisers.
//       Prints mean ± σ of the errors before (odometry) and after SLAM.
//   --outliers P[,P...] --mission DIR   wrong loops: the mission's ground-truth loops
//       (1 cm / 0.5° noise, 30-120 inliers) plus P % as many wrong ones (random keyframe pairs of
//       different sessions, 30-120 inliers, poses off by 2-5 m and any yaw), odometry 2σ = 1 cm /
//       1°, both join policies, the sparse optimiser; prints map ATE, wrong loops kept, joins.
//   --cost N --loops L --optimizer iekf|sparse   one synthetic single-session survey of N
//       keyframes (rows of 50 keyframes 0.5 m apart, 1 cm / 0.5° odometry noise) with L loops
//       between neighbouring rows; prints the time to add the motions, to optimise with all the
//       loops at once, to re-optimise after one more loop, and the peak resident memory. Run
//       once per process (scripts/bench_backend.sh) so that the peak memory is this case's.
#include <sys/resource.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <random>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "cli.h"

#include "uw_multislam/core/backend/backend.h"
#include "uw_multislam/core/frontend/dataset.h"

namespace core = uw_multislam::core;
namespace fs = std::filesystem;
namespace po = boost::program_options;
namespace tools = uw_multislam::tools;
using Clock = std::chrono::steady_clock;

namespace {

const char* kUsage = R"(usage: bench_backend --robustness --mission DIR [--runs N]
       bench_backend --outliers P[,P...] --mission DIR [--runs N] [--optimizer sparse|iekf]
       bench_backend --cost N --loops L --optimizer iekf|sparse

--robustness: Table 3 of the paper on a generated mission (make_survey output: world_gt.csv and
  loops_gt.csv): odometry corrupted with 2σ = 5, 10, 15, 20, 25 cm and degrees per motion, loops
  from the ground truth with 1 cm / 0.5° noise, K = 1, 10, 20, 30, both optimisers, N runs per
  level (default 20). Errors in metres, mean ± σ over the runs:
    odo e_k    the paper's e_k (35) of the odometry over the intra-session loop pairs
    e_k intra  the same after SLAM
    e_k inter  over the inter-session pairs, in the joined map (only runs that joined)
    map ATE    every keyframe in the joined map's frame vs the ground truth in that frame
--outliers: the same mission with its true loops and P % wrong ones added (e.g. 0,10,30,50):
  random keyframe pairs of different sessions (before a join they meet the join's policy, after
  it the gates inside the map) with plausible inlier counts whose measured pose is 2-5 m and any
  yaw off; odometry 2σ = 1 cm / 1°; join_policy count (K = 5, gate 0.5 m) and consistent; the
  sparse optimiser (Huber on loops) or --optimizer iekf; backend defaults otherwise. Mean over N
  runs (default 5) of the map ATE (runs that joined); the ATE change against the same run (same
  odometry, same true loops) without the wrong loops, mean and max over the runs; the wrong loops
  kept (not refused), the true loops refused, the joins made and refused; "wrong joins" counts
  runs whose map ATE exceeds 1 m.
--cost: time and peak memory of one optimiser on a synthetic survey of N keyframes, L loops.)";

double ms(Clock::time_point a, Clock::time_point b) { return std::chrono::duration<double, std::milli>(b - a).count(); }

long peakRssKb() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return u.ru_maxrss;
}

Eigen::Matrix3d diag(double sxy, double syaw) {
  return Eigen::Vector3d(sxy * sxy, sxy * sxy, syaw * syaw).asDiagonal();
}

struct Mission {
  std::vector<std::vector<core::Pose2>> sessions;                          // world poses, every frame a keyframe
  std::vector<std::pair<std::pair<int, int>, std::pair<int, int>>> loops;  // (session, keyframe) pairs
};

std::vector<std::map<std::string, std::string>> readCsv(const fs::path& p) {
  const std::string text = core::readTextFile(p.string());
  std::istringstream in(text);
  std::string line, cell;
  std::getline(in, line);
  std::vector<std::string> header;
  std::istringstream h(line);
  while (std::getline(h, cell, ',')) header.push_back(cell);
  std::vector<std::map<std::string, std::string>> rows;
  while (std::getline(in, line)) {
    if (line.empty()) continue;
    std::istringstream r(line);
    std::map<std::string, std::string> row;
    for (const auto& key : header) {
      std::getline(r, cell, ',');
      row[key] = cell;
    }
    rows.push_back(row);
  }
  return rows;
}

Mission loadMission(const fs::path& dir) {
  Mission m;
  std::map<std::pair<int, int>, int> keyframe;  // (session, frame index) -> keyframe
  for (const auto& r : readCsv(dir / "world_gt.csv")) {
    const int s = std::stoi(r.at("session"));
    if (s >= static_cast<int>(m.sessions.size())) m.sessions.resize(s + 1);
    keyframe[{s, std::stoi(r.at("index"))}] = static_cast<int>(m.sessions[s].size());
    m.sessions[s].emplace_back(std::stod(r.at("x_m")), std::stod(r.at("y_m")), std::stod(r.at("yaw_rad")));
  }
  for (const auto& r : readCsv(dir / "loops_gt.csv")) {
    const std::pair<int, int> a{std::stoi(r.at("session_a")), std::stoi(r.at("index_a"))};
    const std::pair<int, int> b{std::stoi(r.at("session_b")), std::stoi(r.at("index_b"))};
    m.loops.push_back({{a.first, keyframe.at(a)}, {b.first, keyframe.at(b)}});
  }
  return m;
}

struct RunErrors {
  double odo_ek = 0, ek_intra = 0, ek_inter = NAN, map_ate = NAN, ms = 0;
  bool joined = false;
  int wrong = 0, wrong_kept = 0, true_refused = 0, joins = 0, joins_refused = 0;
};

// One run's set-up beyond the noise level: the join rule and the wrong loops to add.
struct RunSpec {
  int k_join = 5;
  core::OptimizerKind optimizer = core::OptimizerKind::kSparse;
  core::JoinPolicy policy = core::JoinPolicy::kCount;
  double outlier_fraction = 0.0;  // wrong loops per true loop
  bool true_loops_only = true;    // --robustness: no gate (the loops are true)
};

double ekOver(const std::vector<std::vector<core::Pose2>>& est, const Mission& m, bool inter) {
  double sum = 0;
  int n = 0;
  for (const auto& l : m.loops) {
    const auto [a, b] = l;
    if ((a.first != b.first) != inter) continue;
    const core::Pose2 e = core::between(est[a.first][a.second], est[b.first][b.second]);
    const core::Pose2 g = core::between(m.sessions[a.first][a.second], m.sessions[b.first][b.second]);
    sum += (e.translation() - g.translation()).norm();
    ++n;
  }
  return n ? sum / n : NAN;
}

RunErrors runOnce(const Mission& m, double level, const RunSpec& spec, unsigned seed) {
  std::mt19937 rng(seed);
  // The wrong loops draw from their own generator, so that a run with them and the run without
  // (same seed) have the same odometry and true loops: the ATE change is theirs alone.
  std::mt19937 rng_wrong(seed ^ 0x5bd1e995u);
  std::normal_distribution<double> n01(0.0, 1.0), n01_wrong(0.0, 1.0);
  std::uniform_int_distribution<int> inliers(30, 120), inliers_wrong(30, 120);
  const double s_xy = 0.5 * level, s_yaw = 0.5 * level * 100.0 * M_PI / 180.0;  // 2σ = level m, level*100 deg
  const double l_xy = 0.01, l_yaw = 0.5 * M_PI / 180.0;
  core::BackendOptions o;
  o.optimizer = spec.optimizer;
  o.join_min_loops = spec.k_join;
  o.join_policy = spec.policy;
  o.optimise_every = 1;
  if (spec.true_loops_only) o.join_gate_m = 1e9;  // the loops are true: measure the optimiser, not the gate
  o.max_keyframes = 100000;
  // UWMS_BENCH_ENTRY_INFLATION=F: intra_gate_inflation and iekf_gate_inflation F (0: the entry
  // gate off), for experiments.
  if (const char* f = std::getenv("UWMS_BENCH_ENTRY_INFLATION")) {
    o.intra_gate_inflation = o.iekf_gate_inflation = std::max(1.0, std::atof(f));
    o.intra_loop_gate = std::atof(f) > 0;
  }
  // UWMS_BENCH_RESIDUAL_INFLATION=F: residual_gate_inflation F, for experiments.
  if (const char* f = std::getenv("UWMS_BENCH_RESIDUAL_INFLATION"))
    o.residual_gate_inflation = std::max(1.0, std::atof(f));
  // UWMS_BENCH_READMIT=0: readmit_refused_loops off, for comparison.
  if (const char* f = std::getenv("UWMS_BENCH_READMIT")) o.readmit_refused_loops = std::atoi(f) != 0;
  // UWMS_BENCH_LOG=1: the back-end's log (joins, refused and switched-off loops) on stderr.
  core::MultiSessionBackend::Log log;
  if (std::getenv("UWMS_BENCH_LOG") != nullptr)
    log = [](const std::string& l) { std::fprintf(stderr, "%s\n", l.c_str()); };
  core::MultiSessionBackend b(o, log);
  // The loops, true ones first, then the wrong ones: random keyframe pairs, 2-5 m and any yaw off.
  auto loops = m.loops;
  const std::size_t n_true = loops.size();
  std::vector<core::Pose2> wrong_offset;
  const int n_wrong = static_cast<int>(std::lround(spec.outlier_fraction * static_cast<double>(n_true)));
  for (int w = 0; w < n_wrong; ++w) {
    std::pair<int, int> a, c;
    do {
      a.first = std::uniform_int_distribution<int>(0, static_cast<int>(m.sessions.size()) - 1)(rng_wrong);
      c.first = std::uniform_int_distribution<int>(0, static_cast<int>(m.sessions.size()) - 1)(rng_wrong);
      a.second = std::uniform_int_distribution<int>(0, static_cast<int>(m.sessions[a.first].size()) - 1)(rng_wrong);
      c.second = std::uniform_int_distribution<int>(0, static_cast<int>(m.sessions[c.first].size()) - 1)(rng_wrong);
      if (a > c) std::swap(a, c);
    } while (a.first == c.first);  // between sessions: the join's question (intra-map ones: see --help)
    loops.push_back({a, c});
    const double r = std::uniform_real_distribution<double>(2.0, 5.0)(rng_wrong);
    const double th = std::uniform_real_distribution<double>(-M_PI, M_PI)(rng_wrong);
    wrong_offset.emplace_back(r * std::cos(th), r * std::sin(th),
                              std::uniform_real_distribution<double>(-M_PI, M_PI)(rng_wrong));
  }
  // Loops indexed by their later end, added when that keyframe arrives.
  std::map<std::pair<int, int>, std::vector<std::size_t>> at;
  for (std::size_t i = 0; i < loops.size(); ++i) at[loops[i].second].push_back(i);
  std::vector<bool> is_wrong;  // per loop as added to the back-end
  std::vector<std::vector<core::Pose2>> odo(m.sessions.size());
  RunErrors r;
  const auto t0 = Clock::now();
  for (int s = 0; s < static_cast<int>(m.sessions.size()); ++s) {
    const int id = b.startSession();
    odo[s].push_back(core::Pose2());
    for (int k = 0; k < static_cast<int>(m.sessions[s].size()); ++k) {
      if (k > 0) {
        const core::Pose2 t = core::between(m.sessions[s][k - 1], m.sessions[s][k]);
        const core::Pose2 z(t.x() + s_xy * n01(rng), t.y() + s_xy * n01(rng), t.yaw() + s_yaw * n01(rng));
        b.addMotion(id, core::UncertainPose2(z, diag(s_xy, s_yaw)));
        odo[s].push_back(core::compose(odo[s].back(), z));
      }
      for (std::size_t i : at[{s, k}]) {
        const auto [a, c] = loops[i];
        core::Pose2 t = core::between(m.sessions[a.first][a.second], m.sessions[c.first][c.second]);
        if (i >= n_true) t = core::compose(t, wrong_offset[i - n_true]);
        // Own distributions too: std::normal_distribution caches its second draw.
        const bool w = i >= n_true;
        auto noise = [&]() { return w ? n01_wrong(rng_wrong) : n01(rng); };
        const double ex = noise(), ey = noise(), eyaw = noise();
        const core::Pose2 z(t.x() + l_xy * ex, t.y() + l_xy * ey, t.yaw() + l_yaw * eyaw);
        b.addLoop({a.first, a.second, c.first, c.second, core::UncertainPose2(z, diag(l_xy, l_yaw)),
                   w ? inliers_wrong(rng_wrong) : inliers(rng)});
        is_wrong.push_back(i >= n_true);
      }
    }
    b.endSession(id);
  }
  b.flush();
  r.ms = ms(t0, Clock::now());
  std::vector<std::vector<core::Pose2>> est;
  for (int s = 0; s < b.numSessions(); ++s) est.push_back(b.sessionPoses(s));
  r.odo_ek = ekOver(odo, m, false);
  r.ek_intra = ekOver(est, m, false);
  r.joined = b.mapIds().size() == 1;
  r.joins = b.stats().joins;
  r.joins_refused = b.stats().joins_refused;
  for (std::size_t i = 0; i < is_wrong.size(); ++i) {
    r.wrong += is_wrong[i];
    r.wrong_kept += is_wrong[i] && !b.loopRecord(static_cast<int>(i)).refused;
    r.true_refused += !is_wrong[i] && b.loopRecord(static_cast<int>(i)).refused;
    if (log && !is_wrong[i] && b.loopRecord(static_cast<int>(i)).refused) {
      const core::BackendLoop& l = b.loopRecord(static_cast<int>(i)).loop;
      std::fprintf(stderr, "true loop %d:%d -> %d:%d refused\n", l.session_a, l.keyframe_a, l.session_b, l.keyframe_b);
    }
  }
  if (r.joined) {
    r.ek_inter = ekOver(est, m, true);
    double sq = 0;
    int n = 0;
    for (int s = 0; s < b.numSessions(); ++s)
      for (std::size_t k = 0; k < est[s].size(); ++k) {
        const core::Pose2 g = core::between(m.sessions[0][0], m.sessions[s][k]);
        sq += (est[s][k].translation() - g.translation()).squaredNorm();
        ++n;
      }
    r.map_ate = std::sqrt(sq / n);
  }
  return r;
}

std::string meanSd(const std::vector<double>& v) {
  std::vector<double> x;
  for (double d : v)
    if (std::isfinite(d)) x.push_back(d);
  if (x.empty()) return "n/a";
  double mean = 0, sq = 0;
  for (double d : x) mean += d;
  mean /= x.size();
  for (double d : x) sq += (d - mean) * (d - mean);
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.3f ± %.3f", mean, x.size() > 1 ? std::sqrt(sq / (x.size() - 1)) : 0.0);
  return buf;
}

int robustness(const fs::path& dir, int runs) {
  const Mission m = loadMission(dir);
  int intra = 0;
  for (const auto& l : m.loops) intra += l.first.first == l.second.first;
  std::printf("mission %s: %zu sessions, %zu loops (%d intra, %zu inter), %d runs per level\n\n", dir.c_str(),
              m.sessions.size(), m.loops.size(), intra, m.loops.size() - intra, runs);
  std::printf(
      "| noise 2σ | K | optimiser | odo e_k (m) | e_k intra (m) | e_k inter (m) | map ATE (m) | joined | ms/run |\n");
  std::printf("|---|---|---|---|---|---|---|---|---|\n");
  for (int level = 1; level <= 5; ++level) {
    const double lv = 0.05 * level;
    for (int k : {1, 10, 20, 30}) {
      for (auto opt : {core::OptimizerKind::kIekf, core::OptimizerKind::kSparse}) {
        std::vector<double> odo, ei, ee, ate, t;
        int joined = 0;
        for (int r = 0; r < runs; ++r) {
          RunSpec spec;
          spec.k_join = k;
          spec.optimizer = opt;
          const RunErrors e = runOnce(m, lv, spec, 1000u * level + r);  // same seeds for both optimisers
          odo.push_back(e.odo_ek);
          ei.push_back(e.ek_intra);
          ee.push_back(e.ek_inter);
          ate.push_back(e.map_ate);
          t.push_back(e.ms);
          joined += e.joined;
        }
        std::printf("| %d cm / %d° | %d | %s | %s | %s | %s | %s | %d/%d | %s |\n", 5 * level, 5 * level, k,
                    core::optimizerName(opt), meanSd(odo).c_str(), meanSd(ei).c_str(), meanSd(ee).c_str(),
                    meanSd(ate).c_str(), joined, runs, meanSd(t).c_str());
        std::fflush(stdout);
      }
    }
  }
  return 0;
}

int outliers(const fs::path& dir, const std::vector<int>& percents, int runs, core::OptimizerKind optimizer) {
  const Mission m = loadMission(dir);
  std::printf("mission %s: %zu sessions, %zu true loops, %d runs per row; odometry 2σ = 1 cm / 1°, %s optimiser\n\n",
              dir.c_str(), m.sessions.size(), m.loops.size(), runs, core::optimizerName(optimizer));
  std::printf(
      "| wrong loops | policy | map ATE (m) | ATE change, mean / max (mm) | wrong loops kept | true loops "
      "refused | joins made | joins refused | wrong joins |\n");
  std::printf("|---|---|---|---|---|---|---|---|---|\n");
  for (int p : percents) {
    for (auto policy : {core::JoinPolicy::kCount, core::JoinPolicy::kConsistent}) {
      std::vector<double> ate;
      double kept = 0, wrong = 0, true_refused = 0, joins = 0, refused = 0, change_sum = 0, change_max = 0;
      int wrong_joins = 0, changes = 0;
      for (int r = 0; r < runs; ++r) {
        RunSpec spec;
        spec.policy = policy;
        spec.optimizer = optimizer;
        spec.outlier_fraction = p / 100.0;
        spec.true_loops_only = false;
        const unsigned seed = 7000u + 31u * static_cast<unsigned>(p) + static_cast<unsigned>(r);  // same per policy
        const RunErrors e = runOnce(m, 0.01, spec, seed);
        // The same run without the wrong loops (same odometry, same true loops).
        RunSpec clean = spec;
        clean.outlier_fraction = 0.0;
        const RunErrors c = p > 0 ? runOnce(m, 0.01, clean, seed) : e;
        ate.push_back(e.map_ate);
        kept += e.wrong_kept;
        wrong += e.wrong;
        true_refused += e.true_refused;
        joins += e.joins;
        refused += e.joins_refused;
        wrong_joins += e.joined && !(e.map_ate <= 1.0);
        if (e.joined && c.joined) {
          const double d = 1000.0 * std::abs(e.map_ate - c.map_ate);
          change_sum += d;
          change_max = std::max(change_max, d);
          ++changes;
        }
      }
      char change[64] = "n/a";
      if (changes > 0) std::snprintf(change, sizeof change, "%.2f / %.2f", change_sum / changes, change_max);
      std::printf("| %d %% | %s | %s | %s | %.1f of %.1f | %.1f | %.1f | %.1f | %d/%d |\n", p,
                  core::joinPolicyName(policy), meanSd(ate).c_str(), change, kept / runs, wrong / runs,
                  true_refused / runs, joins / runs, refused / runs, wrong_joins, runs);
      std::fflush(stdout);
    }
  }
  return 0;
}

int cost(int n, int loops, core::OptimizerKind opt) {
  constexpr int kRow = 50;
  std::mt19937 rng(7);
  std::normal_distribution<double> n01(0.0, 1.0);
  std::vector<core::Pose2> truth;
  for (int k = 0; k < n; ++k) {
    const int row = k / kRow, col = k % kRow;
    const bool back = row % 2 == 1;
    truth.emplace_back(back ? 0.5 * (kRow - 1 - col) : 0.5 * col, 0.5 * row, back ? M_PI : 0.0);
  }
  core::BackendOptions o;
  o.optimizer = opt;
  o.optimise_every = 1 << 30;  // one optimisation with every loop, then one more
  o.max_keyframes = n + 2;
  core::MultiSessionBackend b(o);
  const int s = b.startSession();
  const auto t0 = Clock::now();
  for (int k = 1; k < n; ++k) {
    const core::Pose2 t = core::between(truth[k - 1], truth[k]);
    b.addMotion(s, core::UncertainPose2(
                       core::Pose2(t.x() + 0.01 * n01(rng), t.y() + 0.01 * n01(rng), t.yaw() + 0.0087 * n01(rng)),
                       diag(0.01, 0.0087)));
  }
  const auto t1 = Clock::now();
  std::uniform_int_distribution<int> pick(kRow, n - 1);
  auto loop = [&]() {
    const int j = pick(rng);
    const int row = j / kRow, col = j % kRow;
    const int i = (row - 1) * kRow + (kRow - 1 - col);  // the keyframe beside it in the previous row
    return core::BackendLoop{s, i, s, j, core::UncertainPose2(core::between(truth[i], truth[j]), diag(0.01, 0.0087))};
  };
  for (int l = 0; l < loops; ++l) b.addLoop(loop());
  const auto t2 = Clock::now();
  b.flush();
  const auto t3 = Clock::now();
  b.addLoop(loop());
  b.flush();
  const auto t4 = Clock::now();
  double ate = 0;
  const auto est = b.sessionPoses(s);
  for (int k = 0; k < n; ++k)
    ate += (est[k].translation() - core::between(truth[0], truth[k]).translation()).squaredNorm();
  std::printf("| %s | %d | %d | %.1f | %.1f | %.1f | %.1f | %.3f |\n", core::optimizerName(opt), n, loops, ms(t0, t1),
              ms(t2, t3), ms(t3, t4), peakRssKb() / 1024.0, std::sqrt(ate / n));
  (void)t2;
  return 0;
}

// The bench to run and its settings; every value checked.
struct Arguments {
  enum class Mode { kCost, kRobustness, kOutliers } mode = Mode::kCost;
  std::string mission;
  int runs = 0;
  std::vector<int> percents;
  int n = 0, loops = 0;
  core::OptimizerKind optimizer = core::OptimizerKind::kSparse;
};

std::string parsePercents(const std::string& text, std::vector<int>* percents) {
  std::istringstream list(text);
  std::string item;
  while (std::getline(list, item, ',')) {
    long long p = 0;
    if (!tools::parseInteger(item, 0, 500, &p)) return "--outliers takes percentages in [0, 500], e.g. 0,10,30,50";
    percents->push_back(static_cast<int>(p));
  }
  return "";
}

std::optional<int> parseArguments(int argc, char** argv, Arguments* a) {
  std::string optimizer = "sparse";
  bool robust = false;
  int runs = 20;
  tools::CommandLine cli("bench_backend", kUsage);
  auto option = cli.add();
  option("robustness", tools::flag(&robust));
  option("outliers", tools::checked(&a->percents, parsePercents));
  option("mission", po::value(&a->mission));
  option("runs", tools::integer(&runs));
  option("cost", tools::integer(&a->n));
  option("loops", tools::integer(&a->loops));
  option("optimizer", po::value(&optimizer));
  if (const auto status = cli.parse(argc, argv)) return status;
  if (!a->percents.empty()) {
    if (a->mission.empty() || runs < 1) return cli.bad("--outliers needs --mission DIR and --runs >= 1");
    if (!core::parseOptimizer(optimizer, &a->optimizer)) return cli.bad("--optimizer iekf|sparse");
    a->mode = Arguments::Mode::kOutliers;
    a->runs = cli.given("runs") ? runs : 5;
    return std::nullopt;
  }
  if (robust) {
    if (a->mission.empty() || runs < 1) return cli.bad("--robustness needs --mission DIR and --runs >= 1");
    a->mode = Arguments::Mode::kRobustness;
    a->runs = runs;
    return std::nullopt;
  }
  if (a->n < 2 * 50 || a->loops < 0 || !core::parseOptimizer(optimizer, &a->optimizer))
    return cli.bad("--cost N (>= 100) --loops L --optimizer iekf|sparse");
  return std::nullopt;
}

int bench(const Arguments& a) {
  try {
    switch (a.mode) {
      case Arguments::Mode::kOutliers:
        return outliers(a.mission, a.percents, a.runs, a.optimizer);
      case Arguments::Mode::kRobustness:
        return robustness(a.mission, a.runs);
      case Arguments::Mode::kCost:
        break;
    }
    return cost(a.n, a.loops, a.optimizer);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_backend: %s\n", e.what());
    return 1;
  }
}

}  // namespace

int main(int argc, char** argv) {
  Arguments arguments;
  if (const auto status = parseArguments(argc, argv, &arguments)) return *status;
  return bench(arguments);
}
