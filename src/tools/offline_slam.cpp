// offline_slam: runs the SLAM core over dataset folders without a ROS master. The command line
// and output files are the contract of ../shared/DESIGN.md ("The offline runner's contract").
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <optional>
#include <string>
#include <vector>

#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/backend/backend.h"
#include "uw_multislam/core/loops/loop_detector.h"
#include "uw_multislam/core/frontend/odometry.h"
#include "uw_multislam/core/session/map_persistence.h"
#include "uw_multislam/core/session/session_store.h"
#include "uw_multislam/core/session/slam_config.h"
#include "uw_multislam/core/frontend/tracking.h"

namespace core = uw_multislam::core;
namespace fs = std::filesystem;

namespace {

const char* kUsage = R"(usage: offline_slam --session DIR [--session DIR ...] --out OUT [--config FILE] [--db FILE] [options]

Runs uw_multislam over dataset folders (frames.csv, camera.yaml, images; see
../shared/data/README.md), in the order given, as consecutive missions. Writes into OUT:
  odometry.csv    session,index,x_m,y_m,yaw_rad          odometry keyframe poses, each session in its own frame
  trajectory.csv  session,index,map,x_m,y_m,yaw_rad      final keyframe poses in the frame of map `map`
  loops.csv       session_a,index_a,session_b,index_b,kind,inliers   accepted loops
  loop_poses.csv  session_a,index_a,session_b,index_b,x_m,y_m,yaw_rad  each loop's measured pose of b in a
  links.csv       map,previous_session,current_session,loops,x_m,y_m,yaw_rad   the links joining sessions
  timing.csv      stage,calls,total_ms,mean_ms,max_ms    one row per pipeline stage
`session` is the folder's position on the command line, `index` the frame's index in frames.csv.
Local loops (within a session) and global loops (across sessions, hashes) are detected and
written to loops.csv. Sessions are joined into maps once backend.join_min_loops global loops
link them (paper §9); each map is optimised with its loops by the selected back-end
(backend.optimizer: sparse, the default, or the paper's iekf). `map` in trajectory.csv is the
id of the map's first session, whose frame the poses are in; a session left alone is its own map.

With --db FILE (the session store, created if missing) the sessions already stored are loaded
first and take the numbers 0..k-1 in store order; the folders follow from k. Global loops are
searched against the stored sessions too, stored sessions appear in every output file, and the
new sessions, keyframes, loops, joins and splits are written to the store as they happen (one
transaction per keyframe).

options:
  --session DIR     a dataset folder (repeat for several missions)
  --out OUT         output directory (created)
  --config FILE     YAML configuration (see config/slam.yaml; --dump-config shows every key)
  --db FILE         the session store (SQLite) to read and extend
  --threads N       OpenCV threads (default 1: one core, as onboard)
  --dump-config     print the effective configuration and exit
  --quiet           no per-session summary
  -h, --help        this text

Exit status 0 on success, 2 on bad arguments, 1 with a one-line reason on bad input.)";

struct Args {
  std::vector<std::string> sessions;
  std::string out, config, db;
  int threads = 1;
  bool dump = false, quiet = false;
};

// A small grey JPEG of a keyframe for viewing the store (empty if there is no image).
std::vector<std::uint8_t> thumbnail(const cv::Mat& image) {
  std::vector<std::uint8_t> jpeg;
  if (image.empty()) return jpeg;
  cv::Mat grey, small;
  if (image.channels() == 3) cv::cvtColor(image, grey, cv::COLOR_BGR2GRAY);
  else grey = image;
  const double f = 96.0 / std::max(grey.cols, grey.rows);
  cv::resize(grey, small, cv::Size(), f, f, cv::INTER_AREA);
  cv::imencode(".jpg", small, jpeg, {cv::IMWRITE_JPEG_QUALITY, 70});
  return jpeg;
}

const core::FrameRecord& frameOf(const core::Dataset& d, int index) {
  for (const core::FrameRecord& f : d.frames)
    if (f.index == index) return f;
  throw std::logic_error("no frame " + std::to_string(index));
}

int badArgs(const std::string& why) {
  std::fprintf(stderr, "offline_slam: %s (see --help)\n", why.c_str());
  return 2;
}

void writeTiming(const std::string& path, const core::StageTimes& t) {
  std::ofstream out(path);
  out << "stage,calls,total_ms,mean_ms,max_ms\n" << std::fixed << std::setprecision(3);
  for (const auto& s : t.stats()) {
    out << s.stage << "," << s.calls << "," << s.total_ms << "," << s.meanMs() << "," << s.max_ms << "\n";
  }
  if (!out) throw core::DatasetError(path + ": cannot write");
}

}  // namespace

int main(int argc, char** argv) {
  Args a;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    const bool has_value = i + 1 < argc;
    if (arg == "-h" || arg == "--help") {
      std::puts(kUsage);
      return 0;
    } else if (arg == "--session" && has_value) {
      a.sessions.push_back(argv[++i]);
    } else if (arg == "--out" && has_value) {
      a.out = argv[++i];
    } else if (arg == "--db" && has_value) {
      a.db = argv[++i];
    } else if (arg == "--config" && has_value) {
      a.config = argv[++i];
    } else if (arg == "--threads" && has_value) {
      char* end = nullptr;
      const long n = std::strtol(argv[++i], &end, 10);
      if (*end != '\0' || n < 1 || n > 64) return badArgs(std::string("bad --threads '") + argv[i] + "'");
      a.threads = static_cast<int>(n);
    } else if (arg == "--dump-config") {
      a.dump = true;
    } else if (arg == "--quiet") {
      a.quiet = true;
    } else {
      return badArgs(has_value || arg.rfind("--", 0) != 0 ? "unknown argument '" + arg + "'" : arg + " needs a value");
    }
  }
  try {
    const core::SlamConfig config = a.config.empty() ? core::SlamConfig() : core::loadSlamConfig(a.config);
    if (a.dump) {
      std::fputs(core::slamConfigToYaml(config).c_str(), stdout);
      return 0;
    }
    if (a.sessions.empty()) return badArgs("at least one --session DIR is required");
    if (a.out.empty()) return badArgs("--out OUT is required");
    cv::setNumThreads(a.threads);

    // Check every folder before any work, so a typo in the last one does not cost a long run.
    std::vector<core::Dataset> datasets;
    for (const auto& dir : a.sessions) datasets.push_back(core::loadDataset(dir));
    // The session store is checked before anything is written, too.
    std::optional<core::SessionStore> store;
    const auto store_t0 = std::chrono::steady_clock::now();
    if (!a.db.empty()) store.emplace(a.db);
    fs::create_directories(a.out);

    std::ofstream odo(fs::path(a.out) / "odometry.csv"), traj(fs::path(a.out) / "trajectory.csv");
    odo << "session,index,x_m,y_m,yaw_rad\n" << std::fixed;
    traj << "session,index,map,x_m,y_m,yaw_rad\n" << std::fixed;
    std::ofstream loops_csv(fs::path(a.out) / "loops.csv"), loop_poses(fs::path(a.out) / "loop_poses.csv");
    loops_csv << "session_a,index_a,session_b,index_b,kind,inliers\n";
    loop_poses << "session_a,index_a,session_b,index_b,x_m,y_m,yaw_rad\n" << std::fixed << std::setprecision(6);
    core::StageTimes times;
    core::LoopDetector loops(config.loops, config.odometry.matching, config.odometry.ransac,
                             config.odometry.features.num_features);
    core::MultiSessionBackend backend(config.backend, [&](const std::string& line) {
      if (!a.quiet) std::printf("backend: %s\n", line.c_str());
    });
    // The session store: stored sessions first (numbers 0..k-1), then the folders.
    std::vector<std::unique_ptr<core::CameraIntrinsics>> stored_cameras;
    core::RestoredStore restored;
    std::vector<std::int64_t> store_session_ids, store_loop_ids;  // back-end id -> store id
    if (store) {
      core::ScopedStage stage(&times, "store_load");
      store->checkHashSettings({config.loops.global.hash_mode, config.loops.global.projection_seed,
                                config.odometry.features.num_features, loops.hasher().projections().toText()});
      restored = core::restoreStore(*store, &backend, &loops, &stored_cameras);
      store_session_ids = restored.session_ids;
      store_loop_ids = restored.loop_ids;
      if (!a.quiet)
        std::printf("store %s: %d sessions, %d keyframes, %d loops loaded in %.1f ms\n", a.db.c_str(),
                    backend.numSessions(), restored.keyframes, backend.numLoops(),
                    std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - store_t0).count());
    }
    const int first_new = backend.numSessions();
    std::vector<std::vector<int>> frame_of_keyframe = restored.frame_of_keyframe;
    frame_of_keyframe.resize(first_new);
    // Stored sessions in odometry.csv and loops.csv like the others.
    for (int s = 0; s < first_new; ++s) {
      core::Trajectory t;
      for (const core::UncertainPose2& m : store->odometry(store_session_ids[s])) t.append(m);
      for (std::size_t k = 0; k < t.numKeyframes(); ++k) {
        const core::Pose2 p = t.absolutePose(static_cast<int>(k));
        odo << s << "," << frame_of_keyframe[s][k] << "," << std::setprecision(6) << p.x() << "," << p.y() << ","
            << std::setprecision(7) << p.yaw() << "\n";
      }
    }
    for (int id = 0; id < backend.numLoops(); ++id) {
      const core::BackendLoop l = backend.loopRecord(id).loop;
      const int fa = frame_of_keyframe[l.session_a][l.keyframe_a], fb = frame_of_keyframe[l.session_b][l.keyframe_b];
      loops_csv << l.session_a << "," << fa << "," << l.session_b << "," << fb << ","
                << (restored.loops[id].global ? "global" : "local") << "," << restored.loops[id].inliers << "\n";
      loop_poses << l.session_a << "," << fa << "," << l.session_b << "," << fb << "," << l.z.mean.x() << ","
                 << l.z.mean.y() << "," << l.z.mean.yaw() << "\n";
    }
    int saved_joins = backend.stats().joins, saved_splits = backend.stats().splits;
    auto saveMaps = [&]() {
      if (!store) return;
      core::ScopedStage stage(&times, "store");
      core::saveBackendMaps(&*store, backend, store_session_ids, store_loop_ids);
      saved_joins = backend.stats().joins;
      saved_splits = backend.stats().splits;
    };
    // Back-end sessions: stored ones first, then one or more per folder (a new one each time
    // tracking is lost, see core/frontend/tracking.h). The CSV files number sessions by folder (DESIGN.md).
    std::vector<int> csv_of(first_new);
    for (int b = 0; b < first_new; ++b) csv_of[b] = b;
    for (std::size_t ds = 0; ds < datasets.size(); ++ds) {
      const core::Dataset& d = datasets[ds];
      const int csv = first_new + static_cast<int>(ds);
      core::SegmentedOdometry segmented(d.camera, config.odometry, config.tracking);
      int session = -1;  // the back-end session of the current piece of this folder
      int pieces = 0;
      auto startPiece = [&](double stamp_s) {
        const std::string name = pieces == 0 ? d.directory : d.directory + "#" + std::to_string(pieces);
        ++pieces;
        session = backend.startSession(name);
        csv_of.push_back(csv);
        frame_of_keyframe.resize(backend.numSessions());
        if (store) {
          core::ScopedStage stage(&times, "store");
          store_session_ids.push_back(store->addSession(name, d.camera, stamp_s));
        }
      };
      auto endPiece = [&](double stamp_s) {
        {
          core::ScopedStage stage(&times, "backend");
          backend.endSession(session);
        }
        if (store) {
          store->endSession(store_session_ids[session], stamp_s);
          saveMaps();
        }
        const core::Odometry& odometry = *segmented.odometry();
        const auto& poses = odometry.trajectory().absolutePoses();
        for (std::size_t k = 0; k < static_cast<std::size_t>(segmented.keptKeyframes()); ++k) {
          odo << csv << "," << frame_of_keyframe[session][k] << "," << std::setprecision(6) << poses[k].x() << ","
              << poses[k].y() << "," << std::setprecision(7) << poses[k].yaw() << "\n";
        }
        if (!a.quiet) {
          const core::OdometryStats& st = odometry.stats();
          std::printf(
              "session %d (%s%s): %d frames, %d keyframes, %d tracked, %d fallbacks, %d promotions, %d skipped "
              "(%d image, %d altitude), %d altitudes reused, %.1f ms/frame\n",
              csv, d.directory.c_str(), pieces > 1 ? (" piece " + std::to_string(pieces)).c_str() : "", st.frames,
              st.keyframes, st.tracked, st.fallbacks, st.promotions, st.skipped_image + st.skipped_altitude,
              st.skipped_image, st.skipped_altitude, st.altitude_reused,
              odometry.times().get("odometry_total").meanMs());
        }
        session = -1;
      };
      for (const auto& f : d.frames) {
        cv::Mat image;
        {
          core::ScopedStage stage(&times, "load_image");
          image = cv::imread(d.imagePath(f), cv::IMREAD_COLOR);
        }
        if (image.empty()) {
          std::fprintf(stderr, "offline_slam: %s: cannot decode image of frame %d, skipped\n", d.imagePath(f).c_str(),
                       f.index);
        }
        const core::SegmentedOdometry::Step step = segmented.process({f.index, f.stamp_s, f.altitude_m, image});
        const core::OdometryUpdate& u = step.update;
        if (step.session_started) {
          startPiece(f.stamp_s);
          if (pieces > 1 && !a.quiet)
            std::printf("session %d: tracking resumed at frame %d: new back-end session %d\n", csv, f.index, session);
        }
        if (u.status == core::FrameStatus::kSkipped && !image.empty()) {
          std::fprintf(stderr, "offline_slam: session %d frame %d skipped: %s\n", csv, f.index, u.reason.c_str());
        }
        if (u.status == core::FrameStatus::kFallback && !a.quiet) {
          std::fprintf(stderr, "offline_slam: session %d frame %d: odometry fallback (%s)\n", csv, f.index,
                       u.reason.c_str());
        }
        if (session < 0) continue;  // no session open: tracking lost
        const core::Odometry& odometry = *segmented.odometry();
        for (const auto& kf : segmented.newKeyframes()) {
          const core::KeyframeInfo& info = odometry.keyframes()[kf.id];
          frame_of_keyframe[session].push_back(info.frame_index);
          if (kf.id > 0) backend.addMotion(session, odometry.trajectory().motion(kf.id));  // (10)(11)
          const std::vector<core::Loop> found = loops.addKeyframe(session, kf.id, info.frame_index, info.altitude_m,
                                                                  &d.camera, kf.features, backend.sessionTrajectory(session));
          std::vector<core::StoredLoop> stored_loops;
          if (store) {
            // One transaction: the keyframe, its odometry motion, the loops it closed.
            core::ScopedStage stage(&times, "store");
            core::StoredKeyframe sk;
            sk.session = store_session_ids[session];
            sk.keyframe = kf.id;
            sk.frame_index = info.frame_index;
            sk.stamp_s = info.stamp_s;
            sk.altitude_m = info.altitude_m;
            sk.image_size = kf.features.image_size;
            for (const cv::KeyPoint& p : kf.features.keypoints) sk.points.push_back(p.pt);
            sk.descriptors = kf.features.descriptors;
            sk.hash = loops.lastHash();
            sk.thumbnail = thumbnail(info.frame_index == f.index ? image : cv::imread(d.imagePath(frameOf(d, info.frame_index)), cv::IMREAD_COLOR));
            for (const core::Loop& l : found) {
              core::StoredLoop sl;
              sl.session_a = store_session_ids[l.session_a];
              sl.keyframe_a = l.keyframe_a;
              sl.session_b = store_session_ids[l.session_b];
              sl.keyframe_b = l.keyframe_b;
              sl.global = l.kind == core::Loop::Kind::kGlobal;
              sl.inliers = l.inliers;
              sl.z = l.z;
              stored_loops.push_back(sl);
            }
            const core::UncertainPose2 motion = kf.id > 0 ? odometry.trajectory().motion(kf.id) : core::UncertainPose2();
            store->addKeyframe(sk, kf.id > 0 ? &motion : nullptr, &stored_loops);
            for (const core::StoredLoop& sl : stored_loops) store_loop_ids.push_back(sl.id);
          }
          core::ScopedStage stage(&times, "backend");
          for (const core::Loop& l : found) {
            loops_csv << csv_of[l.session_a] << "," << l.frame_a << "," << csv_of[l.session_b] << "," << l.frame_b << ","
                      << core::loopKindName(l.kind) << "," << l.inliers << "\n";
            loop_poses << csv_of[l.session_a] << "," << l.frame_a << "," << csv_of[l.session_b] << "," << l.frame_b << ","
                       << l.z.mean.x() << "," << l.z.mean.y() << "," << l.z.mean.yaw() << "\n";
            backend.addLoop({l.session_a, l.keyframe_a, l.session_b, l.keyframe_b, l.z});
          }
          if (store && !store_loop_ids.empty() && static_cast<int>(store_loop_ids.size()) != backend.numLoops())
            throw std::logic_error("store and back-end loop counts differ");
          if (backend.stats().joins != saved_joins || backend.stats().splits != saved_splits) saveMaps();
        }
        if (step.session_closed) {
          if (!a.quiet)
            std::printf("session %d: tracking lost at frame %d (%d unmatched frames): back-end session %d closed\n",
                        csv, f.index, config.tracking.max_fallbacks, session);
          endPiece(f.stamp_s);
        }
      }
      if (session >= 0) endPiece(d.frames.empty() ? 0.0 : d.frames.back().stamp_s);
      times.merge(segmented.times());
    }
    {
      core::ScopedStage stage(&times, "backend");
      backend.flush();
    }
    saveMaps();
    // The final optimised poses, each session in the frame of its map.
    std::ofstream links_csv(fs::path(a.out) / "links.csv");
    links_csv << "map,previous_session,current_session,loops,x_m,y_m,yaw_rad\n" << std::fixed << std::setprecision(6);
    // Map labels: a map is named after its first session; a folder's first piece keeps the folder's
    // number, further pieces (tracking loss) take numbers after the last folder's.
    std::vector<int> label(backend.numSessions());
    int next_label = first_new + static_cast<int>(datasets.size());
    for (int b = 0; b < backend.numSessions(); ++b) label[b] = (b > 0 && csv_of[b] == csv_of[b - 1]) ? next_label++ : csv_of[b];
    for (int s = 0; s < backend.numSessions(); ++s) {
      const std::vector<core::Pose2> slam = backend.sessionPoses(s);
      for (std::size_t k = 0; k < slam.size(); ++k) {
        traj << csv_of[s] << "," << frame_of_keyframe[s][k] << "," << label[backend.mapOf(s)] << "," << std::setprecision(6)
             << slam[k].x() << "," << slam[k].y() << "," << std::setprecision(7) << slam[k].yaw() << "\n";
      }
    }
    for (int m : backend.mapIds()) {
      for (const core::LinkInfo& l : backend.links(m)) {
        links_csv << label[m] << "," << csv_of[l.previous] << "," << csv_of[l.current] << "," << l.loops << ","
                  << l.estimate.x() << ","
                  << l.estimate.y() << "," << l.estimate.yaw() << "\n";
      }
    }
    if (!a.quiet) {
      const core::BackendStats& bs = backend.stats();
      std::printf("back-end (%s): %zu maps, %d joins, %d optimisations (%.1f ms total, %.1f ms max), %d loops refused\n",
                  core::optimizerName(config.backend.optimizer), backend.mapIds().size(), bs.joins, bs.optimisations,
                  bs.optimise_ms_total, bs.optimise_ms_max, bs.loops_refused);
    }
    times.merge(loops.times());
    if (!a.quiet) {
      const core::LoopStats& ls = loops.stats();
      std::printf(
          "loops: %d local accepted of %d candidates, %d global accepted of %d candidates, %zu keyframes stored\n",
          ls.local_accepted, ls.local_candidates, ls.global_accepted, ls.global_candidates, loops.size());
    }
    writeTiming((fs::path(a.out) / "timing.csv").string(), times);
    if (!odo || !traj || !loops_csv || !loop_poses || !links_csv) throw core::DatasetError(a.out + ": cannot write the output files");
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "offline_slam: %s\n", e.what());
    return 1;
  }
}
