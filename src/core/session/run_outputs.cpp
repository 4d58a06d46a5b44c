#include "uw_multislam/core/session/run_outputs.h"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iomanip>

#include "uw_multislam/core/frontend/dataset.h"

namespace uw_multislam {
namespace core {

void writeRunOutputs(const std::string& out_dir, const SessionManager& manager, const std::map<int, int>& csv_of,
                     int first_free_label, const StageTimes& times) {
  namespace fs = std::filesystem;
  auto csv = [&](int id) {
    const auto it = csv_of.find(id);
    return it == csv_of.end() ? id : it->second;
  };
  std::ofstream odo(fs::path(out_dir) / "odometry.csv"), traj(fs::path(out_dir) / "trajectory.csv");
  std::ofstream loops(fs::path(out_dir) / "loops.csv"), loop_poses(fs::path(out_dir) / "loop_poses.csv");
  std::ofstream links(fs::path(out_dir) / "links.csv"), timing(fs::path(out_dir) / "timing.csv");
  std::ofstream motions(fs::path(out_dir) / "motions.csv");
  motions << "session,index,source\n";
  odo << "session,index,x_m,y_m,yaw_rad\n" << std::fixed;
  traj << "session,index,map,x_m,y_m,yaw_rad\n" << std::fixed;
  loops << "session_a,index_a,session_b,index_b,kind,inliers\n";
  // The loops the back-end refused (inconsistent at a join, or gated inside a map): not in
  // loops.csv, whose contract is the accepted loops; the same columns in a file of their own.
  std::ofstream refused(fs::path(out_dir) / "loops_refused.csv");
  refused << "session_a,index_a,session_b,index_b,kind,inliers\n";
  loop_poses << "session_a,index_a,session_b,index_b,x_m,y_m,yaw_rad,cov_xx,cov_xy,cov_xyaw,cov_yy,cov_yyaw,cov_yawyaw\n"
             << std::fixed << std::setprecision(6);
  links << "map,previous_session,current_session,loops,x_m,y_m,yaw_rad,previous_piece,current_piece\n" << std::fixed
        << std::setprecision(6);
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
  std::ofstream pieces(fs::path(out_dir) / "pieces.csv");
  pieces << "session,piece,store_session,first_index,last_index,keyframes,map\n";
  for (int id : manager.sessionIds()) {
    const std::vector<int>& frames = manager.frames(id);
    pieces << csv(id) << "," << piece.at(id) << "," << id << "," << (frames.empty() ? -1 : frames.front()) << ","
           << (frames.empty() ? -1 : frames.back()) << "," << frames.size() << "," << label.at(manager.mapOf(id)) << "\n";
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
  for (std::size_t i = 0; i < manager.loops().size(); ++i) {
    const Loop& l = manager.loops()[i];
    (manager.loopRefused(i) ? refused : loops) << csv(l.session_a) << "," << l.frame_a << "," << csv(l.session_b)
                                                << "," << l.frame_b << "," << loopKindName(l.kind) << "," << l.inliers
                                                << "\n";
    loop_poses << csv(l.session_a) << "," << l.frame_a << "," << csv(l.session_b) << "," << l.frame_b << ","
               << l.z.mean.x() << "," << l.z.mean.y() << "," << l.z.mean.yaw() << std::scientific << std::setprecision(9);
    const Eigen::Matrix3d& c = l.z.covariance;
    loop_poses << "," << c(0, 0) << "," << c(0, 1) << "," << c(0, 2) << "," << c(1, 1) << "," << c(1, 2) << "," << c(2, 2)
               << "\n" << std::fixed << std::setprecision(6);
  }
  for (const SessionLink& l : manager.links())
    links << label.at(l.map) << "," << csv(l.previous) << "," << csv(l.current) << "," << l.loops << ","
          << l.estimate.x() << "," << l.estimate.y() << "," << l.estimate.yaw() << "," << piece.at(l.previous) << ","
          << piece.at(l.current) << "\n";
  timing << "stage,calls,total_ms,mean_ms,max_ms\n" << std::fixed << std::setprecision(3);
  for (const auto& s : times.stats())
    timing << s.stage << "," << s.calls << "," << s.total_ms << "," << s.meanMs() << "," << s.max_ms << "\n";
  if (!odo || !traj || !loops || !loop_poses || !links || !timing || !pieces || !motions)
    throw DatasetError(out_dir + ": cannot write the output files");
}

void writeRunInputs(const std::string& out_dir, const std::vector<Dataset>& datasets, int first_number,
                    const std::string& config_yaml) {
  namespace fs = std::filesystem;
  std::error_code ec;
  fs::create_directories(out_dir, ec);
  std::ofstream f(fs::path(out_dir) / "inputs.csv");
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
      << (d.frames.empty() ? 0.0 : d.frames.front().stamp_s) << "," << (d.frames.empty() ? 0.0 : d.frames.back().stamp_s)
      << "," << (finite ? sum / finite : std::nan("")) << "\n";
  }
  if (!f) throw DatasetError(out_dir + ": cannot write inputs.csv");
  if (config_yaml.empty()) return;
  std::ofstream c(fs::path(out_dir) / "config.yaml");
  c << "# The effective configuration of this run (offline_slam --config reads it back).\n" << config_yaml;
  if (!c) throw DatasetError(out_dir + ": cannot write config.yaml");
}

}  // namespace core
}  // namespace uw_multislam
