// offline_slam: the SLAM core over dataset folders, no ROS master. The main parses the command line into
// tools::OfflineOptions; tools::runOffline (offline_run.h) does the work. Contract: --help, doc/run_outputs.md.
#include <cmath>
#include <cstdlib>
#include <optional>
#include <string>
#include <vector>

#include "cli.h"
#include "offline_run.h"

namespace core = uw_multislam::core;
namespace po = boost::program_options;
namespace tools = uw_multislam::tools;

namespace {

const char* kUsage =
    R"(usage: offline_slam --session DIR [--session DIR ...] --out OUT [--config FILE] [--db FILE] [options]

Runs uw_multislam over dataset folders (frames.csv, camera.yaml, images; see
doc/dataset_format.md), in the order given, as consecutive missions. Writes into OUT (columns in
doc/run_outputs.md): odometry.csv (odometry keyframe poses, each session in its own frame), trajectory.csv
(final keyframe poses in the frame of their map), loops.csv, loop_poses.csv (measured pose and covariance),
links.csv (joins), pieces.csv (the pieces tracking loss splits a folder into), nav_placements.csv (pieces and
sessions placed by the nav, --nav on), timing.csv, inputs.csv, config.yaml.
`session` is the folder's position on the command line, `index` the frame's index in frames.csv.
Sessions are joined into maps through one link (paper §9) once the global loops between them
support it (backend.join_policy: consistent, the default: a pairwise-consistent set of at least
backend.join_min_consistent loops with join_min_inliers inliers and join_min_spread_m spread; count:
backend.join_min_loops loops), and each map is optimised (backend.optimizer); `map` is the map's first session, whose frame it is.

With --db FILE (the session store, created if missing) the stored sessions keep their store ids,
the folders follow from the first id no session has had (the run prints which folder got which
session ids once); global loops are searched against them and everything is written to the
store as it happens. A folder already in it (frame indexes and stamps) is refused (exit status 3)
without --again. A run killed before it ended (kill -9, power cut) leaves the folder's session
`recording` in the store: running the folder again is refused (exit status 3) until you choose
with --interrupted:
  discard   delete the interrupted run's sessions (keyframes, motions, loops; the maps lose them)
            in one transaction, then process the folder again as usual;
  finish    keep what was stored, mark the session finished, and skip the folder in this run
            (when every folder is skipped, the run ends with status 0 and writes nothing to OUT).

options:
  --session DIR     a dataset folder (repeat for several missions)
  --out OUT         output directory (created)
  --config FILE     YAML configuration (see config/slam.yaml; --dump-config shows every key)
  --db FILE         the session store (SQLite) to read and extend
  --again           process folders already in the store once more (as new sessions)
  --detect-loops    first search global loops among the stored sessions (each against those
                    stored before it; loops already stored are skipped) and join what they
                    support (backend.join_policy), so stored sessions join without a new one;
                    --session may then be left out
  --add-link A:KA:B:KB[:X:Y:YAW:SXY:SYAW]
                    with --db (repeatable): the operator's link between keyframe KA of stored
                    session A and keyframe KB of stored session B (the back-end's add_link):
                    with the pose of KB in KA's frame (m, rad) and standard deviations, or
                    without it measured by RANSAC between the two stored keyframes ("find it").
                    Applied after --detect-loops, before the folders; a link is a loop like a
                    detector's (stored, counted towards joins). Every link is checked (and
                    measured) before any is added: one refused, none is, exit status 1.
  --interrupted discard|finish
                    what to do with a folder's run that was interrupted (above)
  --localise-only   with --db: the store is read, never written (localisation mode, as the
                    back-end's set_mode localisation): the folders are tracked and their loops to
                    the stored sessions found, automatic joins wait, OUT gets the outputs; the
                    store stays byte-identical. Not with --detect-loops or --interrupted
  --finish-after N  end each folder's session after its first N frames (as the back-end's
                    finish_session): the folder's later frames are dropped, counted and printed,
                    the session is finished (stored as finished with --db) and the next folder
                    starts the next session as usual
  --nav on|off      use a folder's nav.csv (dead reckoning) as a prior (default: nav.enabled, on)
  --threads N       worker threads that read, enhance and extract (SIFT) the next frames while
                    the main thread matches, detects loops and optimises (default 1: all in one
                    thread, one core); the outputs are the same for any N
  --dump-config     print the effective configuration and exit
  --quiet           no per-session summary
  -h, --help        this text

Exit status 0 on success, 2 on bad arguments, 1 with a one-line reason on bad input, 3 when a
folder is already in the store (the one-line reason names the option to pass: --again, or
--interrupted discard|finish).)";

// --add-link A:KA:B:KB[:X:Y:YAW:SXY:SYAW] -> a link (sessions, keyframes; z when measured). false:
// not that shape, or a number that is not one (sigmas must be > 0).
bool parseLink(const std::string& spec, core::Loop* link, bool* measured, double* yaw) {
  std::vector<std::string> f;
  std::size_t start = 0;
  for (std::size_t colon; (colon = spec.find(':', start)) != std::string::npos; start = colon + 1)
    f.push_back(spec.substr(start, colon - start));
  f.push_back(spec.substr(start));
  if (f.size() != 4 && f.size() != 9) return false;
  int ids[4];
  for (int i = 0; i < 4; ++i) {
    char* end = nullptr;
    const long v = std::strtol(f[i].c_str(), &end, 10);
    if (f[i].empty() || *end != '\0' || v < 0 || v > 1000000000) return false;
    ids[i] = static_cast<int>(v);
  }
  double x[5] = {0, 0, 0, 0, 0};
  for (std::size_t i = 4; i < f.size(); ++i) {
    char* end = nullptr;
    x[i - 4] = std::strtod(f[i].c_str(), &end);
    if (f[i].empty() || *end != '\0' || !std::isfinite(x[i - 4])) return false;
  }
  *measured = f.size() == 9;
  if (*measured && !(x[3] >= 1e-6 && x[4] >= 1e-6)) return false;  // squared: a covariance the back-end takes
  link->session_a = ids[0];
  link->keyframe_a = ids[1];
  link->session_b = ids[2];
  link->keyframe_b = ids[3];
  link->z = core::UncertainPose2(core::Pose2(x[0], x[1], x[2]),
                                 Eigen::Vector3d(x[3] * x[3], x[3] * x[3], x[4] * x[4]).asDiagonal());
  link->inliers = 0;
  *yaw = x[2];
  return true;
}

std::string parseNav(const std::string& text, std::optional<bool>* on) {
  if (text != "on" && text != "off") return "--nav takes on or off, not '%value%'";
  *on = text == "on";
  return "";
}

std::string parseInterrupted(const std::string& text, std::optional<core::InterruptedChoice>* choice) {
  if (text != "discard" && text != "finish") return "--interrupted takes discard or finish, not '%value%'";
  *choice = text == "discard" ? core::InterruptedChoice::kDiscard : core::InterruptedChoice::kFinish;
  return "";
}

std::string parseAddLink(const std::string& spec, tools::OperatorLink* link) {
  if (parseLink(spec, &link->loop, &link->measured, &link->yaw)) return "";
  return "bad --add-link '%value%': A:KA:B:KB (find it) or A:KA:B:KB:X:Y:YAW:SXY:SYAW (sigmas >= 1e-6)";
}

// The command line into *o, every value and combination checked; std::nullopt, or the exit status to return.
std::optional<int> parseArguments(int argc, char** argv, tools::OfflineOptions* o) {
  tools::CommandLine cli("offline_slam", kUsage);
  auto option = cli.add();
  option("session", po::value(&o->folders));
  option("out", po::value(&o->out));
  option("config", po::value(&o->config_file));
  option("db", po::value(&o->db));
  option("again", tools::flag(&o->again));
  option("detect-loops", tools::flag(&o->detect_loops));
  option("add-link", tools::checkedEach(&o->links, parseAddLink));
  option("interrupted", tools::checked(&o->interrupted, parseInterrupted));
  option("localise-only", tools::flag(&o->localise_only));
  option("finish-after", tools::integer(&o->finish_after, 1, 100000000, "a number of frames, 1 or more"));
  option("nav", tools::checked(&o->nav, parseNav));
  option("threads", tools::integer(&o->threads, 1, 64));
  option("dump-config", tools::flag(&o->dump_config));
  option("quiet", tools::flag(&o->quiet));
  if (const auto status = cli.parse(argc, argv)) return status;
  const bool store = !o->db.empty();
  if (o->interrupted && !store) return cli.bad("--interrupted needs --db FILE");
  if (o->dump_config) return std::nullopt;  // nothing else is needed to print the configuration
  if (o->detect_loops && !store) return cli.bad("--detect-loops needs --db FILE");
  if (o->localise_only && !store) return cli.bad("--localise-only needs --db FILE");
  if (o->localise_only && (o->detect_loops || o->interrupted))
    return cli.bad("--localise-only writes nothing to the store: not with --detect-loops or --interrupted");
  if (!o->links.empty() && !store) return cli.bad("--add-link needs --db FILE");
  if (!o->links.empty() && o->localise_only)
    return cli.bad("--localise-only writes nothing to the store: not with --add-link");
  if (o->folders.empty() && !o->detect_loops && o->links.empty())
    return cli.bad("at least one --session DIR is required");
  if (o->out.empty()) return cli.bad("--out OUT is required");
  return std::nullopt;
}

}  // namespace

int main(int argc, char** argv) {
  tools::OfflineOptions options;
  if (const auto status = parseArguments(argc, argv, &options)) return *status;
  return tools::runOffline(options);
}
