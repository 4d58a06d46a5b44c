// offline_slam: runs the SLAM core over dataset folders without a ROS master. The command line
// and output files are the contract of ../shared/DESIGN.md ("The offline runner's contract").
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <optional>
#include <string>
#include <vector>

#include "uw_multislam/core/dataset.h"
#include "uw_multislam/core/backend.h"
#include "uw_multislam/core/loop_detector.h"
#include "uw_multislam/core/odometry.h"
#include "uw_multislam/core/slam_config.h"

namespace core = uw_multislam::core;
namespace fs = std::filesystem;

namespace {

const char* kUsage = R"(usage: offline_slam --session DIR [--session DIR ...] --out OUT [--config FILE] [options]

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

options:
  --session DIR     a dataset folder (repeat for several missions)
  --out OUT         output directory (created)
  --config FILE     YAML configuration (see config/slam.yaml; --dump-config shows every key)
  --threads N       OpenCV threads (default 1: one core, as onboard)
  --dump-config     print the effective configuration and exit
  --quiet           no per-session summary
  -h, --help        this text

Exit status 0 on success, 2 on bad arguments, 1 with a one-line reason on bad input.)";

struct Args {
  std::vector<std::string> sessions;
  std::string out, config;
  int threads = 1;
  bool dump = false, quiet = false;
};

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
    std::vector<std::vector<int>> frame_of_keyframe(datasets.size());
    for (std::size_t s = 0; s < datasets.size(); ++s) {
      const core::Dataset& d = datasets[s];
      core::Odometry odometry(d.camera, config.odometry);
      const int session = backend.startSession(d.directory);
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
        const core::OdometryUpdate u = odometry.process({f.index, f.stamp_s, f.altitude_m, image});
        if (u.status == core::FrameStatus::kSkipped && !image.empty()) {
          std::fprintf(stderr, "offline_slam: session %zu frame %d skipped: %s\n", s, f.index, u.reason.c_str());
        }
        if (u.status == core::FrameStatus::kFallback && !a.quiet) {
          std::fprintf(stderr, "offline_slam: session %zu frame %d: odometry fallback (%s)\n", s, f.index,
                       u.reason.c_str());
        }
        for (const auto& kf : odometry.newKeyframes()) {
          const core::KeyframeInfo& info = odometry.keyframes()[kf.id];
          frame_of_keyframe[s].push_back(info.frame_index);
          if (kf.id > 0) backend.addMotion(session, odometry.trajectory().motion(kf.id));  // (10)(11)
          const std::vector<core::Loop> found = loops.addKeyframe(session, kf.id, info.frame_index, info.altitude_m,
                                                                  &d.camera, kf.features, backend.sessionTrajectory(session));
          core::ScopedStage stage(&times, "backend");
          for (const core::Loop& l : found) {
            loops_csv << l.session_a << "," << l.frame_a << "," << l.session_b << "," << l.frame_b << ","
                      << core::loopKindName(l.kind) << "," << l.inliers << "\n";
            loop_poses << l.session_a << "," << l.frame_a << "," << l.session_b << "," << l.frame_b << ","
                       << l.z.mean.x() << "," << l.z.mean.y() << "," << l.z.mean.yaw() << "\n";
            backend.addLoop({l.session_a, l.keyframe_a, l.session_b, l.keyframe_b, l.z});
          }
        }
      }
      {
        core::ScopedStage stage(&times, "backend");
        backend.endSession(session);
      }
      const auto& poses = odometry.trajectory().absolutePoses();
      for (std::size_t k = 0; k < poses.size(); ++k) {
        odo << s << "," << frame_of_keyframe[s][k] << "," << std::setprecision(6) << poses[k].x() << ","
            << poses[k].y() << "," << std::setprecision(7) << poses[k].yaw() << "\n";
      }
      times.merge(odometry.times());
      if (!a.quiet) {
        const core::OdometryStats& st = odometry.stats();
        std::printf(
            "session %zu (%s): %d frames, %d keyframes, %d tracked, %d fallbacks, %d promotions, %d skipped "
            "(%d image, %d altitude), %d altitudes reused, %.1f ms/frame\n",
            s, d.directory.c_str(), st.frames, st.keyframes, st.tracked, st.fallbacks, st.promotions,
            st.skipped_image + st.skipped_altitude, st.skipped_image, st.skipped_altitude, st.altitude_reused,
            odometry.times().get("odometry_total").meanMs());
      }
    }
    {
      core::ScopedStage stage(&times, "backend");
      backend.flush();
    }
    // The final optimised poses, each session in the frame of its map.
    std::ofstream links_csv(fs::path(a.out) / "links.csv");
    links_csv << "map,previous_session,current_session,loops,x_m,y_m,yaw_rad\n" << std::fixed << std::setprecision(6);
    for (int s = 0; s < backend.numSessions(); ++s) {
      const std::vector<core::Pose2> slam = backend.sessionPoses(s);
      for (std::size_t k = 0; k < slam.size(); ++k) {
        traj << s << "," << frame_of_keyframe[s][k] << "," << backend.mapOf(s) << "," << std::setprecision(6)
             << slam[k].x() << "," << slam[k].y() << "," << std::setprecision(7) << slam[k].yaw() << "\n";
      }
    }
    for (int m : backend.mapIds()) {
      for (const core::LinkInfo& l : backend.links(m)) {
        links_csv << m << "," << l.previous << "," << l.current << "," << l.loops << "," << l.estimate.x() << ","
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
