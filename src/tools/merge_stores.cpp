// merge_stores: session stores of several vehicles or dives into one. Argument parsing around
// core::mergeStores (core/store/store_merge.h); contract: --help, doc/tools/merge_stores.md.
#include <cstdio>
#include <exception>
#include <optional>
#include <string>
#include <vector>

#include "cli.h"

#include "uw_multislam/core/session/slam_config.h"
#include "uw_multislam/core/store/session_store.h"
#include "uw_multislam/core/store/store_merge.h"

namespace core = uw_multislam::core;
namespace po = boost::program_options;
namespace tools = uw_multislam::tools;

namespace {

const char* kUsage =
    R"usage(usage: merge_stores OUT IN1 IN2 ... [--config FILE] [--vehicle NAME ...] [--dive NAME ...] [options]

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

struct Arguments {
  std::string out;  // the new store
  std::vector<core::MergeInput> inputs;
  std::string config_file;  // "": the defaults
  bool loops = true, quiet = false;
};

std::optional<int> parseArguments(int argc, char** argv, Arguments* a) {
  std::vector<std::string> positional, vehicles, dives;
  bool no_loops = false;
  tools::CommandLine cli("merge_stores", kUsage);
  auto option = cli.add();
  option("config", po::value(&a->config_file));
  option("vehicle", po::value(&vehicles));
  option("dive", po::value(&dives));
  option("no-loops", tools::flag(&no_loops));
  option("quiet", tools::flag(&a->quiet));
  cli.positional(&positional);
  if (const auto status = cli.parse(argc, argv)) return status;
  if (positional.size() < 3) return cli.bad("give OUT and at least two input stores");
  a->out = positional[0];
  for (std::size_t i = 1; i < positional.size(); ++i) a->inputs.push_back({positional[i], "", ""});
  if (vehicles.size() > a->inputs.size()) return cli.bad("more --vehicle names than inputs");
  if (dives.size() > a->inputs.size()) return cli.bad("more --dive names than inputs");
  for (std::size_t i = 0; i < vehicles.size(); ++i) a->inputs[i].vehicle = vehicles[i];
  for (std::size_t i = 0; i < dives.size(); ++i) a->inputs[i].dive = dives[i];
  a->loops = !no_loops;
  return std::nullopt;
}

int merge(const Arguments& a) {
  const bool quiet = a.quiet;
  try {
    const core::SlamConfig config = a.config_file.empty() ? core::SlamConfig() : core::loadSlamConfig(a.config_file);
    auto log = [quiet](const std::string& line) {
      if (!quiet) std::printf("%s\n", line.c_str());
    };
    const core::MergeReport r = core::mergeStores(a.out, a.inputs, config, a.loops, log);
    if (!quiet)
      std::printf(
          "merge_stores out=%s inputs=%d sessions=%d keyframes=%d copied_loops=%d new_loops=%d refused_loops=%d "
          "joins=%d maps=%d\n",
          a.out.c_str(), r.inputs, r.sessions, r.keyframes, r.copied_loops, r.loops_accepted, r.loops_refused, r.joins,
          r.maps);
    if (!quiet && r.renamed_sessions > 0)
      std::printf("%d sessions renamed NAME@VEHICLE (their names were taken by an earlier input)\n",
                  r.renamed_sessions);
    if (!quiet && r.skipped_empty_sessions > 0)
      std::printf("%d sessions without a keyframe were not copied\n", r.skipped_empty_sessions);
    return 0;
  } catch (const std::exception& e) {  // bad input (std::invalid_argument) or a store error
    std::fprintf(stderr, "merge_stores: %s\n", e.what());
    return 1;
  }
}

}  // namespace

int main(int argc, char** argv) {
  Arguments arguments;
  if (const auto status = parseArguments(argc, argv, &arguments)) return *status;
  return merge(arguments);
}
