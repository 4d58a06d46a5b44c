// merge_stores: session stores of several vehicles or dives into one (issue 20, item 4). Argument
// parsing around core::mergeStores (core/session/store_merge.h); contract: --help, README "Fleet
// merge".
#include <cstdio>
#include <exception>
#include <string>
#include <vector>

#include "uw_multislam/core/session/session_store.h"
#include "uw_multislam/core/session/slam_config.h"
#include "uw_multislam/core/session/store_merge.h"

namespace core = uw_multislam::core;

namespace {

const char* kUsage = R"usage(usage: merge_stores OUT IN1 IN2 ... [--config FILE] [--vehicle NAME ...] [--dive NAME ...] [options]

Merges session stores (offline_slam --db, the back-end's store_path) of several vehicles or dives
into the new store OUT:
  1. every session with a keyframe is copied in input order with its keyframes (features, hash,
     image), odometry, loops, maps and split pairs, renumbered by OUT; its provenance (source
     file, source session id and name, vehicle, dive) is kept in OUT's table `provenance`; a
     name already taken becomes NAME@VEHICLE;
  2. the sessions of each input search the sessions of the inputs before it for global loops
     (stored hashes, best_k candidates, RANSAC on the stored features), and the back-end joins
     what the loops support by its join policy (backend.join_policy of the configuration),
     as if the inputs had been recorded one after another in one run; every map is optimised.
OUT then loads like any store: in the back-end nodelet (store_path) and in offline_slam --db.

Refused, before anything is written: an OUT that exists (never overwritten), a missing input, the
same input twice, inputs whose hash settings differ (mode, seed, n, projection vectors: the reason
names both), a session still recording (an interrupted run: finish or discard it first). The
inputs are opened read-only and never modified. OUT is written to OUT.partial-<pid> and appears
only when complete: on any failure no OUT is left.

options:
  --config FILE     SLAM configuration (config/slam.yaml layout): loop verification and the
                    back-end's join policy; the hash settings come from the inputs
  --vehicle NAME    the vehicle of the next input without one, in input order (repeat it);
                    default: the input file's stem
  --dive NAME       the dive of the next input without one, in input order (repeat it);
                    default: each session's own name
  --no-loops        copy only: no loop search, no new joins
  --quiet           no summary
  -h, --help        this text

Prints one line per input and a summary:
  merge_stores out=OUT inputs=N sessions=S keyframes=K copied_loops=L new_loops=A refused_loops=R joins=J maps=M
Exit status 0 on success, 2 on bad arguments, 1 with a one-line reason on bad input.)usage";

int badArgs(const std::string& why) {
  std::fprintf(stderr, "merge_stores: %s (see --help)\n", why.c_str());
  return 2;
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<std::string> positional, vehicles, dives;
  std::string config_file;
  bool quiet = false, loops = true;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    const bool has_value = i + 1 < argc;
    if (arg == "-h" || arg == "--help") return std::puts(kUsage), 0;
    if (arg == "--config" && has_value) {
      config_file = argv[++i];
    } else if (arg == "--vehicle" && has_value) {
      vehicles.push_back(argv[++i]);
    } else if (arg == "--dive" && has_value) {
      dives.push_back(argv[++i]);
    } else if (arg == "--no-loops") {
      loops = false;
    } else if (arg == "--quiet") {
      quiet = true;
    } else if (arg.rfind("--", 0) == 0 || arg == "-") {
      return badArgs(has_value || arg == "-" ? "unknown argument '" + arg + "'" : arg + " needs a value");
    } else {
      positional.push_back(arg);
    }
  }
  if (positional.size() < 3) return badArgs("give OUT and at least two input stores");
  std::vector<core::MergeInput> inputs;
  for (std::size_t i = 1; i < positional.size(); ++i) inputs.push_back({positional[i], "", ""});
  if (vehicles.size() > inputs.size()) return badArgs("more --vehicle names than inputs");
  if (dives.size() > inputs.size()) return badArgs("more --dive names than inputs");
  for (std::size_t i = 0; i < vehicles.size(); ++i) inputs[i].vehicle = vehicles[i];
  for (std::size_t i = 0; i < dives.size(); ++i) inputs[i].dive = dives[i];
  try {
    const core::SlamConfig config = config_file.empty() ? core::SlamConfig() : core::loadSlamConfig(config_file);
    auto log = [quiet](const std::string& line) {
      if (!quiet) std::printf("%s\n", line.c_str());
    };
    const core::MergeReport r = core::mergeStores(positional[0], inputs, config, loops, log);
    if (!quiet)
      std::printf(
          "merge_stores out=%s inputs=%d sessions=%d keyframes=%d copied_loops=%d new_loops=%d refused_loops=%d "
          "joins=%d maps=%d\n",
          positional[0].c_str(), r.inputs, r.sessions, r.keyframes, r.copied_loops, r.loops_accepted, r.loops_refused,
          r.joins, r.maps);
    if (!quiet && r.renamed_sessions > 0)
      std::printf("%d sessions renamed NAME@VEHICLE (their names were taken by an earlier input)\n", r.renamed_sessions);
    if (!quiet && r.skipped_empty_sessions > 0)
      std::printf("%d sessions without a keyframe were not copied\n", r.skipped_empty_sessions);
    return 0;
  } catch (const std::exception& e) {  // bad input (std::invalid_argument) or a store error
    std::fprintf(stderr, "merge_stores: %s\n", e.what());
    return 1;
  }
}
