#include "uw_multislam/ros/backend_conversions.h"

#include "uw_multislam/ros/conversions.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>

namespace uw_multislam {
namespace ros_conversions {

uw_multislam::Status statusMsg(std::uint8_t code, const std::string& message) {
  uw_multislam::Status s;
  s.code = code;
  s.message = message;
  return s;
}

uw_multislam::Status toStatusMsg(const core::Status& s) {
  // core::StatusCode takes its values from Status.msg (test_conversions checks each one).
  return statusMsg(static_cast<std::uint8_t>(s.code), s.ok() ? std::string() : s.message);
}

bool fromAddLinkRequest(const uw_multislam::AddLink::Request& r, core::Loop* out, std::string* why) {
  uw_multislam::Loop m;
  m.kind = r.session_a == r.session_b ? uw_multislam::Loop::LOCAL : uw_multislam::Loop::GLOBAL;
  m.session_a = r.session_a;
  m.keyframe_a = r.keyframe_a;
  m.session_b = r.session_b;
  m.keyframe_b = r.keyframe_b;
  m.pose = r.pose;
  m.covariance = r.covariance;
  m.inliers = r.inliers;
  return fromMsg(m, out, why);
}

core::KeyframeInput toKeyframeInput(const KeyframeData& k, double stamp_s) {
  core::KeyframeInput in;
  in.session = k.session;
  in.keyframe = k.keyframe;
  in.frame_index = k.frame_index;
  in.stamp_s = stamp_s;
  in.altitude_m = k.altitude_m;
  in.camera = k.camera;
  in.features = k.features;
  in.motion = k.motion;
  in.odometry_pose = k.odometry_pose;
  in.hash = k.hash;            // computed once, by the odometry (empty from older senders: the manager hashes)
  in.thumbnail = k.thumbnail;  // kept by the store (empty: none)
  in.nav_placement = k.nav_placement;
  return in;
}

uw_multislam::DetectLoops::Response toDetectLoopsResponse(const core::Status& st, const core::StoredLoopSearch& f,
                                                          int joins) {
  uw_multislam::DetectLoops::Response res;
  res.status = toStatusMsg(st);
  res.queries = f.queries;
  res.candidates = f.candidates;
  res.found = f.found;
  res.already_held = f.duplicates;
  res.accepted = f.accepted;
  res.refused = f.refused;
  res.joins = joins;
  return res;
}

std::string detectLoopsLine(const core::Status& st, const core::StoredLoopSearch& f, int joins) {
  char counts[256];
  std::snprintf(counts, sizeof(counts),
                "; %d keyframes queried, %d candidates, %d loops (%d held already), %d accepted, %d refused, %d joins",
                f.queries, f.candidates, f.found, f.duplicates, f.accepted, f.refused, joins);
  return (st.ok() ? std::string("OK") : st.message) + counts;
}

KeyframeData reloadedKeyframe(const core::ReloadedSession& session, const core::StoredKeyframe& k) {
  KeyframeData d;
  d.session = session.id;
  d.keyframe = k.keyframe;
  d.frame_index = k.frame_index;
  d.altitude_m = k.altitude_m > 0 ? k.altitude_m : 1.0;
  d.camera = session.camera;
  d.features = k.features();
  if (!k.descriptors.empty()) d.features.descriptors = core::extractorDescriptors(k.descriptors);  // as the extractor's
  d.hash = k.hash;  // as stored (the store refuses other hash settings): paged keyframes are found by it
  d.motion = core::UncertainPose2(core::Pose2(), Eigen::Matrix3d::Identity() * 1e-6);
  d.quality = k.keyframe == 0 ? KeyframeQuality::kFirst : KeyframeQuality::kMatched;
  return d;
}

uw_multislam::Keyframe reloadedKeyframeMsg(const core::ReloadedSession& session, const core::StoredKeyframe& k,
                                           const std::string& frame_id) {
  std_msgs::Header h;
  h.stamp = ros::Time(std::max(0.0, k.stamp_s));
  h.frame_id = frame_id;
  return toKeyframeMsg(reloadedKeyframe(session, k), h);
}

uw_multislam::SessionState toSessionStateMsg(const core::SessionSummary& s) {
  uw_multislam::SessionState st;
  st.session = s.id;
  st.name = s.name;
  st.state = s.state == core::SessionState::kActive     ? uw_multislam::SessionState::ACTIVE
             : s.state == core::SessionState::kUnloaded ? uw_multislam::SessionState::UNLOADED
                                                        : uw_multislam::SessionState::FINISHED;
  st.map = s.map;
  st.num_keyframes = s.keyframes;
  st.num_loops = s.loops;
  st.first_stamp = ros::Time(std::max(0.0, s.first_stamp_s));
  st.last_stamp = ros::Time(std::max(0.0, s.last_stamp_s));
  st.relocalised_map = -1;
  st.vehicle = s.vehicle;
  return st;
}

uw_multislam::HistoryEntry toHistoryEntryMsg(const core::HistoryEntry& e) {
  uw_multislam::HistoryEntry m;
  m.id = e.id;
  m.time_utc = e.time_utc;
  m.kind = e.kind;
  m.cause = e.cause;
  m.sessions = e.sessions;
  m.loops = e.loops;
  m.message = e.message;
  return m;
}

uw_multislam::History::Response toHistoryResponse(const std::vector<core::HistoryEntry>& h, int last) {
  uw_multislam::History::Response res;
  if (last < 0) {
    res.status = toStatusMsg({core::StatusCode::kInvalidArgument, "history: last must be >= 0 (0: all entries)"});
    return res;
  }
  const std::size_t from = last == 0 ? 0 : h.size() - std::min(h.size(), static_cast<std::size_t>(last));
  for (std::size_t i = from; i < h.size(); ++i) res.entries.push_back(toHistoryEntryMsg(h[i]));
  res.status = toStatusMsg(core::Status::Ok());
  return res;
}

core::Status setMode(core::SessionManager* m, const std::string& mode) {
  if (mode == "mapping") return m->setLocalisation(false);
  if (mode == "localisation" || mode == "localization") return m->setLocalisation(true);
  return {core::StatusCode::kInvalidArgument,
          "set_mode: mode '" + mode.substr(0, 64) + "' is neither 'mapping' nor 'localisation' (or 'localization')"};
}

std::vector<core::Pose2> vehiclePoses(const core::SessionQueries& manager, int id, const core::CameraMount& mount) {
  std::vector<core::Pose2> p = manager.poses(id);
  for (core::Pose2& x : p) x = core::vehicleFromCamera(x, mount);
  return p;
}

std::map<int, double> mapOffsets(const core::SessionQueries& manager, const core::CameraMount& mount) {
  std::map<int, std::pair<double, double>> extent;  // map -> min x, max x
  for (int id : manager.sessionIds()) {
    auto& e = extent.emplace(manager.mapOf(id), std::make_pair(1e300, -1e300)).first->second;
    for (const core::Pose2& p : vehiclePoses(manager, id, mount))
      e = {std::min(e.first, p.x()), std::max(e.second, p.x())};
  }
  std::map<int, double> offsets;
  if (extent.empty()) return offsets;
  const int anchor = manager.activeSession() >= 0 ? manager.mapOf(manager.activeSession()) : extent.begin()->first;
  offsets[anchor] = 0.0;
  double right = extent[anchor].second;  // the rightmost x drawn so far
  for (const auto& [map, e] : extent) {
    if (map == anchor) continue;
    offsets[map] = right + 1.0 - e.first;
    right = right + 1.0 + (e.second - e.first);
  }
  return offsets;
}

std::vector<Segment> loopSegments(const core::SessionQueries& manager, const core::CameraMount& mount,
                                  const std::map<int, double>& offsets) {
  std::map<int, std::vector<core::Pose2>> poses;  // each session's poses once, shifted with its map
  auto posesOf = [&](int id) -> const std::vector<core::Pose2>& {
    auto it = poses.find(id);
    if (it == poses.end()) {
      const auto o = offsets.find(manager.mapOf(id));
      std::vector<core::Pose2> p = vehiclePoses(manager, id, mount);
      if (o != offsets.end())
        for (core::Pose2& x : p) x = core::Pose2(x.x() + o->second, x.y(), x.yaw());
      it = poses.emplace(id, std::move(p)).first;
    }
    return it->second;
  };
  std::vector<Segment> segments;
  for (std::size_t i = 0; i < manager.loops().size(); ++i) {
    const core::Loop& l = manager.loops()[i];
    if (manager.mapOf(l.session_a) != manager.mapOf(l.session_b)) continue;
    const Segment::Kind kind = manager.loopRefused(i)               ? Segment::Kind::kRefused
                               : l.kind == core::Loop::Kind::kLocal ? Segment::Kind::kLocal
                                                                    : Segment::Kind::kGlobal;
    segments.push_back({posesOf(l.session_a)[l.keyframe_a], posesOf(l.session_b)[l.keyframe_b], kind});
  }
  for (const core::SessionLink& link : manager.links())
    segments.push_back({posesOf(link.previous).back(), posesOf(link.current).front(), Segment::Kind::kJoin});
  return segments;
}

std_msgs::ColorRGBA sessionColour(int id) {
  // HSV (h, 0.75, 0.95) to RGB, h = frac(id * golden ratio): neighbours get far-apart hues.
  const double h = std::fmod(0.12 + 0.6180339887 * id, 1.0) * 6.0, s = 0.75, v = 0.95;
  const int i = static_cast<int>(h);
  const double f = h - i, p = v * (1 - s), q = v * (1 - s * f), t = v * (1 - s * (1 - f));
  const double rgb[6][3] = {{v, t, p}, {q, v, p}, {p, v, t}, {p, q, v}, {t, p, v}, {v, p, q}};
  std_msgs::ColorRGBA c;
  c.r = static_cast<float>(rgb[i % 6][0]);
  c.g = static_cast<float>(rgb[i % 6][1]);
  c.b = static_cast<float>(rgb[i % 6][2]);
  c.a = 1.0f;
  return c;
}

visualization_msgs::MarkerArray toTrajectoryMarkersMsg(const core::SessionQueries& manager,
                                                       const core::CameraMount& mount,
                                                       const std::map<int, double>& offsets,
                                                       const std::string& frame_id, const ros::Time& stamp) {
  visualization_msgs::MarkerArray out;
  auto marker = [&](const char* ns, int id, int type) {
    visualization_msgs::Marker m;
    m.header.frame_id = frame_id;
    m.header.stamp = stamp;
    m.ns = ns;
    m.id = id;
    m.type = type;
    m.action = visualization_msgs::Marker::ADD;
    m.pose.orientation.w = 1.0;
    return m;
  };
  visualization_msgs::Marker clear = marker("", 0, visualization_msgs::Marker::LINE_STRIP);
  clear.action = visualization_msgs::Marker::DELETEALL;
  out.markers.push_back(clear);
  std::map<int, std::pair<double, double>> top_left;  // shifted maps: where to put their label
  for (int id : manager.sessionIds()) {
    const int map = manager.mapOf(id);
    const auto o = offsets.find(map);
    const double dx = o == offsets.end() ? 0.0 : o->second;
    visualization_msgs::Marker line = marker("trajectories", id, visualization_msgs::Marker::LINE_STRIP);
    line.scale.x = id == manager.activeSession() ? 0.06 : 0.03;
    line.color = sessionColour(id);
    for (const core::Pose2& p : vehiclePoses(manager, id, mount)) {
      geometry_msgs::Point q;
      q.x = p.x() + dx;
      q.y = p.y();
      line.points.push_back(q);
      if (dx != 0.0) {
        auto& tl = top_left.emplace(map, std::make_pair(q.x, q.y)).first->second;
        tl = {std::min(tl.first, q.x), std::min(tl.second, q.y)};
      }
    }
    if (line.points.size() == 1) line.points.push_back(line.points.front());  // a LINE_STRIP needs two
    visualization_msgs::Marker label = marker("labels", id, visualization_msgs::Marker::TEXT_VIEW_FACING);
    label.pose.position = line.points.back();
    label.scale.z = 0.5;
    label.color = line.color;
    label.text = "session " + std::to_string(id);
    out.markers.push_back(line);
    out.markers.push_back(label);
  }
  for (const auto& [map, tl] : top_left) {
    visualization_msgs::Marker label = marker("maps", map, visualization_msgs::Marker::TEXT_VIEW_FACING);
    label.pose.position.x = tl.first;
    label.pose.position.y = tl.second - 0.8;
    label.scale.z = 0.6;
    label.color.r = label.color.g = label.color.b = label.color.a = 1.0f;
    label.text = "map " + std::to_string(map) + " (not joined; drawn shifted)";
    out.markers.push_back(label);
  }
  return out;
}

uw_multislam::SessionTrajectory toSessionTrajectoryMsg(int session, int map, const std::vector<core::Pose2>& poses,
                                                       const ros::Time& stamp, const std::string& frame_id) {
  uw_multislam::SessionTrajectory t;
  t.header.stamp = stamp;
  t.header.frame_id = frame_id;
  t.session = session;
  t.map = map;
  for (const core::Pose2& p : poses) t.poses.push_back(toPose2DMsg(p));
  return t;
}

nav_msgs::Path toPathMsg(const std::vector<core::Pose2>& poses, const std::vector<ros::Time>& stamps,
                         const std::string& frame_id, const ros::Time& fallback) {
  nav_msgs::Path path;
  path.header.frame_id = frame_id;
  path.header.stamp = stamps.empty() ? fallback : stamps.back();
  for (std::size_t k = 0; k < poses.size(); ++k) {
    geometry_msgs::PoseStamped p;
    p.header.frame_id = frame_id;
    p.header.stamp = k < stamps.size() ? stamps[k] : path.header.stamp;
    p.pose = toPoseMsg(poses[k]);
    path.poses.push_back(p);
  }
  return path;
}

visualization_msgs::MarkerArray toMarkerArrayMsg(const std::vector<Segment>& segments, const std::string& frame_id,
                                                 const ros::Time& stamp) {
  visualization_msgs::MarkerArray out;
  visualization_msgs::Marker clear;
  clear.header.frame_id = frame_id;
  clear.header.stamp = stamp;
  clear.action = visualization_msgs::Marker::DELETEALL;
  out.markers.push_back(clear);
  struct Style {
    Segment::Kind kind;
    const char* ns;
    float r, g, b, width;
  };
  const Style styles[] = {{Segment::Kind::kLocal, "local_loops", 0.1f, 0.8f, 0.2f, 0.02f},
                          {Segment::Kind::kGlobal, "global_loops", 1.0f, 0.55f, 0.0f, 0.02f},
                          {Segment::Kind::kJoin, "joins", 0.9f, 0.1f, 0.1f, 0.05f},
                          // Loops the back-end refused (gated, or inconsistent at a join): thin, magenta.
                          {Segment::Kind::kRefused, "refused_loops", 0.85f, 0.1f, 0.85f, 0.01f}};
  int id = 0;
  for (const Style& st : styles) {
    visualization_msgs::Marker m;
    m.header.frame_id = frame_id;
    m.header.stamp = stamp;
    m.ns = st.ns;
    m.id = id++;
    m.type = visualization_msgs::Marker::LINE_LIST;
    m.action = visualization_msgs::Marker::ADD;
    m.pose.orientation.w = 1.0;
    m.scale.x = st.width;
    m.color.r = st.r;
    m.color.g = st.g;
    m.color.b = st.b;
    m.color.a = 1.0f;
    for (const Segment& s : segments) {
      if (s.kind != st.kind) continue;
      for (const core::Pose2* p : {&s.a, &s.b}) {
        geometry_msgs::Point q;
        q.x = p->x();
        q.y = p->y();
        m.points.push_back(q);
      }
    }
    if (!m.points.empty()) out.markers.push_back(m);
  }
  return out;
}

std::vector<core::Pose2> toPublished(const core::MapFrame& out, const std::vector<core::Pose2>& in_core_map) {
  std::vector<core::Pose2> poses;
  poses.reserve(in_core_map.size());
  for (const core::Pose2& p : in_core_map) poses.push_back(out.toPublished(p));
  return poses;
}

visualization_msgs::MarkerArray toPublished(const core::MapFrame& out, visualization_msgs::MarkerArray markers) {
  if (out.isIdentity()) return markers;
  const Eigen::Quaterniond turn(Eigen::AngleAxisd(out.theta(), Eigen::Vector3d::UnitZ()));
  for (visualization_msgs::Marker& m : markers.markers) {
    if (m.action != visualization_msgs::Marker::ADD) continue;
    geometry_msgs::Pose& p = m.pose;
    const Eigen::Vector3d at = turn * Eigen::Vector3d(p.position.x, p.position.y, p.position.z);
    const Eigen::Quaterniond q =
        turn * Eigen::Quaterniond(p.orientation.w, p.orientation.x, p.orientation.y, p.orientation.z);
    p.position.x = at.x(), p.position.y = at.y(), p.position.z = at.z();
    p.orientation.w = q.w(), p.orientation.x = q.x(), p.orientation.y = q.y(), p.orientation.z = q.z();
  }
  return markers;
}

}  // namespace ros_conversions
}  // namespace uw_multislam
