#include "uw_multislam/core/export/run_export.h"

#include <algorithm>
#include <array>
#include <climits>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <set>

#include "uw_multislam/core/geometry/vehicle_frame.h"

namespace uw_multislam {
namespace core {

namespace {

// One CSV file of the run, read by column name (the run_outputs.md columns; extra columns are
// ignored, so later additions to a file do not break the export).
struct Table {
  std::string path;
  std::vector<std::string> header;
  std::vector<std::vector<std::string>> rows;
  std::vector<int> lines;  // file line of each row

  int column(const std::string& name) const {
    const auto it = std::find(header.begin(), header.end(), name);
    if (it == header.end()) throw ExportError(path + ": no column '" + name + "'");
    return static_cast<int>(it - header.begin());
  }
  const std::string& cell(std::size_t r, const std::string& name) const {
    const std::size_t c = static_cast<std::size_t>(column(name));
    if (c >= rows[r].size())
      throw ExportError(path + ":" + std::to_string(lines[r]) + ": no value in column '" + name + "'");
    return rows[r][c];
  }
  double number(std::size_t r, const std::string& name) const {
    const std::string& s = cell(r, name);
    char* end = nullptr;
    const double v = std::strtod(s.c_str(), &end);
    if (s.empty() || *end != '\0' || !std::isfinite(v))
      throw ExportError(path + ":" + std::to_string(lines[r]) + ": bad number in " + name + ": '" + s + "'");
    return v;
  }
  int integer(std::size_t r, const std::string& name) const {
    const double v = number(r, name);
    if (v != std::floor(v) || std::abs(v) > INT_MAX)
      throw ExportError(path + ":" + std::to_string(lines[r]) + ": " + name + " is not an integer: '" + cell(r, name) +
                        "'");
    return static_cast<int>(v);
  }
};

std::vector<std::string> splitCells(const std::string& line) {
  std::vector<std::string> out(1);
  bool quoted = false;
  for (char c : line) {
    if (c == '"') {
      quoted = !quoted;
    } else if (c == ',' && !quoted) {
      out.emplace_back();
    } else if (c != '\r') {
      out.back() += c;
    }
  }
  return out;
}

std::optional<Table> readTable(const std::string& path, bool required, const std::vector<std::string>& columns) {
  std::ifstream in(path);
  if (!in) {
    if (required) throw ExportError(path + ": cannot open (not an offline_slam output folder?)");
    return std::nullopt;
  }
  Table t;
  t.path = path;
  std::string line;
  if (!std::getline(in, line)) throw ExportError(path + ": empty file (no header)");
  t.header = splitCells(line);
  for (const std::string& c : columns) t.column(c);  // every contract column present
  int n = 1;
  while (std::getline(in, line)) {
    ++n;
    if (line.empty() || line == "\r") continue;
    t.rows.push_back(splitCells(line));
    t.lines.push_back(n);
    if (t.rows.back().size() < t.header.size())
      throw ExportError(path + ":" + std::to_string(n) + ": expected " + std::to_string(t.header.size()) +
                        " columns, found " + std::to_string(t.rows.back().size()));
  }
  return t;
}

// A piece of a folder: one session of the engine, one store session (pieces.csv).
struct Unit {
  int session = 0, piece = 0;
  std::int64_t store = 0;
  int first = INT_MIN, last = INT_MAX;
  std::vector<std::size_t> rows;  // trajectory.csv rows, by index
  int map = 0;                    // trajectory.csv's map column
};

}  // namespace

RunExport loadRunExport(const std::string& run_dir, std::vector<std::string> dirs) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (!fs::is_directory(run_dir, ec)) throw ExportError(run_dir + ": not a directory (an offline_slam output folder)");
  const auto file = [&](const char* name) { return (fs::path(run_dir) / name).string(); };
  const Table traj = *readTable(file("trajectory.csv"), true, {"session", "index", "map", "x_m", "y_m", "yaw_rad"});
  const Table odo = *readTable(file("odometry.csv"), true, {"session", "index", "x_m", "y_m", "yaw_rad"});
  const auto inputs =
      readTable(file("inputs.csv"), false, {"session", "folder", "frames", "first_stamp_s", "last_stamp_s"});
  const auto pieces =
      readTable(file("pieces.csv"), false, {"session", "piece", "store_session", "first_index", "last_index"});
  const auto links =
      readTable(file("links.csv"), false, {"map", "previous_session", "current_session", "x_m", "y_m", "yaw_rad"});
  const auto loops = readTable(file("loops.csv"), false, {"session_a", "index_a", "session_b", "index_b"});
  const auto loop_poses = readTable(file("loop_poses.csv"), false,
                                    {"session_a", "index_a", "session_b", "index_b", "x_m", "y_m", "yaw_rad", "cov_xx",
                                     "cov_xy", "cov_xyaw", "cov_yy", "cov_yyaw", "cov_yawyaw"});
  RunExport out;
  if (dirs.empty()) {
    if (!inputs)
      throw ExportError(file("inputs.csv") + ": missing, so the run names no dataset folder: give them with --session");
    for (std::size_t r = 0; r < inputs->rows.size(); ++r) {
      if (inputs->integer(r, "session") != static_cast<int>(r))
        throw ExportError(inputs->path + ": sessions not numbered 0, 1, ... in order: give the folders with --session");
      dirs.push_back(inputs->cell(r, "folder"));
    }
  }
  std::vector<Dataset> datasets;
  std::vector<std::map<int, const FrameRecord*>> frame_of(dirs.size());
  for (const std::string& d : dirs) datasets.push_back(loadDataset(d));
  for (std::size_t d = 0; d < datasets.size(); ++d)
    for (const FrameRecord& f : datasets[d].frames) frame_of[d][f.index] = &f;
  if (inputs) {  // the folders the run was made from, as evaluate.py checks them
    for (std::size_t r = 0; r < inputs->rows.size(); ++r) {
      const int n = inputs->integer(r, "session");
      if (n < 0 || n >= static_cast<int>(datasets.size()))
        throw ExportError("the run was made from " + inputs->cell(r, "folder") + " as session " + std::to_string(n) +
                          " (inputs.csv) but " + std::to_string(datasets.size()) + " folder(s) were given");
      const Dataset& d = datasets[static_cast<std::size_t>(n)];
      const bool same = static_cast<int>(d.frames.size()) == inputs->integer(r, "frames") && !d.frames.empty() &&
                        std::abs(d.frames.front().stamp_s - inputs->number(r, "first_stamp_s")) <= 1e-3 &&
                        std::abs(d.frames.back().stamp_s - inputs->number(r, "last_stamp_s")) <= 1e-3;
      if (!same)
        throw ExportError("session " + std::to_string(n) + " of the run was made from " + inputs->cell(r, "folder") +
                          " (inputs.csv: " + inputs->cell(r, "frames") + " frames), but " + d.directory + " has " +
                          std::to_string(d.frames.size()) + " frames or other stamps: not the same folder");
    }
  }

  // The pieces (store sessions) and their keyframes.
  std::vector<Unit> units;
  if (pieces) {
    for (std::size_t r = 0; r < pieces->rows.size(); ++r) {
      Unit u;
      u.session = pieces->integer(r, "session");
      u.piece = pieces->integer(r, "piece");
      u.store = pieces->integer(r, "store_session");
      u.first = pieces->integer(r, "first_index");
      u.last = pieces->integer(r, "last_index");
      units.push_back(u);
    }
  } else {
    out.notes.push_back("no pieces.csv: one session per folder, named by its folder number");
    std::set<int> sessions;
    for (std::size_t r = 0; r < traj.rows.size(); ++r) sessions.insert(traj.integer(r, "session"));
    for (int s : sessions) {
      Unit u;
      u.session = s;
      u.store = s;
      units.push_back(u);
    }
  }
  const auto unitOf = [&](int session, int index) -> Unit* {
    for (Unit& u : units)
      if (u.session == session && u.first <= index && index <= u.last) return &u;
    return nullptr;
  };
  for (std::size_t r = 0; r < traj.rows.size(); ++r) {
    const int s = traj.integer(r, "session"), i = traj.integer(r, "index");
    if (s < 0 || s >= static_cast<int>(datasets.size()))
      throw ExportError(traj.path + ":" + std::to_string(traj.lines[r]) + ": session " + std::to_string(s) + " but " +
                        std::to_string(datasets.size()) + " dataset folder(s) given: one per session of the run");
    if (!frame_of[static_cast<std::size_t>(s)].count(i))
      throw ExportError(traj.path + ":" + std::to_string(traj.lines[r]) + ": frame " + std::to_string(i) +
                        " is not in " + datasets[static_cast<std::size_t>(s)].directory + "/frames.csv");
    Unit* u = unitOf(s, i);
    if (!u)
      throw ExportError(traj.path + ":" + std::to_string(traj.lines[r]) + ": keyframe " + std::to_string(s) + "/" +
                        std::to_string(i) + " is in no piece of pieces.csv");
    u->rows.push_back(r);
    u->map = traj.integer(r, "map");
  }
  units.erase(std::remove_if(units.begin(), units.end(), [](const Unit& u) { return u.rows.empty(); }), units.end());
  for (Unit& u : units)
    std::sort(u.rows.begin(), u.rows.end(),
              [&](std::size_t a, std::size_t b) { return traj.integer(a, "index") < traj.integer(b, "index"); });
  std::map<std::pair<int, int>, Pose2> odometry;
  for (std::size_t r = 0; r < odo.rows.size(); ++r)
    odometry[{odo.integer(r, "session"), odo.integer(r, "index")}] =
        Pose2(odo.number(r, "x_m"), odo.number(r, "y_m"), odo.number(r, "yaw_rad"));
  std::map<std::array<int, 4>, UncertainPose2> measured;
  if (loop_poses) {
    for (std::size_t r = 0; r < loop_poses->rows.size(); ++r) {
      const Table& t = *loop_poses;
      Eigen::Matrix3d c;
      c << t.number(r, "cov_xx"), t.number(r, "cov_xy"), t.number(r, "cov_xyaw"), t.number(r, "cov_xy"),
          t.number(r, "cov_yy"), t.number(r, "cov_yyaw"), t.number(r, "cov_xyaw"), t.number(r, "cov_yyaw"),
          t.number(r, "cov_yawyaw");
      measured[{t.integer(r, "session_a"), t.integer(r, "index_a"), t.integer(r, "session_b"),
                t.integer(r, "index_b")}] =
          UncertainPose2(Pose2(t.number(r, "x_m"), t.number(r, "y_m"), t.number(r, "yaw_rad")), c);
    }
  }

  // Maps: their pieces in chain order (links.csv: previous -> current), each piece's keyframes.
  std::map<int, std::vector<Unit*>> by_map;
  for (Unit& u : units) by_map[u.map].push_back(&u);
  const auto pieceColumn = [&](const Table& t, std::size_t r, const char* column) {
    return std::find(t.header.begin(), t.header.end(), column) != t.header.end() ? t.integer(r, column) : 0;
  };
  int loops_without_pose = 0;
  for (auto& [map_id, members] : by_map) {
    std::map<const Unit*, std::pair<const Unit*, std::size_t>> next;  // piece -> (next piece, links.csv row)
    std::set<const Unit*> has_previous;
    if (links) {
      for (std::size_t r = 0; r < links->rows.size(); ++r) {
        const auto find = [&](int session, int piece) -> const Unit* {
          for (const Unit* u : members)
            if (u->session == session && u->piece == piece) return u;
          return nullptr;
        };
        const Unit* a = find(links->integer(r, "previous_session"), pieceColumn(*links, r, "previous_piece"));
        const Unit* b = find(links->integer(r, "current_session"), pieceColumn(*links, r, "current_piece"));
        if (!a || !b) continue;
        next[a] = {b, r};
        has_previous.insert(b);
      }
    }
    std::vector<const Unit*> chain;
    std::vector<std::size_t> link_row;  // links.csv row reaching chain[c], c > 0
    for (const Unit* u : members) {
      if (has_previous.count(u)) continue;
      for (const Unit* at = u; at && chain.size() <= members.size();) {
        chain.push_back(at);
        const auto it = next.find(at);
        if (it == next.end()) break;
        link_row.push_back(it->second.second);
        at = it->second.first;
      }
      break;
    }
    if (chain.size() != members.size())
      throw ExportError(run_dir + ": links.csv does not chain the " + std::to_string(members.size()) +
                        " sessions of map " + std::to_string(map_id) + " into one line");
    ExportTrack track;
    track.map = chain.front()->store;
    track.label = "map_" + std::to_string(track.map);
    std::map<std::pair<int, int>, int> index_of;  // (folder session, frame index) -> track index
    for (std::size_t c = 0; c < chain.size(); ++c) {
      const Unit& u = *chain[c];
      const Dataset& d = datasets[static_cast<std::size_t>(u.session)];
      track.sessions.push_back(u.store);
      track.name += (c ? "+" : "") + dirs[static_cast<std::size_t>(u.session)];
      if (c > 0) {
        const std::size_t r = link_row[c - 1];
        ExportEdge e;
        e.from = static_cast<int>(track.keyframes.size()) - 1;
        e.to = e.from + 1;
        e.z = zUp(UncertainPose2::exact(
            Pose2(links->number(r, "x_m"), links->number(r, "y_m"), links->number(r, "yaw_rad"))));
        e.kind = ExportEdge::Kind::kLink;
        e.information_known = false;
        track.edges.push_back(e);
      }
      int previous_index = -1;
      for (std::size_t k = 0; k < u.rows.size(); ++k) {
        const std::size_t r = u.rows[k];
        const int index = traj.integer(r, "index");
        const FrameRecord& f = *frame_of[static_cast<std::size_t>(u.session)].at(index);
        if (k > 0) {
          const auto a = odometry.find({u.session, previous_index}), b = odometry.find({u.session, index});
          if (a != odometry.end() && b != odometry.end()) {
            ExportEdge e;
            e.from = static_cast<int>(track.keyframes.size()) - 1;
            e.to = e.from + 1;
            e.z = zUp(UncertainPose2::exact(between(a->second, b->second)));
            e.kind = ExportEdge::Kind::kOdometry;
            e.information_known = false;
            track.edges.push_back(e);
          }
        }
        ExportKeyframe e;
        e.session = u.store;
        e.keyframe = static_cast<int>(k);
        e.frame_index = index;
        e.stamp_s = f.stamp_s;
        e.altitude_m = f.altitude_m;
        e.image_size = cv::Size(d.camera.width, d.camera.height);
        e.pose =
            zUp(UncertainPose2::exact(Pose2(traj.number(r, "x_m"), traj.number(r, "y_m"), traj.number(r, "yaw_rad"))));
        e.covariance_known = false;
        index_of[{u.session, index}] = static_cast<int>(track.keyframes.size());
        track.keyframes.push_back(std::move(e));
        previous_index = index;
      }
    }
    if (loops) {
      for (std::size_t r = 0; r < loops->rows.size(); ++r) {
        const std::array<int, 4> key = {loops->integer(r, "session_a"), loops->integer(r, "index_a"),
                                        loops->integer(r, "session_b"), loops->integer(r, "index_b")};
        const auto a = index_of.find({key[0], key[1]}), b = index_of.find({key[2], key[3]});
        if (a == index_of.end() || b == index_of.end()) continue;  // not both in this map
        const auto z = measured.find(key);
        if (z == measured.end()) {
          ++loops_without_pose;
          continue;
        }
        ExportEdge e;
        e.from = a->second;
        e.to = b->second;
        e.z = zUp(z->second);
        e.kind = ExportEdge::Kind::kLoop;
        track.edges.push_back(e);
      }
    }
    out.survey.maps.push_back(std::move(track));
  }
  std::sort(units.begin(), units.end(), [](const Unit& a, const Unit& b) { return a.store < b.store; });
  for (const Unit& u : units) {
    for (const ExportTrack& m : out.survey.maps) {
      ExportTrack t = sessionSlice(m, u.store, dirs[static_cast<std::size_t>(u.session)]);
      if (!t.keyframes.empty()) out.survey.sessions.push_back(std::move(t));
    }
    out.survey.cameras.emplace_back(u.store, datasets[static_cast<std::size_t>(u.session)].camera);
  }
  out.survey.store_path = run_dir;
  // The exported files take the permissions of the run's own (0600 when it was run on a 0600 store).
  out.survey.modes = outputModesOf((std::filesystem::path(run_dir) / "trajectory.csv").string());
  out.dataset_dirs = dirs;
  out.notes.push_back(
      "from an offline_slam output folder: no pose covariances (the CSV's covariance columns are nan), no "
      "information for the g2o odometry and link edges (written as comments)");
  if (!loop_poses) out.notes.push_back("no loop_poses.csv: no loop edges in the g2o files");
  if (loops_without_pose > 0)
    out.notes.push_back(std::to_string(loops_without_pose) +
                        " accepted loops have no measured pose in loop_poses.csv: not in the g2o files");
  return out;
}

}  // namespace core
}  // namespace uw_multislam
