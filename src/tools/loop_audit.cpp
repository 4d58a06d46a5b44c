// loop_audit: where the ground-truth loop pairs of an offline_slam run are lost, stage by stage.
// A diagnostic beside the pipeline, not in it: it re-computes, for every pair of loops_gt.csv, what
// each stage of the loop search would do with it, using the core's own functions and the run's
// configuration, and prints one markdown table (loss by stage) and a CSV row per pair.
//
// Stages, in pipeline order; a pair is charged to the first that loses it:
//   keyframe     the pair's frames did not both become keyframes (all-pairs view: no keyframe
//                within one frame of each, as evaluate.py's recall_all counts them);
//   verification RANSAC between the two keyframes (estimatePairMotion, descriptors through the
//                detector's 8-bit copy, the stored keyframe as a, the new as b: what the detector
//                computes, deterministically) fails or keeps fewer than the loop's min_inliers;
//                split into "RANSAC fails" and "too few inliers", and counted again when another
//                enhancement (--enhancement) would pass;
//   gate         verified and accepted by the detector but refused by the back-end's consistency
//                gates (loops_refused.csv);
//   candidate    it would verify, yet it is neither accepted nor refused: the candidate search
//                never proposed it (its rank among the earlier keyframes by distance in the run's
//                final trajectory and in its odometry, and its hash rank, are in the CSV);
//   found        accepted (loops.csv).
// A verification that fails is charged to verification whether or not the pair was a candidate
// (a candidate that fails and a non-candidate that would fail are lost either way).
#include <opencv2/core.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <map>
#include <optional>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "cli.h"
#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/frontend/features.h"
#include "uw_multislam/core/frontend/image_file.h"
#include "uw_multislam/core/frontend/odometry.h"
#include "uw_multislam/core/frontend/pair_motion.h"
#include "uw_multislam/core/loops/haloc.h"
#include "uw_multislam/core/session/slam_config.h"

namespace core = uw_multislam::core;
namespace tools = uw_multislam::tools;
namespace po = boost::program_options;

namespace {

const char* kUsage = R"(usage: loop_audit --session DIR --run OUT --loops-gt FILE [options]

Where the ground-truth loop pairs (loops_gt.csv, pairs of session 0) of an offline_slam run of the
one folder DIR are lost: keyframe choice, verification (RANSAC, inliers), the consistency gate, or the
candidate search. Prints a markdown table of losses by stage over keyframe pairs and over all pairs
(a pair found through keyframes within one frame of each of its frames, as evaluate.py's recall_all).

options:
  --config FILE        the run's configuration (default: the built-in defaults; give OUT/config.yaml)
  --csv FILE           one row per ground-truth pair with every stage's numbers
  --enhancement MODE   also verify with this enhancement (none, clahe, dehaze, dehaze_clahe)
  --min-inliers N      also count the pairs that would verify with this many inliers
  --verify-only        only verify: every ground-truth pair, and pairs the folder's gt.csv puts
                       farther apart than the footprint's diagonal (which must not verify), with
                       the configuration; prints how many pass and their inliers (no run needed)
)";

struct Pair {
  int a, b;  // frame indexes, a < b
};

std::vector<std::vector<std::string>> readCsv(const std::string& path, bool required) {
  std::ifstream in(path);
  std::vector<std::vector<std::string>> rows;
  if (!in) {
    if (required) throw std::runtime_error(path + ": cannot open");
    return rows;
  }
  std::string line;
  std::getline(in, line);  // header
  while (std::getline(in, line)) {
    if (line.empty()) continue;
    std::vector<std::string> cells;
    std::stringstream ss(line);
    std::string cell;
    while (std::getline(ss, cell, ',')) cells.push_back(cell);
    rows.push_back(cells);
  }
  return rows;
}

struct Verified {
  bool ransac = false;  // RANSAC succeeded
  int inliers = 0;
  int matches = 0;
  bool pass(int min_inliers) const { return ransac && inliers >= min_inliers; }
};

class Verifier {
 public:
  Verifier(const core::Dataset& d, const core::SlamConfig& c, core::EnhancementMode mode)
      : d_(d), c_(c), camera_(d.camera.pinhole()) {
    core::OdometryOptions o = c.odometry;
    o.enhancement.mode = mode;
    o.klt.enabled = false;
    preparer_ = std::make_unique<core::FramePreparer>(d.camera, o);
  }
  const core::FrameFeatures& features(int index) {
    auto it = cache_.find(index);
    if (it != cache_.end()) return it->second;
    const core::FrameRecord& f = d_.frames.at(static_cast<std::size_t>(position(index)));
    std::string why;
    const cv::Mat image = core::readFrameImageBgr(d_.imagePath(f), &why);
    if (image.empty()) throw std::runtime_error(d_.imagePath(f) + ": " + why);
    core::PreparedFrame p = preparer_->prepare(image);
    if (!p.error.empty() || !p.features) throw std::runtime_error(d_.imagePath(f) + ": " + p.error);
    // As the detector holds a keyframe: descriptors through 8 bits and back.
    core::FrameFeatures held = std::move(*p.features);
    cv::Mat bytes;
    held.descriptors.convertTo(bytes, CV_8U);
    held.descriptors = core::extractorDescriptors(bytes);
    return cache_.emplace(index, std::move(held)).first->second;
  }
  Verified verify(int older, int newer) {
    const core::View a{&features(older), altitude(older), &camera_};
    const core::View b{&features(newer), altitude(newer), &camera_};
    const core::PairMotion m =
        core::estimatePairMotion(a, b, core::loopMatching(c_.odometry.matching, c_.loops), c_.odometry.ransac);
    return {m.ransac.success, static_cast<int>(m.ransac.inliers.size()), m.matches};
  }
  double altitude(int index) const { return d_.frames.at(static_cast<std::size_t>(position(index))).altitude_m; }

 private:
  int position(int index) const {
    for (std::size_t i = 0; i < d_.frames.size(); ++i)
      if (d_.frames[i].index == index) return static_cast<int>(i);
    throw std::runtime_error("frame " + std::to_string(index) + " is not in frames.csv");
  }
  const core::Dataset& d_;
  const core::SlamConfig& c_;
  core::CameraIntrinsics camera_;
  std::unique_ptr<core::FramePreparer> preparer_;
  std::map<int, core::FrameFeatures> cache_;
};

struct Args {
  std::string session, run, loops_gt, config, csv, enhancement;
  int min_inliers = 0;
  bool verify_only = false;
};

std::optional<int> parseArguments(int argc, char** argv, Args* a) {
  tools::CommandLine cli("loop_audit", kUsage);
  auto option = cli.add();
  option("session", po::value(&a->session));
  option("run", po::value(&a->run));
  option("loops-gt", po::value(&a->loops_gt));
  option("config", po::value(&a->config));
  option("csv", po::value(&a->csv));
  option("enhancement", po::value(&a->enhancement));
  option("min-inliers", tools::integer(&a->min_inliers, 0, std::numeric_limits<int>::max()));
  option("verify-only", tools::flag(&a->verify_only));
  if (const auto status = cli.parse(argc, argv)) return status;
  if (a->session.empty() || (a->run.empty() && !a->verify_only) || a->loops_gt.empty())
    return cli.bad("--session, --run and --loops-gt are required (--run not with --verify-only)");
  return std::nullopt;
}

core::EnhancementMode modeNamed(const std::string& name) {
  for (core::EnhancementMode m : {core::EnhancementMode::kNone, core::EnhancementMode::kClahe,
                                  core::EnhancementMode::kDehaze, core::EnhancementMode::kDehazeClahe})
    if (core::enhancementName(m) == name) return m;
  throw std::invalid_argument("unknown enhancement " + name);
}

// Rank (1 = nearest) of `target` among the keyframes at least `gap` keyframes before `query` by
// distance in `poses` (frame index -> x, y); 0 when `target` is not among them.
int distanceRank(const std::map<int, std::pair<double, double>>& poses, const std::vector<int>& keyframes, int target,
                 int query, int gap) {
  const auto q = poses.find(query), t = poses.find(target);
  if (q == poses.end() || t == poses.end()) return 0;
  const auto at = std::find(keyframes.begin(), keyframes.end(), query) - keyframes.begin();
  auto dist = [&](int k) {
    const auto& p = poses.at(k);
    return std::hypot(p.first - q->second.first, p.second - q->second.second);
  };
  const double d = dist(target);
  int rank = 1;
  bool eligible = false;
  for (long i = 0; i + gap < at; ++i) {
    const int k = keyframes[static_cast<std::size_t>(i)];
    if (k == target)
      eligible = true;
    else if (dist(k) < d)
      ++rank;
  }
  return eligible ? rank : 0;
}

// Verification alone (see --verify-only): the pairs that should and should not verify.
std::set<std::pair<int, int>> framePairs(const std::string& file);

int verifyOnly(const core::Dataset& d, const core::SlamConfig& config, const std::string& loops_gt) {
  Verifier verifier(d, config, config.odometry.enhancement.mode);
  const int min_inliers = config.loops.local.min_inliers;
  std::map<int, int> histogram;  // inliers (bins of 5) of the ground-truth pairs
  int pass = 0, n = 0;
  for (const auto& p : framePairs(loops_gt)) {
    const Verified v = verifier.verify(p.first, p.second);
    ++n;
    if (v.pass(min_inliers)) ++pass;
    ++histogram[v.ransac ? v.inliers / 5 * 5 : -1];
  }
  std::map<int, core::Pose2> gt;
  for (const auto& g : d.ground_truth) gt[g.index] = g.pose;
  const double diagonal = std::hypot(d.camera.width, d.camera.height) / d.camera.fx;  // per metre of altitude
  int negatives = 0, false_pass = 0, most = 0;
  for (auto a = gt.begin(); a != gt.end(); ++a) {
    for (auto b = std::next(a); b != gt.end(); ++b) {
      const double reach = diagonal * std::max(verifier.altitude(a->first), verifier.altitude(b->first));
      if ((a->second.translation() - b->second.translation()).norm() <= reach) continue;
      if ((a->first * 31 + b->first) % 7 != 0) continue;  // a seventh of them: every frame still takes part
      const Verified v = verifier.verify(a->first, b->first);
      ++negatives;
      most = std::max(most, v.ransac ? v.inliers : 0);
      if (v.pass(min_inliers)) {
        ++false_pass;
        std::printf("false verification: frames %d and %d, %d inliers\n", a->first, b->first, v.inliers);
      }
    }
  }
  std::printf("ground-truth pairs verified: %d of %d (min_inliers %d); inliers:", pass, n, min_inliers);
  for (const auto& h : histogram)
    std::printf(" %s%d: %d", h.first < 0 ? "RANSAC fails" : "", h.first < 0 ? 0 : h.first, h.second);
  std::printf("\nnon-overlapping pairs verified: %d of %d (most inliers %d)\n", false_pass, negatives, most);
  return 0;
}

std::set<std::pair<int, int>> framePairs(const std::string& file) {
  std::set<std::pair<int, int>> out;
  for (const auto& r : readCsv(file, false)) {
    if (std::stoi(r.at(0)) != 0 || std::stoi(r.at(2)) != 0) continue;
    const int x = std::stoi(r.at(1)), y = std::stoi(r.at(3));
    out.insert({std::min(x, y), std::max(x, y)});
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  Args args;
  if (const auto status = parseArguments(argc, argv, &args)) return *status;
  try {
    cv::setNumThreads(1);
    const core::SlamConfig config = args.config.empty() ? core::SlamConfig() : core::loadSlamConfig(args.config);
    const core::Dataset d = core::loadDataset(args.session);
    const int min_inliers = config.loops.local.min_inliers;
    const int gap = config.loops.local.exclude_recent + 1;
    if (args.verify_only) return verifyOnly(d, config, args.loops_gt);

    std::vector<int> keyframes;
    std::map<int, std::pair<double, double>> odometry, slam;
    for (const auto& r : readCsv(args.run + "/odometry.csv", true)) {
      if (std::stoi(r.at(0)) != 0) continue;
      keyframes.push_back(std::stoi(r.at(1)));
      odometry[keyframes.back()] = {std::stod(r.at(2)), std::stod(r.at(3))};
    }
    for (const auto& r : readCsv(args.run + "/trajectory.csv", false))
      if (std::stoi(r.at(0)) == 0) slam[std::stoi(r.at(1))] = {std::stod(r.at(3)), std::stod(r.at(4))};
    std::sort(keyframes.begin(), keyframes.end());
    const std::set<int> is_kf(keyframes.begin(), keyframes.end());
    const auto pairsOf = framePairs;
    const auto accepted = pairsOf(args.run + "/loops.csv");
    const auto refused = pairsOf(args.run + "/loops_refused.csv");
    std::vector<Pair> gt;
    for (const auto& p : pairsOf(args.loops_gt)) gt.push_back({p.first, p.second});

    Verifier verifier(d, config, config.odometry.enhancement.mode);
    std::unique_ptr<Verifier> other;
    if (!args.enhancement.empty()) other = std::make_unique<Verifier>(d, config, modeNamed(args.enhancement));
    const core::ImageHasher hasher(config.loops.global.hash_mode, config.odometry.features.num_features,
                                   config.loops.global.projection_seed);
    core::HashStore store(core::hashCodeRange(config.loops.global.hash_mode));
    std::map<int, Eigen::VectorXf> hashes;
    for (int k : keyframes) hashes[k] = hasher.hash(verifier.features(k).descriptors);
    auto hashRank = [&](int target, int query) {  // among keyframes `gap` keyframes or more before query
      if (!hashes.count(target) || !hashes.count(query)) return 0;
      const float d0 = store.distance(hashes[query], hashes[target]);
      const auto at = std::find(keyframes.begin(), keyframes.end(), query) - keyframes.begin();
      int rank = 1;
      bool eligible = false;
      for (long i = 0; i + gap < at; ++i) {
        const int k = keyframes[static_cast<std::size_t>(i)];
        if (k == target)
          eligible = true;
        else if (store.distance(hashes[query], hashes[k]) < d0)
          ++rank;
      }
      return eligible ? rank : 0;
    };

    // Stage of a set of keyframe pairs (the pair itself, or its neighbours' for the all-pairs view).
    enum Stage { kKeyframe, kVerifyRansac, kVerifyInliers, kCandidate, kGate, kFound, kStages };
    const char* names[kStages] = {"keyframe choice (frames not keyframes)",
                                  "verification: RANSAC fails",
                                  "verification: fewer inliers than loops min_inliers",
                                  "candidate search (would verify, never proposed)",
                                  "consistency gate (refused by the back-end)",
                                  "found"};
    int count[2][kStages] = {};
    int other_pass[2] = {}, lower_pass[2] = {};
    std::map<int, int> hash_rank_hist, odo_rank_hist;
    std::ofstream csv;
    if (!args.csv.empty()) {
      csv.open(args.csv);
      csv << "index_a,index_b,keyframes,inliers,ransac,matches,other_inliers,run,slam_rank,odometry_rank,hash_rank,"
             "stage_keyframe_pair,stage_all,near_a,near_b,near_inliers\n";
    }
    for (const Pair& p : gt) {
      auto stageOf = [&](const std::vector<std::pair<int, int>>& combos, int* best_inliers, std::pair<int, int>* best,
                         bool* other_ok, bool* lower_ok) {
        *best_inliers = -1;
        *other_ok = *lower_ok = false;
        if (combos.empty()) return kKeyframe;
        for (const auto& c : combos)
          if (accepted.count(c)) {
            *best = c;
            return kFound;
          }
        for (const auto& c : combos)
          if (refused.count(c)) {
            *best = c;
            return kGate;
          }
        bool ransac = false, pass = false;
        for (const auto& c : combos) {
          const Verified v = verifier.verify(c.first, c.second);
          if (v.inliers > *best_inliers) {
            *best_inliers = v.inliers;
            *best = c;
          }
          ransac = ransac || v.ransac;
          pass = pass || v.pass(min_inliers);
          if (args.min_inliers > 0 && v.ransac && v.inliers >= args.min_inliers) *lower_ok = true;
          if (other && other->verify(c.first, c.second).pass(min_inliers)) *other_ok = true;
        }
        if (pass) return kCandidate;
        return ransac ? kVerifyInliers : kVerifyRansac;
      };
      std::vector<std::pair<int, int>> self, near;
      if (is_kf.count(p.a) && is_kf.count(p.b)) self.push_back({p.a, p.b});
      for (int x = p.a - 1; x <= p.a + 1; ++x)
        for (int y = p.b - 1; y <= p.b + 1; ++y)
          if (x < y && is_kf.count(x) && is_kf.count(y)) near.push_back({x, y});
      int inl_self = -1, inl_near = -1;
      std::pair<int, int> best_self{p.a, p.b}, best_near{-1, -1};
      bool o_self = false, o_near = false, l_self = false, l_near = false;
      const Stage s_self = stageOf(self, &inl_self, &best_self, &o_self, &l_self);
      const Stage s_near = stageOf(near, &inl_near, &best_near, &o_near, &l_near);
      ++count[0][s_self];
      ++count[1][s_near];
      if ((s_self == kVerifyRansac || s_self == kVerifyInliers) && o_self) ++other_pass[0];
      if ((s_near == kVerifyRansac || s_near == kVerifyInliers) && o_near) ++other_pass[1];
      if ((s_self == kVerifyRansac || s_self == kVerifyInliers) && l_self) ++lower_pass[0];
      if ((s_near == kVerifyRansac || s_near == kVerifyInliers) && l_near) ++lower_pass[1];
      const Verified v = verifier.verify(p.a, p.b);
      const int other_inliers = other ? other->verify(p.a, p.b).inliers : -1;
      const int slam_rank = distanceRank(slam, keyframes, p.a, p.b, gap);
      const int odo_rank = distanceRank(odometry, keyframes, p.a, p.b, gap);
      const int h_rank = hashRank(p.a, p.b);
      if (is_kf.count(p.a) && is_kf.count(p.b)) {
        ++hash_rank_hist[h_rank <= 0 ? 0 : h_rank == 1 ? 1 : h_rank <= 3 ? 3 : h_rank <= 10 ? 10 : 11];
        ++odo_rank_hist[odo_rank <= 0 ? 0 : odo_rank == 1 ? 1 : odo_rank <= 3 ? 3 : odo_rank <= 10 ? 10 : 11];
      }
      const char* run = accepted.count({p.a, p.b}) ? "accepted" : refused.count({p.a, p.b}) ? "refused" : "-";
      if (csv) {
        csv << p.a << "," << p.b << "," << (is_kf.count(p.a) + is_kf.count(p.b)) << "," << v.inliers << "," << v.ransac
            << "," << v.matches << "," << other_inliers << "," << run << "," << slam_rank << "," << odo_rank << ","
            << h_rank << "," << s_self << "," << s_near << "," << best_near.first << "," << best_near.second << ","
            << inl_near << "\n";
      }
    }
    const int n = static_cast<int>(gt.size());
    std::printf("Ground-truth pairs: %d; keyframes: %zu of %zu frames; loop min_inliers %d.\n\n", n, keyframes.size(),
                d.frames.size(), min_inliers);
    std::printf("| stage where the pair is lost | keyframe pairs | all pairs (keyframes within one frame) |\n");
    std::printf("|---|---|---|\n");
    for (int s = 0; s < kStages; ++s) std::printf("| %s | %d | %d |\n", names[s], count[0][s], count[1][s]);
    std::printf("| recall | %.3f (%d of %d keyframe pairs) | %.3f (%d of %d) |\n",
                n - count[0][kKeyframe] > 0 ? double(count[0][kFound]) / (n - count[0][kKeyframe]) : 0.0,
                count[0][kFound], n - count[0][kKeyframe], n > 0 ? double(count[1][kFound]) / n : 0.0, count[1][kFound],
                n);
    if (other)
      std::printf("| of the verification losses, would verify with enhancement %s | %d | %d |\n",
                  args.enhancement.c_str(), other_pass[0], other_pass[1]);
    if (args.min_inliers > 0)
      std::printf("| of the verification losses, would verify with %d inliers | %d | %d |\n", args.min_inliers,
                  lower_pass[0], lower_pass[1]);
    auto hist = [](const std::map<int, int>& h) {
      char out[200];
      auto at = [&](int k) { return h.count(k) ? h.at(k) : 0; };
      std::snprintf(out, sizeof out, "1st: %d, 2-3: %d, 4-10: %d, >10: %d, not eligible: %d", at(1), at(3), at(10),
                    at(11), at(0));
      return std::string(out);
    };
    std::printf(
        "\nKeyframe pairs, rank of the older frame among the earlier keyframes (leaving out the %d before the "
        "newer) as seen from the newer:\n- by hash distance: %s\n- by distance in the odometry: %s\n",
        gap - 1, hist(hash_rank_hist).c_str(), hist(odo_rank_hist).c_str());
  } catch (const std::exception& e) {
    std::fprintf(stderr, "loop_audit: %s\n", e.what());
    return 1;
  }
  return 0;
}
