// The offline runner (offline_run.h): dataset reading and calls into core::Pipeline / core::SessionManager,
// the nodelets' engine.
#include "offline_run.h"

#include <opencv2/core.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <memory>
#include <set>
#include <string>
#include <vector>

#include "uw_multislam/core/common/ordered_prefetch.h"
#include "uw_multislam/core/export/run_outputs.h"
#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/frontend/image_file.h"
#include "uw_multislam/core/session/pipeline.h"
#include "uw_multislam/core/session/session_manager.h"
#include "uw_multislam/core/session/slam_config.h"
#include "uw_multislam/core/session/stored_loops.h"
#include "uw_multislam/core/store/interrupted_run.h"

namespace uw_multislam::tools {

namespace {

int inStore(const std::string& why) {
  std::fprintf(stderr, "offline_slam: %s\n", why.c_str());
  return kInStore;
}

// Streams whose run in the store `db` was interrupted: without a choice the first
// is refused (kInStore, naming the option); `discard` deletes the run and keeps the stream,
// `finish` marks it finished and drops the stream from `streams`. Only an
// existing store is opened (a new one is created by the session manager); the store is closed
// again before the manager opens it. `finished` gets the ids of the sessions marked finished
// (the stream they belong to is skipped: another stream with the same frames must not be taken
// for it). Returns 0 or the exit status.
int resolveInterrupted(const std::string& db, std::optional<core::InterruptedChoice> choice,
                       std::vector<StreamInput>* streams, std::set<int>* finished) {
  std::error_code ec;
  if (db.empty() || !std::filesystem::is_regular_file(db, ec) || std::filesystem::file_size(db, ec) == 0) return 0;
  core::SessionStore store(db);
  std::vector<StreamInput> kept;
  for (StreamInput& s : *streams) {
    const std::string& name = s.dataset.directory;
    const std::vector<core::InterruptedRun> runs = core::findInterruptedRuns(store, s.dataset.frames);
    bool skip = false;
    for (const core::InterruptedRun& r : runs) {
      const std::string what = "session " + std::to_string(r.ids.back()) + " '" + r.name + "', " +
                               std::to_string(r.keyframes) + " keyframes in " + std::to_string(r.ids.size()) +
                               " session(s)";
      if (!choice)
        return inStore(name + " is in " + db + " from an interrupted run (" + what +
                       ", still recording): pass --interrupted discard (delete it and process the folder again) "
                       "or --interrupted finish (keep it as stored and skip the folder)");
      if (*choice == core::InterruptedChoice::kDiscard) {
        core::resolveInterruptedRun(&store, r, core::InterruptedChoice::kDiscard);
        std::fprintf(stderr,
                     "offline_slam: %s: the interrupted run (%s) deleted from %s; processing the folder again\n",
                     name.c_str(), what.c_str(), db.c_str());
      } else {
        core::resolveInterruptedRun(&store, r, core::InterruptedChoice::kFinish);
        finished->insert(r.ids.begin(), r.ids.end());
        std::fprintf(stderr,
                     "offline_slam: %s: the interrupted run (%s) marked finished as stored in %s; folder skipped\n",
                     name.c_str(), what.c_str(), db.c_str());
        skip = true;
      }
    }
    if (!skip) kept.push_back(std::move(s));
  }
  *streams = std::move(kept);
  return 0;
}

// A bag's progress, a line at each tenth of its recording (and at its end): frames, % of the bag, frames/s.
class Progress {
 public:
  Progress(const StreamInput& s, bool on) : s_(s), on_(on && s.recorded_s > 0.0) {}
  void frame(std::size_t i) {
    if (!on_) return;
    const auto& f = s_.dataset.frames;
    const int tenth = static_cast<int>(10.0 * (f[i].stamp_s - f.front().stamp_s) / s_.recorded_s);
    if (tenth <= tenth_ && i + 1 != f.size()) return;
    tenth_ = tenth;
    const double wall = seconds();
    std::printf("%s: %zu/%zu frames, %.0f %% of the bag, %.1f frames/s\n", s_.dataset.directory.c_str(), i + 1,
                f.size(), 100.0 * (f[i].stamp_s - f.front().stamp_s) / s_.recorded_s,
                wall > 0.0 ? static_cast<double>(i + 1) / wall : 0.0);
    std::fflush(stdout);
  }
  void end() const {
    if (!on_) return;
    const double wall = seconds();
    std::printf("%s: %.1f s recorded processed in %.1f s: %.1fx real time\n", s_.dataset.directory.c_str(),
                s_.recorded_s, wall, wall > 0.0 ? s_.recorded_s / wall : 0.0);
  }

 private:
  double seconds() const { return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0_).count(); }
  const StreamInput& s_;
  bool on_;
  int tenth_ = 0;
  std::chrono::steady_clock::time_point t0_ = std::chrono::steady_clock::now();
};

}  // namespace

bool parseOperatorLink(const std::string& spec, OperatorLink* out) {
  core::Loop* link = &out->loop;
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
  out->measured = f.size() == 9;
  if (out->measured && !(x[3] >= 1e-6 && x[4] >= 1e-6)) return false;  // squared: a covariance the back-end takes
  link->session_a = ids[0];
  link->keyframe_a = ids[1];
  link->session_b = ids[2];
  link->keyframe_b = ids[3];
  link->z = core::UncertainPose2(core::Pose2(x[0], x[1], x[2]),
                                 Eigen::Vector3d(x[3] * x[3], x[3] * x[3], x[4] * x[4]).asDiagonal());
  link->inliers = 0;
  out->yaw = x[2];
  return true;
}

int runOffline(const OfflineOptions& options) {
  const std::string& out = options.out;
  const std::string& db = options.db;
  const bool quiet = options.quiet, again = options.again, detect_loops = options.detect_loops;
  const bool localise_only = options.localise_only;
  const int threads = options.threads;
  const long finish_after = options.finish_after;
  const std::vector<OperatorLink>& links = options.links;
  try {
    core::SlamConfig config =
        options.config_file.empty() ? core::SlamConfig() : core::loadSlamConfig(options.config_file);
    if (options.nav) config.odometry.nav.enabled = *options.nav;
    if (options.dump_config) return std::fputs(core::slamConfigToYaml(config).c_str(), stdout), 0;
    if (localise_only && !std::filesystem::exists(db)) {
      std::fprintf(stderr, "offline_slam: --localise-only: no store %s (it would not be created)\n", db.c_str());
      return 1;
    }
    // Our own workers (below) use the cores: OpenCV's threads inside them would only
    // oversubscribe. (OpenCV's own parallelism, cv::setNumThreads(2), gave 1.41x on the demo on
    // 2 cores, against 1.83x for the workers: SIFT's pyramid is built serially.)
    cv::setNumThreads(1);
    // Every folder, bag and the store are checked before any work or any output.
    std::vector<StreamInput> inputs;
    for (const auto& dir : options.folders) {
      inputs.push_back({core::loadDataset(dir, true, core::StampOrder::kRequired), {}, 0.0, ""});
      if (const std::string bad = core::checkCameraFitsImages(inputs.back().dataset); !bad.empty())
        throw core::DatasetError(bad);
    }
    for (const auto& bag : options.bags) {
      inputs.push_back(options.open_bag(bag, config));
      if (!quiet) std::printf("%s\n", inputs.back().summary.c_str());
    }
    std::set<int> finished_now;
    if (const int refused = resolveInterrupted(db, options.interrupted, &inputs, &finished_now); refused != 0)
      return refused;
    std::vector<core::Dataset> datasets;  // the streams' frames, for the store's checks and inputs.csv
    for (const StreamInput& s : inputs) datasets.push_back(s.dataset);
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
    const int stored = manager.view().restoredSessions();
    // The folders' CSV numbers start at the first id this run gives, past every stored (or
    // deleted) session's id, so that they never name a stored session in the CSV files.
    const int first = manager.view().firstNewId();
    for (std::size_t ds = 0; !again && ds < datasets.size(); ++ds) {
      std::vector<int> s = manager.view().storedSessionsOf(datasets[ds].frames);
      s.erase(std::remove_if(s.begin(), s.end(), [&](int id) { return finished_now.count(id) > 0; }), s.end());
      if (!s.empty())
        return inStore(datasets[ds].directory + " is already in " + db + " (session " + std::to_string(s.front()) +
                       "): pass --again to process it once more as new sessions");
    }
    if (!db.empty() && !quiet)
      std::printf("store %s: %d sessions, %d loops loaded in %.1f ms\n", db.c_str(), stored,
                  static_cast<int>(manager.view().loops().size()),
                  std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
    // The operator's links (the back-end's add_link, offline): all checked and measured before
    // anything is written, so that a refusal adds none of them and leaves OUT alone.
    std::vector<OperatorLink> parsed = links;  // measured in place
    for (auto& [l, measured, yaw] : parsed) {
      // The back-end's add_link checks, in one place; added below, after the folders.
      const core::Status st = core::checkOperatorLink(manager.view(), config, !measured, &l, yaw);
      if (!st.ok()) {
        std::fprintf(stderr, "offline_slam: --add-link %d:%d:%d:%d refused (%s): %s; no link added\n", l.session_a,
                     l.keyframe_a, l.session_b, l.keyframe_b, core::statusCodeName(st.code), st.message.c_str());
        return 1;
      }
    }
    // Creates OUT; folders + config. Outputs take the store's permissions (0600 / 0700 for a 0600 store).
    core::writeRunInputs(out, datasets, first, core::slamConfigToYaml(config), core::outputModesOf(db));
    if (detect_loops) {
      // Global loops among the stored sessions: each one searches the ones stored
      // before it; loops the store holds already are skipped; the back-end joins by its policy.
      std::vector<std::vector<int>> groups;
      for (int s : manager.view().sessionIds())
        if (manager.view().restored(s)) groups.push_back({s});
      const core::StoredLoopSearch f = core::searchStoredLoops(&manager, config, groups, print(""));
      if (!quiet)
        std::printf(
            "detect-loops among %d stored sessions: %d keyframes queried, %d candidates verified, %d loops "
            "(%d already stored), %d accepted, %d refused; %d joins\n",
            stored, f.queries, f.candidates, f.found, f.duplicates, f.accepted, f.refused,
            manager.view().backendStats().joins);
    }
    for (const auto& [l, measured, yaw] : parsed) {  // checked above; the back-end may still refuse one
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
      const StreamInput& in = inputs[ds];
      const core::Dataset& d = in.dataset;
      if (in.image)  // a bag: its frame indexes are the positions of its images
        pipeline.beginStream(
            d.directory, d.camera,
            [&in, &d](int index) {
              const auto f = std::lower_bound(d.frames.begin(), d.frames.end(), index,
                                              [](const core::FrameRecord& r, int i) { return r.index < i; });
              return f == d.frames.end() || f->index != index
                         ? cv::Mat()
                         : in.image(static_cast<std::size_t>(f - d.frames.begin()), nullptr);
            },
            core::NavTrack(d.nav), d.nav_frame);
      else
        pipeline.beginStream(d);  // its camera, its images (thumbnails), its nav.csv
      Progress progress(in, !quiet);
      // --finish-after (the back-end's finish_session, offline): the frames after the first N
      // are dropped and counted, as the odometry drops them after finish_session.
      const std::size_t taken =
          finish_after > 0 ? std::min(d.frames.size(), static_cast<std::size_t>(finish_after)) : d.frames.size();
      // --threads N >= 2: N workers read and prepare (enhance, SIFT) the next
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
            // As the live odometry reads its messages (a cut-off JPEG refused, 16 bits
            // scaled to 8 by the frame's range); grey as BGR, as cv::IMREAD_COLOR gave
            // it before.
            l.image = in.image ? in.image(i, &l.why) : core::readFrameImageBgr(d.imagePath(d.frames[i]), &l.why);
            if (!preparers.empty()) l.prepared = preparers[worker]->prepare(l.image);
            return l;
          });
      frames_read += taken;
      for (std::size_t i = 0; i < taken; ++i) {
        const core::FrameRecord& f = d.frames[i];
        Loaded l = loaded.next();
        if (l.image.empty()) std::fprintf(stderr, "offline_slam: %s: frame %d skipped\n", l.why.c_str(), f.index);
        pipeline.processFrame({f.index, f.stamp_s, f.altitude_m, l.image}, preparers.empty() ? nullptr : &l.prepared);
        progress.frame(i);
      }
      progress.end();
      pipeline.endStream(taken == 0 ? 0.0 : d.frames[taken - 1].stamp_s);
      if (taken < d.frames.size() && !quiet)
        std::printf("%s: session finished after %zu frames (--finish-after), %zu frames dropped\n", d.directory.c_str(),
                    taken, d.frames.size() - taken);
      for (int id : pipeline.streamSessions().back()) csv_of[id] = first + static_cast<int>(ds);
    }
    pipeline.finish();
    const double frames_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - frames_t0).count();
    if (!quiet && frames_read > 0)
      std::printf("throughput: %zu frames in %.2f s wall, %.1f ms/frame (image reading included; --threads %d)\n",
                  frames_read, frames_s, 1000.0 * frames_s / static_cast<double>(frames_read), threads);
    if (!quiet && !datasets.empty()) {
      // The mapping from the command line to ids, once: the CSV files number a folder by its
      // position (from `first`), the store, the services and export_survey by its sessions' ids.
      const std::vector<std::vector<int>>& streams = pipeline.streamSessions();
      std::printf("session ids (CSV session -> store session ids):\n");
      for (std::size_t ds = 0; ds < datasets.size() && ds < streams.size(); ++ds) {
        std::string ids;
        for (int id : streams[ds])
          ids += (ids.empty() ? "" : ", ") + std::to_string(id) + " '" + manager.view().name(id) + "'";
        std::printf("  %d %s -> %s\n", first + static_cast<int>(ds), datasets[ds].directory.c_str(),
                    ids.empty() ? "no session" : ids.c_str());
      }
    }
    core::writeRunOutputs(out, manager.view(), csv_of, first + static_cast<int>(datasets.size()), pipeline.times(),
                          core::outputModesOf(db));
    if (!quiet) {
      const core::BackendStats& bs = manager.view().backendStats();
      const core::LoopStats& ls = pipeline.loopDetector().stats();
      std::printf(
          "back-end (%s): %zu maps, %d joins, %d optimisations (%.1f ms total, %.1f ms max), %d loops refused\n",
          core::optimizerName(config.backend.optimizer), manager.view().mapIds().size(), bs.joins, bs.optimisations,
          bs.optimise_ms_total, bs.optimise_ms_max, bs.loops_refused);
      std::printf(
          "loops: %d local accepted of %d candidates, %d global accepted of %d candidates, %zu keyframes stored\n",
          ls.local_accepted, ls.local_candidates, ls.global_accepted, ls.global_candidates,
          pipeline.loopDetector().size());
    }
    if (manager.view().stats().store_failures > 0) {
      std::fprintf(stderr, "offline_slam: %s: %ld store writes failed (see above); the outputs in %s are complete\n",
                   db.c_str(), manager.view().stats().store_failures, out.c_str());
      return 1;
    }
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "offline_slam: %s\n", e.what());
    return 1;
  }
}

}  // namespace uw_multislam::tools
