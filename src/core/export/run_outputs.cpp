#include "uw_multislam/core/export/run_outputs.h"

#include <cmath>
#include <filesystem>
#include <iomanip>
#include <memory>

#include "uw_multislam/core/common/atomic_file.h"

#include "uw_multislam/core/frontend/dataset.h"

namespace uw_multislam {
namespace core {

void writeRunOutputs(const std::string& out_dir, const SessionQueries& manager, const std::map<int, int>& csv_of,
                     int first_free_label, const StageTimes& times, const OutputModes& modes) {
  namespace fs = std::filesystem;
  auto csv = [&](int id) {
    const auto it = csv_of.find(id);
    return it == csv_of.end() ? id : it->second;
  };
  // Each file written atomically (core/common/atomic_file.h), renamed into place once all are
  // complete: a failure leaves the previous files, or none, never a half-written one.
  std::map<std::string, std::unique_ptr<AtomicFile>> files;
  auto file = [&](const char* name) -> std::ostream& {
    try {
      auto& f = files[name];
      f = std::make_unique<AtomicFile>((fs::path(out_dir) / name).string(), modes.file);
      return f->stream();
    } catch (const FileWriteError& e) {
      throw DatasetError(out_dir + ": cannot write the output files: " + e.what());
    }
  };
  std::ostream& odo = file("odometry.csv");
  std::ostream& traj = file("trajectory.csv");
  std::ostream& loops = file("loops.csv");
  std::ostream& loop_poses = file("loop_poses.csv");
  std::ostream& links = file("links.csv");
  std::ostream& timing = file("timing.csv");
  std::ostream& motions = file("motions.csv");
  motions << "session,index,source\n";
  odo << "session,index,x_m,y_m,yaw_rad\n" << std::fixed;
  traj << "session,index,map,x_m,y_m,yaw_rad\n" << std::fixed;
  loops << "session_a,index_a,session_b,index_b,kind,inliers\n";
  // The loops the back-end refused (inconsistent at a join, or gated inside a map): not in
  // loops.csv, whose contract is the accepted loops; the same columns in a file of their own.
  std::ostream& refused = file("loops_refused.csv");
  refused << "session_a,index_a,session_b,index_b,kind,inliers\n";
  loop_poses
      << "session_a,index_a,session_b,index_b,x_m,y_m,yaw_rad,cov_xx,cov_xy,cov_xyaw,cov_yy,cov_yyaw,cov_yawyaw\n"
      << std::fixed << std::setprecision(6);
  links << "map,previous_session,current_session,loops,x_m,y_m,yaw_rad,previous_piece,current_piece\n"
        << std::fixed << std::setprecision(6);
  // Map labels: a session that shares its CSV number with the session before it (a later piece
  // of one folder, after a tracking loss) labels its map with the next free number. Pieces are
  // numbered from 0 within their folder, in session order.
  std::map<int, int> label, piece;
  int previous = -1, next_label = first_free_label;
  for (int id : manager.sessionIds()) {
    const bool later_piece = previous >= 0 && csv(id) == csv(previous);
    label[id] = later_piece ? next_label++ : csv(id);
    piece[id] = later_piece ? piece[previous] + 1 : 0;
    previous = id;
  }
  // pieces.csv: which session of the engine (and of the store) each piece of a folder is.
  std::ostream& pieces = file("pieces.csv");
  pieces << "session,piece,store_session,first_index,last_index,keyframes,map\n";
  for (int id : manager.sessionIds()) {
    const std::vector<int>& frames = manager.frames(id);
    pieces << csv(id) << "," << piece.at(id) << "," << id << "," << (frames.empty() ? -1 : frames.front()) << ","
           << (frames.empty() ? -1 : frames.back()) << "," << frames.size() << "," << label.at(manager.mapOf(id))
           << "\n";
  }
  for (int id : manager.sessionIds()) {
    const std::vector<Pose2>& o = manager.odometryPoses(id);
    const std::vector<int>& frames = manager.frames(id);
    for (std::size_t k = 0; k < o.size(); ++k)
      odo << csv(id) << "," << frames[k] << "," << std::setprecision(6) << o[k].x() << "," << o[k].y() << ","
          << std::setprecision(7) << o[k].yaw() << "\n";
  }
  for (int id : manager.sessionIds()) {
    const std::vector<MotionSource>& sources = manager.motionSources(id);
    const std::vector<int>& frames = manager.frames(id);
    for (std::size_t k = 1; k < sources.size() && k < frames.size(); ++k)
      motions << csv(id) << "," << frames[k] << "," << motionSourceName(sources[k]) << "\n";
  }
  for (int id : manager.sessionIds()) {
    const std::vector<Pose2> p = manager.poses(id);
    const std::vector<int>& frames = manager.frames(id);
    const int map = label.at(manager.mapOf(id));
    for (std::size_t k = 0; k < p.size(); ++k)
      traj << csv(id) << "," << frames[k] << "," << map << "," << std::setprecision(6) << p[k].x() << "," << p[k].y()
           << "," << std::setprecision(7) << p[k].yaw() << "\n";
  }
  // The nav's placements of sessions (SessionManager::addNavPlacement) are no visual loops: a file of
  // their own, so that loops.csv stays the loops the images measured (evaluate.py scores them).
  std::ostream& placements = file("nav_placements.csv");
  placements << "session_a,index_a,session_b,index_b,x_m,y_m,yaw_rad,sigma_xy_m,sigma_yaw_rad\n"
             << std::fixed << std::setprecision(6);
  for (const Loop& l : manager.loops()) {
    if (!l.nav_placement) continue;
    placements << csv(l.session_a) << "," << l.frame_a << "," << csv(l.session_b) << "," << l.frame_b << ","
               << l.z.mean.x() << "," << l.z.mean.y() << "," << l.z.mean.yaw() << "," << std::sqrt(l.z.covariance(0, 0))
               << "," << std::sqrt(l.z.covariance(2, 2)) << "\n";
  }
  for (std::size_t i = 0; i < manager.loops().size(); ++i) {
    const Loop& l = manager.loops()[i];
    if (l.nav_placement) continue;
    (manager.loopRefused(i) ? refused : loops) << csv(l.session_a) << "," << l.frame_a << "," << csv(l.session_b) << ","
                                               << l.frame_b << "," << loopKindName(l.kind) << "," << l.inliers << "\n";
    loop_poses << csv(l.session_a) << "," << l.frame_a << "," << csv(l.session_b) << "," << l.frame_b << ","
               << l.z.mean.x() << "," << l.z.mean.y() << "," << l.z.mean.yaw() << std::scientific
               << std::setprecision(9);
    const Eigen::Matrix3d& c = l.z.covariance;
    loop_poses << "," << c(0, 0) << "," << c(0, 1) << "," << c(0, 2) << "," << c(1, 1) << "," << c(1, 2) << ","
               << c(2, 2) << "\n"
               << std::fixed << std::setprecision(6);
  }
  for (const SessionLink& l : manager.links())
    links << label.at(l.map) << "," << csv(l.previous) << "," << csv(l.current) << "," << l.loops << ","
          << l.estimate.x() << "," << l.estimate.y() << "," << l.estimate.yaw() << "," << piece.at(l.previous) << ","
          << piece.at(l.current) << "\n";
  timing << "stage,calls,total_ms,mean_ms,max_ms\n" << std::fixed << std::setprecision(3);
  for (const auto& s : times.stats())
    timing << s.stage << "," << s.calls << "," << s.total_ms << "," << s.meanMs() << "," << s.max_ms << "\n";
  try {
    for (auto& [name, f] : files) f->commit();
  } catch (const FileWriteError& e) {
    throw DatasetError(out_dir + ": cannot write the output files: " + e.what());
  }
}

void writeRunInputs(const std::string& out_dir, const std::vector<Dataset>& datasets, int first_number,
                    const std::string& config_yaml, const OutputModes& modes) {
  namespace fs = std::filesystem;
  try {
    makeDirectories(out_dir, modes.directory);
  } catch (const FileWriteError& e) {
    throw DatasetError(std::string(e.what()) + " (cannot write inputs.csv)");
  }
  auto atomic = [&](const char* name) {
    try {
      return std::make_unique<AtomicFile>((fs::path(out_dir) / name).string(), modes.file);
    } catch (const FileWriteError& e) {
      throw DatasetError(out_dir + ": cannot write " + name + ": " + e.what());
    }
  };
  auto commit = [&](AtomicFile* file, const char* name) {
    try {
      file->commit();
    } catch (const FileWriteError& e) {
      throw DatasetError(out_dir + ": cannot write " + name + ": " + e.what());
    }
  };
  const std::unique_ptr<AtomicFile> inputs = atomic("inputs.csv");
  std::ostream& f = inputs->stream();
  f << "session,folder,frames,first_stamp_s,last_stamp_s,altitude_mean_m\n" << std::fixed << std::setprecision(6);
  for (std::size_t ds = 0; ds < datasets.size(); ++ds) {
    const Dataset& d = datasets[ds];
    std::string folder;  // CSV-quoted: a path may hold a comma
    for (char c : d.directory) folder += c == '"' ? std::string("\"\"") : std::string(1, c);
    double sum = 0.0;
    int finite = 0;
    for (const FrameRecord& r : d.frames) {
      if (!std::isfinite(r.altitude_m)) continue;
      sum += r.altitude_m;
      ++finite;
    }
    f << first_number + static_cast<int>(ds) << ",\"" << folder << "\"," << d.frames.size() << ","
      << (d.frames.empty() ? 0.0 : d.frames.front().stamp_s) << ","
      << (d.frames.empty() ? 0.0 : d.frames.back().stamp_s) << "," << (finite ? sum / finite : std::nan("")) << "\n";
  }
  commit(inputs.get(), "inputs.csv");
  if (config_yaml.empty()) return;
  const std::unique_ptr<AtomicFile> config = atomic("config.yaml");
  config->stream() << "# The effective configuration of this run (offline_slam --config reads it back).\n"
                   << config_yaml;
  commit(config.get(), "config.yaml");
}

}  // namespace core
}  // namespace uw_multislam
