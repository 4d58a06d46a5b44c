// offline_slam: the SLAM core over dataset folders, no ROS master: argument parsing, dataset reading and
// calls into core::Pipeline / core::SessionManager (the nodelets' engine); contract: --help, doc/run_outputs.md.
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <map>
#include <memory>
#include <set>
#include <string>
#include <vector>

#include "uw_multislam/core/common/ordered_prefetch.h"
#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/frontend/image_file.h"
#include "uw_multislam/core/session/interrupted_run.h"
#include "uw_multislam/core/session/pipeline.h"
#include "uw_multislam/core/session/run_outputs.h"
#include "uw_multislam/core/session/session_manager.h"
#include "uw_multislam/core/session/slam_config.h"
#include "uw_multislam/core/session/stored_loops.h"

namespace core = uw_multislam::core;

namespace {

const char* kUsage = R"(usage: offline_slam --session DIR [--session DIR ...] --out OUT [--config FILE] [--db FILE] [options]

Runs uw_multislam over dataset folders (frames.csv, camera.yaml, images; see
doc/dataset_format.md), in the order given, as consecutive missions. Writes into OUT (columns in
doc/run_outputs.md): odometry.csv (odometry keyframe poses, each session in its own frame), trajectory.csv
(final keyframe poses in the frame of their map), loops.csv, loop_poses.csv (measured pose and covariance),
links.csv (joins), pieces.csv (the pieces tracking loss splits a folder into), timing.csv, inputs.csv, config.yaml.
`session` is the folder's position on the command line, `index` the frame's index in frames.csv.
Sessions are joined into maps through one link (paper §9) once the global loops between them
support it (backend.join_policy: consistent, the default: a pairwise-consistent set of at least
backend.join_min_consistent loops with join_min_inliers inliers and join_min_spread_m spread; count:
backend.join_min_loops loops), and each map is optimised (backend.optimizer); `map` is the map's first session, whose frame it is.

With --db FILE (the session store, created if missing) the stored sessions come first as 0..k-1,
the folders follow from k; global loops are searched against them and everything is written to the
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

constexpr int kInStore = 3;  // a folder already in the store: finished (--again) or interrupted (--interrupted)

int badArgs(const std::string& why) {
  std::fprintf(stderr, "offline_slam: %s (see --help)\n", why.c_str());
  return 2;
}

// --add-link A:KA:B:KB[:X:Y:YAW:SXY:SYAW] -> a link (sessions, keyframes; z when measured). false:
// not that shape, or a number that is not one (sigmas must be > 0).
bool parseLink(const std::string& spec, core::Loop* link, bool* measured) {
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
  return true;
}

int inStore(const std::string& why) {
  std::fprintf(stderr, "offline_slam: %s\n", why.c_str());
  return kInStore;
}

// Folders whose run in the store `db` was interrupted (issue 21, 8): without a choice the first
// is refused (kInStore, naming the option); `discard` deletes the run and keeps the folder,
// `finish` marks it finished and drops the folder from `folders` and `datasets`. Only an
// existing store is opened (a new one is created by the session manager); the store is closed
// again before the manager opens it. `finished` gets the ids of the sessions marked finished
// (the folder they belong to is skipped: another folder with the same frames must not be taken
// for it). Returns 0 or the exit status.
int resolveInterrupted(const std::string& db, const std::string& choice, std::vector<std::string>* folders,
                       std::vector<core::Dataset>* datasets, std::set<int>* finished) {
  std::error_code ec;
  if (db.empty() || !std::filesystem::is_regular_file(db, ec) || std::filesystem::file_size(db, ec) == 0) return 0;
  core::SessionStore store(db);
  std::vector<std::string> kept_folders;
  std::vector<core::Dataset> kept;
  for (std::size_t ds = 0; ds < datasets->size(); ++ds) {
    const std::vector<core::InterruptedRun> runs = core::findInterruptedRuns(store, (*datasets)[ds].frames);
    bool skip = false;
    for (const core::InterruptedRun& r : runs) {
      const std::string what = "session " + std::to_string(r.ids.back()) + " '" + r.name + "', " +
                               std::to_string(r.keyframes) + " keyframes in " + std::to_string(r.ids.size()) +
                               " session(s)";
      if (choice.empty())
        return inStore((*folders)[ds] + " is in " + db + " from an interrupted run (" + what +
                       ", still recording): pass --interrupted discard (delete it and process the folder again) "
                       "or --interrupted finish (keep it as stored and skip the folder)");
      if (choice == "discard") {
        core::resolveInterruptedRun(&store, r, core::InterruptedChoice::kDiscard);
        std::fprintf(stderr,
                     "offline_slam: %s: the interrupted run (%s) deleted from %s; processing the folder again\n",
                     (*folders)[ds].c_str(), what.c_str(), db.c_str());
      } else {
        core::resolveInterruptedRun(&store, r, core::InterruptedChoice::kFinish);
        finished->insert(r.ids.begin(), r.ids.end());
        std::fprintf(stderr,
                     "offline_slam: %s: the interrupted run (%s) marked finished as stored in %s; folder skipped\n",
                     (*folders)[ds].c_str(), what.c_str(), db.c_str());
        skip = true;
      }
    }
    if (skip) continue;
    kept_folders.push_back((*folders)[ds]);
    kept.push_back(std::move((*datasets)[ds]));
  }
  *folders = std::move(kept_folders);
  *datasets = std::move(kept);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<std::string> folders, links;
  std::string out, config_file, db, nav, interrupted;
  int threads = 1;
  long finish_after = 0;  // 0: every frame
  bool dump = false, quiet = false, again = false, detect_loops = false, localise_only = false;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    const bool has_value = i + 1 < argc;
    if (arg == "-h" || arg == "--help") return std::puts(kUsage), 0;
    if (arg == "--session" && has_value) folders.push_back(argv[++i]);
    else if (arg == "--out" && has_value) out = argv[++i];
    else if (arg == "--db" && has_value) db = argv[++i];
    else if (arg == "--config" && has_value) config_file = argv[++i];
    else if (arg == "--dump-config") dump = true;
    else if (arg == "--quiet") quiet = true;
    else if (arg == "--again") again = true;
    else if (arg == "--detect-loops") detect_loops = true;
    else if (arg == "--localise-only") localise_only = true;
    else if (arg == "--nav" && has_value) nav = argv[++i];
    else if (arg == "--interrupted" && has_value) interrupted = argv[++i];
    else if (arg == "--add-link" && has_value) links.push_back(argv[++i]);
    else if (arg == "--finish-after" && has_value) {
      char* end = nullptr;
      finish_after = std::strtol(argv[++i], &end, 10);
      if (*end != '\0' || finish_after < 1 || finish_after > 100000000)
        return badArgs(std::string("bad --finish-after '") + argv[i] + "': a number of frames, 1 or more");
    } else if (arg == "--threads" && has_value) {
      char* end = nullptr;
      const long n = std::strtol(argv[++i], &end, 10);
      if (*end != '\0' || n < 1 || n > 64) return badArgs(std::string("bad --threads '") + argv[i] + "'");
      threads = static_cast<int>(n);
    } else {
      return badArgs(has_value || arg.rfind("--", 0) != 0 ? "unknown argument '" + arg + "'" : arg + " needs a value");
    }
  }
  try {
    core::SlamConfig config = config_file.empty() ? core::SlamConfig() : core::loadSlamConfig(config_file);
    if (!nav.empty() && nav != "on" && nav != "off") return badArgs("--nav takes on or off, not '" + nav + "'");
    if (!nav.empty()) config.odometry.nav.enabled = nav == "on";
    if (!interrupted.empty() && interrupted != "discard" && interrupted != "finish")
      return badArgs("--interrupted takes discard or finish, not '" + interrupted + "'");
    if (!interrupted.empty() && db.empty()) return badArgs("--interrupted needs --db FILE");
    if (dump) return std::fputs(core::slamConfigToYaml(config).c_str(), stdout), 0;
    if (detect_loops && db.empty()) return badArgs("--detect-loops needs --db FILE");
    if (localise_only && db.empty()) return badArgs("--localise-only needs --db FILE");
    if (localise_only && (detect_loops || !interrupted.empty()))
      return badArgs("--localise-only writes nothing to the store: not with --detect-loops or --interrupted");
    if (!links.empty() && db.empty()) return badArgs("--add-link needs --db FILE");
    if (!links.empty() && localise_only) return badArgs("--localise-only writes nothing to the store: not with --add-link");
    std::vector<std::pair<core::Loop, bool>> parsed;  // the link, measured (else found)
    for (const std::string& spec : links) {
      core::Loop l;
      bool measured = false;
      if (!parseLink(spec, &l, &measured))
        return badArgs("bad --add-link '" + spec +
                       "': A:KA:B:KB (find it) or A:KA:B:KB:X:Y:YAW:SXY:SYAW (sigmas >= 1e-6)");
      parsed.emplace_back(l, measured);
    }
    if (folders.empty() && !detect_loops && links.empty()) return badArgs("at least one --session DIR is required");
    if (out.empty()) return badArgs("--out OUT is required");
    if (localise_only && !std::filesystem::exists(db)) {
      std::fprintf(stderr, "offline_slam: --localise-only: no store %s (it would not be created)\n", db.c_str());
      return 1;
    }
    // Our own workers (below) use the cores: OpenCV's threads inside them would only
    // oversubscribe. (OpenCV's own parallelism, cv::setNumThreads(2), gave 1.41x on the demo on
    // 2 cores, against 1.83x for the workers: SIFT's pyramid is built serially.)
    cv::setNumThreads(1);
    // Every folder and the store are checked before any work or any output.
    std::vector<core::Dataset> datasets;
    for (const auto& dir : folders) datasets.push_back(core::loadDataset(dir, true, core::StampOrder::kRequired));
    std::set<int> finished_now;
    if (const int refused = resolveInterrupted(db, interrupted, &folders, &datasets, &finished_now); refused != 0)
      return refused;
    if (datasets.empty() && !detect_loops && links.empty()) {
      std::printf("offline_slam: every folder was skipped: nothing to process\n");
      return 0;
    }
    auto print = [quiet](const char* prefix) {
      return [quiet, prefix](const std::string& line) {
        if (!quiet) std::printf("%s%s\n", prefix, line.c_str());
      };
    };
    const auto t0 = std::chrono::steady_clock::now();
    core::SessionManager manager(core::sessionManagerOptions(config, db), {}, print("backend: "));
    if (localise_only) manager.setLocalisation(true);  // before any keyframe: nothing is written
    core::Pipeline pipeline(config, &manager, print(""), !quiet);
    const int stored = manager.restoredSessions();
    for (std::size_t ds = 0; !again && ds < datasets.size(); ++ds) {
      std::vector<int> s = manager.storedSessionsOf(datasets[ds].frames);
      s.erase(std::remove_if(s.begin(), s.end(), [&](int id) { return finished_now.count(id) > 0; }), s.end());
      if (!s.empty())
        return inStore(folders[ds] + " is already in " + db + " (session " + std::to_string(s.front()) +
                       "): pass --again to process it once more as new sessions");
    }
    if (!db.empty() && !quiet)
      std::printf("store %s: %d sessions, %d loops loaded in %.1f ms\n", db.c_str(), stored,
                  static_cast<int>(manager.loops().size()),
                  std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
    // The operator's links (issue 16, item 4, add_link offline): all checked and measured before
    // anything is written, so that a refusal adds none of them and leaves OUT alone.
    for (auto& [l, measured] : parsed) {
      core::Status st = manager.checkLinkEnds(l);
      if (st.ok()) st = manager.storedMapsMayChange("add-link");
      if (st.ok() && !measured) st = core::findStoredLink(manager, config, &l);
      if (!st.ok()) {
        std::fprintf(stderr, "offline_slam: --add-link %d:%d:%d:%d refused (%s): %s; no link added\n", l.session_a,
                     l.keyframe_a, l.session_b, l.keyframe_b, core::statusCodeName(st.code), st.message.c_str());
        return 1;
      }
    }
    core::writeRunInputs(out, datasets, stored, core::slamConfigToYaml(config));  // creates OUT; folders + config
    if (detect_loops) {
      // Global loops among the stored sessions (issue 16, 3): each one searches the ones stored
      // before it; loops the store holds already are skipped; the back-end joins by its policy.
      std::vector<std::vector<int>> groups;
      for (int s = 0; s < stored; ++s) groups.push_back({s});
      const core::StoredLoopSearch f = core::searchStoredLoops(&manager, config, groups, print(""));
      if (!quiet)
        std::printf("detect-loops among %d stored sessions: %d keyframes queried, %d candidates verified, %d loops "
                    "(%d already stored), %d accepted, %d refused; %d joins\n",
                    stored, f.queries, f.candidates, f.found, f.duplicates, f.accepted, f.refused,
                    manager.backendStats().joins);
    }
    for (const auto& [l, measured] : parsed) {  // checked above; the back-end may still refuse one
      const core::Status st = manager.addLink(l);
      if (!st.ok()) {
        std::fprintf(stderr, "offline_slam: --add-link %d:%d:%d:%d refused (%s): %s (the links before it are added)\n",
                     l.session_a, l.keyframe_a, l.session_b, l.keyframe_b, core::statusCodeName(st.code),
                     st.message.c_str());
        return 1;
      }
      if (!quiet)
        std::printf("add-link %d:%d -> %d:%d: (%.4f, %.4f, %.4f) %s, %d inliers: added\n", l.session_a, l.keyframe_a,
                    l.session_b, l.keyframe_b, l.z.mean.x(), l.z.mean.y(), l.z.mean.yaw(),
                    measured ? "as given" : "found by RANSAC", l.inliers);
    }

    std::map<int, int> csv_of;  // session id -> the folder's number (stored sessions keep their id)
    const auto frames_t0 = std::chrono::steady_clock::now();
    std::size_t frames_read = 0;
    for (std::size_t ds = 0; ds < datasets.size(); ++ds) {
      const core::Dataset& d = datasets[ds];
      pipeline.beginStream(d);  // its camera, its images (thumbnails), its nav.csv
      // --finish-after (finish_session offline, issue 16 item 4): the frames after the first N
      // are dropped and counted, as the odometry drops them after finish_session.
      const std::size_t taken =
          finish_after > 0 ? std::min(d.frames.size(), static_cast<std::size_t>(finish_after)) : d.frames.size();
      // --threads N >= 2 (issue 19, item 3): N workers read and prepare (enhance, SIFT) the next
      // frames while this thread runs the odometry's matching, loops and back-end on the current
      // one; a prepared frame gives the same output as one the odometry prepares itself.
      std::vector<std::unique_ptr<core::FramePreparer>> preparers;
      for (int w = 0; threads > 1 && w < threads; ++w)
        preparers.push_back(std::make_unique<core::FramePreparer>(pipeline.preparer()));
      struct Loaded {
        cv::Mat image;
        std::string why;  // when the image could not be used
        core::PreparedFrame prepared;
      };
      core::OrderedPrefetch<Loaded> loaded(
          taken, threads > 1 ? threads : 0, 2 * static_cast<std::size_t>(threads), [&](std::size_t i, int worker) {
            Loaded l;
            // As the live odometry reads its messages (a cut-off JPEG refused, 16 bits scaled to
            // 8 by the frame's range); grey as BGR, as cv::IMREAD_COLOR gave it before.
            l.image = core::readFrameImageBgr(d.imagePath(d.frames[i]), &l.why);
            if (!preparers.empty()) l.prepared = preparers[worker]->prepare(l.image);
            return l;
          });
      frames_read += taken;
      for (std::size_t i = 0; i < taken; ++i) {
        const core::FrameRecord& f = d.frames[i];
        Loaded l = loaded.next();
        if (l.image.empty()) std::fprintf(stderr, "offline_slam: %s: frame %d skipped\n", l.why.c_str(), f.index);
        pipeline.processFrame({f.index, f.stamp_s, f.altitude_m, l.image}, preparers.empty() ? nullptr : &l.prepared);
      }
      pipeline.endStream(taken == 0 ? 0.0 : d.frames[taken - 1].stamp_s);
      if (taken < d.frames.size() && !quiet)
        std::printf("%s: session finished after %zu frames (--finish-after), %zu frames dropped\n",
                    folders[ds].c_str(), taken, d.frames.size() - taken);
      for (int id : pipeline.streamSessions().back()) csv_of[id] = stored + static_cast<int>(ds);
    }
    pipeline.finish();
    const double frames_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - frames_t0).count();
    if (!quiet && frames_read > 0)
      std::printf("throughput: %zu frames in %.2f s wall, %.1f ms/frame (image reading included; --threads %d)\n",
                  frames_read, frames_s, 1000.0 * frames_s / static_cast<double>(frames_read), threads);
    core::writeRunOutputs(out, manager, csv_of, stored + static_cast<int>(datasets.size()), pipeline.times());
    if (!quiet) {
      const core::BackendStats& bs = manager.backendStats();
      const core::LoopStats& ls = pipeline.loopDetector().stats();
      std::printf("back-end (%s): %zu maps, %d joins, %d optimisations (%.1f ms total, %.1f ms max), %d loops refused\n",
                  core::optimizerName(config.backend.optimizer), manager.mapIds().size(), bs.joins, bs.optimisations,
                  bs.optimise_ms_total, bs.optimise_ms_max, bs.loops_refused);
      std::printf("loops: %d local accepted of %d candidates, %d global accepted of %d candidates, %zu keyframes stored\n",
                  ls.local_accepted, ls.local_candidates, ls.global_accepted, ls.global_candidates,
                  pipeline.loopDetector().size());
    }
    if (manager.stats().store_failures > 0) {
      std::fprintf(stderr, "offline_slam: %s: %ld store writes failed (see above); the outputs in %s are complete\n",
                   db.c_str(), manager.stats().store_failures, out.c_str());
      return 1;
    }
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "offline_slam: %s\n", e.what());
    return 1;
  }
}
