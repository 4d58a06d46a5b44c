#include "uw_multislam/core/export/survey_export.h"

#include <GeographicLib/LocalCartesian.hpp>

#include <Eigen/LU>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <iomanip>
#include <map>
#include <sstream>

#include "uw_multislam/core/backend/backend.h"
#include "uw_multislam/core/geometry/vehicle_frame.h"
#include "uw_multislam/core/store/map_persistence.h"
#include "uw_multislam/core/store/session_store.h"

namespace uw_multislam {
namespace core {

namespace {

std::string sessionLabel(std::int64_t id) { return "session_" + std::to_string(id); }

}  // namespace

const char* edgeKindName(ExportEdge::Kind kind) {
  switch (kind) {
    case ExportEdge::Kind::kOdometry:
      return "odometry";
    case ExportEdge::Kind::kLink:
      return "link";
    case ExportEdge::Kind::kLoop:
      return "loop";
  }
  return "?";
}

const CameraIntrinsics* SurveyExport::findCamera(std::int64_t session) const {
  for (const auto& [id, c] : cameras)
    if (id == session) return &c;
  return nullptr;
}

const CameraIntrinsics& SurveyExport::camera(std::int64_t session) const {
  if (const CameraIntrinsics* c = findCamera(session)) return *c;
  throw ExportError(store_path + ": no camera for session " + std::to_string(session));
}

SurveyExport loadSurveyExport(const std::string& store_path) {
  const SessionStore store(store_path, StoreAccess::kReadOnly);
  // The back-end restored exactly as stored (restoreStore: nothing is optimised), so the poses
  // are the ones the back-end had when it saved the maps.
  MultiSessionBackend backend(BackendOptions{});
  const RestoredStore restored = restoreStore(store, &backend, nullptr, nullptr);
  // A store repaired on the way (damaged map motions or links, a map naming a session it does not
  // hold) would be exported as something it does not hold: refused, with what is wrong.
  if (!restored.notes.empty()) throw ExportError(restored.notes.front() + " (export refused: the store is damaged)");
  SurveyExport out;
  out.store_path = store_path;
  out.modes = outputModesOf(store_path);
  std::map<std::int64_t, StoredSession> stored_session;
  for (const StoredSession& s : store.sessions()) stored_session[s.id] = s;
  std::map<std::int64_t, int> backend_of;  // store session id -> back-end session id
  for (std::size_t b = 0; b < restored.session_ids.size(); ++b)
    backend_of[restored.session_ids[b]] = static_cast<int>(b);

  for (int map : backend.mapIds()) {
    const MapState state = backend.mapState(map);
    ExportTrack track;
    track.map = restored.session_ids.at(static_cast<std::size_t>(map));
    track.label = "map_" + std::to_string(track.map);
    // The map's keyframes in chain order; their covariance composed along the map's motions to
    // first order, as keyframeInMap does (one pass instead of one per keyframe).
    UncertainPose2 at = UncertainPose2::exact(Pose2());
    std::size_t motion = 0;
    std::map<std::pair<int, int>, int> index_of;  // (back-end session, keyframe) -> track index
    for (std::size_t c = 0; c < state.chain.size(); ++c) {
      const int s = state.chain[c];
      const std::int64_t sid = restored.session_ids.at(static_cast<std::size_t>(s));
      track.sessions.push_back(sid);
      track.name += (c ? "+" : "") + stored_session.at(sid).name;
      const std::vector<StoredKeyframe> kfs = store.keyframes(sid, false);
      const std::vector<std::vector<std::uint8_t>> thumbs = store.thumbnails(sid);
      const std::vector<UncertainPose2> odometry = store.odometry(sid);
      if (c > 0) {
        at = compose(at, state.motions.empty() ? state.links[c - 1].measured : state.motions.at(motion));
        ++motion;
        track.edges.push_back({static_cast<int>(track.keyframes.size()) - 1, static_cast<int>(track.keyframes.size()),
                               zUp(state.links[c - 1].measured), ExportEdge::Kind::kLink, true});
      }
      const std::vector<Pose2> means = backend.sessionPoses(s);
      for (std::size_t k = 0; k < kfs.size(); ++k) {
        if (k > 0) {
          at = compose(at, state.motions.empty() ? odometry.at(k - 1) : state.motions.at(motion));
          ++motion;
          track.edges.push_back({static_cast<int>(track.keyframes.size()) - 1, static_cast<int>(track.keyframes.size()),
                                 zUp(odometry.at(k - 1)), ExportEdge::Kind::kOdometry, true});
        }
        ExportKeyframe e;
        e.session = sid;
        e.keyframe = kfs[k].keyframe;
        e.frame_index = kfs[k].frame_index;
        e.stamp_s = kfs[k].stamp_s;
        e.altitude_m = kfs[k].altitude_m;
        e.image_size = kfs[k].image_size;
        e.thumbnail = thumbs.at(k);
        // The back-end's mean (the same compositions; kept so that the files match
        // trajectory.csv exactly) with the composed covariance.
        e.pose = zUp(UncertainPose2(means.at(k), at.covariance));
        index_of[{s, static_cast<int>(k)}] = static_cast<int>(track.keyframes.size());
        track.keyframes.push_back(std::move(e));
      }
    }
    for (const StoredLoop& l : restored.loops) {
      if (l.refused || l.summarised) continue;
      const auto a = index_of.find({backend_of.at(l.session_a), l.keyframe_a});
      const auto b = index_of.find({backend_of.at(l.session_b), l.keyframe_b});
      if (a == index_of.end() || b == index_of.end()) continue;  // not both in this map
      track.edges.push_back({a->second, b->second, zUp(l.z), ExportEdge::Kind::kLoop, true});
    }
    out.pending_loops += state.pending;
    out.maps.push_back(std::move(track));
  }
  // Sessions: their slice of their map's track, with the edges inside the slice.
  for (std::int64_t sid : restored.session_ids) {
    for (const ExportTrack& m : out.maps) {
      ExportTrack t = sessionSlice(m, sid, stored_session.at(sid).name);
      if (!t.keyframes.empty()) out.sessions.push_back(std::move(t));
    }
    out.cameras.emplace_back(sid, stored_session.at(sid).camera);
  }
  return out;
}

ExportTrack sessionSlice(const ExportTrack& m, std::int64_t sid, const std::string& name) {
  int first = -1, n = 0;
  for (std::size_t i = 0; i < m.keyframes.size(); ++i) {
    if (m.keyframes[i].session != sid) continue;
    if (first < 0) first = static_cast<int>(i);
    ++n;
  }
  ExportTrack t;
  t.label = sessionLabel(sid);
  t.name = name;
  t.map = m.map;
  t.sessions = {sid};
  if (first < 0) return t;
  t.keyframes.assign(m.keyframes.begin() + first, m.keyframes.begin() + first + n);
  for (const ExportEdge& e : m.edges)
    if (e.from >= first && e.from < first + n && e.to >= first && e.to < first + n)
      t.edges.push_back({e.from - first, e.to - first, e.z, e.kind, e.information_known});
  return t;
}

bool parseGeoOrigin(const std::string& text, GeoOrigin* out, std::string* why) {
  double v[3];
  const char* p = text.c_str();
  for (int i = 0; i < 3; ++i) {
    char* end = nullptr;
    errno = 0;
    v[i] = std::strtod(p, &end);
    if (end == p || errno != 0 || !std::isfinite(v[i])) {
      *why = "'" + text + "' is not LAT,LON,HEADING_DEG (three numbers separated by commas)";
      return false;
    }
    p = end;
    if (i < 2) {
      if (*p != ',') {
        *why = "'" + text + "' is not LAT,LON,HEADING_DEG (three numbers separated by commas)";
        return false;
      }
      ++p;
    }
  }
  if (*p != '\0') {
    *why = "'" + text + "' has more than LAT,LON,HEADING_DEG";
    return false;
  }
  if (std::abs(v[0]) > 90.0) {
    *why = "latitude " + std::to_string(v[0]) + " is outside [-90, 90]";
    return false;
  }
  if (std::abs(v[1]) > 180.0) {
    *why = "longitude " + std::to_string(v[1]) + " is outside [-180, 180]";
    return false;
  }
  if (std::abs(v[2]) > 360.0) {
    *why = "heading " + std::to_string(v[2]) + " is outside [-360, 360] degrees";
    return false;
  }
  *out = {v[0], v[1], v[2]};
  return true;
}

Eigen::Vector2d eastNorth(const GeoOrigin& o, double x, double y) {
  // x has compass heading h (clockwise from north): in (east, north) it is (sin h, cos h); y, 90
  // degrees anticlockwise from x (z up), is (-cos h, sin h).
  const double h = o.heading_deg * M_PI / 180.0;
  return {x * std::sin(h) - y * std::cos(h), x * std::cos(h) + y * std::sin(h)};
}

Eigen::Vector2d latLon(const GeoOrigin& o, double x, double y) {
  const GeographicLib::LocalCartesian plane(o.lat_deg, o.lon_deg, 0.0);
  const Eigen::Vector2d en = eastNorth(o, x, y);
  double lat = 0.0, lon = 0.0, h = 0.0;
  plane.Reverse(en.x(), en.y(), 0.0, lat, lon, h);
  return {lat, lon};
}

void writeExportFile(const std::string& path, mode_t mode, const std::function<void(std::ostream&)>& fill) {
  try {
    writeFileAtomically(path, fill, mode);
  } catch (const FileWriteError& e) {
    throw ExportError(e.what());
  }
}

void writeTum(const std::string& path, const ExportTrack& track, mode_t mode) {
  writeExportFile(path, mode, [&](std::ostream& f) {
    f << std::fixed;
    for (const ExportKeyframe& k : track.keyframes) {
      const Pose2& p = k.pose.mean;
      f << std::setprecision(6) << k.stamp_s << std::setprecision(9) << " " << p.x() << " " << p.y() << " 0 0 0 "
        << std::sin(p.yaw() / 2.0) << " " << std::cos(p.yaw() / 2.0) << "\n";
    }
  });
}

void writeKitti(const std::string& path, const ExportTrack& track, mode_t mode) {
  writeExportFile(path, mode, [&](std::ostream& f) {
    f << std::scientific << std::setprecision(9);
    for (const ExportKeyframe& k : track.keyframes) {
      const Pose2& p = k.pose.mean;
      const double c = std::cos(p.yaw()), s = std::sin(p.yaw());
      f << c << " " << -s << " " << 0.0 << " " << p.x() << " " << s << " " << c << " " << 0.0 << " " << p.y() << " "
        << 0.0 << " " << 0.0 << " " << 1.0 << " " << 0.0 << "\n";
    }
  });
}

void writeTrackCsv(const std::string& path, const ExportTrack& track, mode_t mode) {
  writeExportFile(path, mode, [&](std::ostream& f) {
    f << "stamp_s,session,keyframe,frame_index,x_m,y_m,yaw_rad,altitude_m,cov_xx,cov_xy,cov_xyaw,cov_yy,cov_yyaw,"
         "cov_yawyaw\n";
    for (const ExportKeyframe& k : track.keyframes) {
      const Pose2& p = k.pose.mean;
      const Eigen::Matrix3d& c = k.pose.covariance;
      f << std::fixed << std::setprecision(6) << k.stamp_s << "," << k.session << "," << k.keyframe << ","
        << k.frame_index << "," << std::setprecision(9) << p.x() << "," << p.y() << "," << p.yaw() << ","
        << std::setprecision(4) << k.altitude_m << std::scientific << std::setprecision(9);
      if (k.covariance_known)
        f << "," << c(0, 0) << "," << c(0, 1) << "," << c(0, 2) << "," << c(1, 1) << "," << c(1, 2) << "," << c(2, 2)
          << "\n";
      else
        f << ",nan,nan,nan,nan,nan,nan\n";
    }
  });
}

void writeG2o(const std::string& path, const ExportTrack& track, mode_t mode) {
  writeExportFile(path, mode, [&](std::ostream& f) {
    f << std::setprecision(12);
    int unknown = 0;
    for (const ExportEdge& e : track.edges) unknown += !e.information_known;
    if (unknown > 0)
      f << "# " << unknown << " of " << track.edges.size()
        << " edges have no known information matrix (their covariance was not recorded): written as comments\n";
    for (std::size_t i = 0; i < track.keyframes.size(); ++i) {
      const Pose2& p = track.keyframes[i].pose.mean;
      f << "VERTEX_SE2 " << i << " " << p.x() << " " << p.y() << " " << p.yaw() << "\n";
    }
    if (!track.keyframes.empty()) f << "FIX 0\n";
    for (const ExportEdge& e : track.edges) {
      if (!e.information_known) {
        f << "# EDGE_SE2 " << e.from << " " << e.to << " " << e.z.mean.x() << " " << e.z.mean.y() << " "
          << e.z.mean.yaw() << " information unknown (" << edgeKindName(e.kind) << ")\n";
        continue;
      }
      Eigen::FullPivLU<Eigen::Matrix3d> lu(e.z.covariance);
      if (!lu.isInvertible() || !e.z.covariance.allFinite())
        throw ExportError(path + ": the " + std::string(edgeKindName(e.kind)) + " edge " + std::to_string(e.from) +
                          " -> " + std::to_string(e.to) + " has a singular covariance");
      Eigen::Matrix3d info = lu.inverse();
      info = 0.5 * (info + info.transpose());
      const Pose2& z = e.z.mean;
      f << "EDGE_SE2 " << e.from << " " << e.to << " " << z.x() << " " << z.y() << " " << z.yaw() << " " << info(0, 0)
        << " " << info(0, 1) << " " << info(0, 2) << " " << info(1, 1) << " " << info(1, 2) << " " << info(2, 2)
        << "\n";
    }
  });
}

void writeGeoJson(const std::string& path, const std::vector<const ExportTrack*>& sessions, const GeoOrigin& origin,
                  mode_t mode) {
  writeExportFile(path, mode, [&](std::ostream& f) {
    f << "{\"type\": \"FeatureCollection\", \"features\": [";
    for (std::size_t t = 0; t < sessions.size(); ++t) {
      const ExportTrack& s = *sessions[t];
      std::string name;  // JSON string escaping of the session's name
      for (unsigned char c : s.name) {
        if (c == '"' || c == '\\') {
          name += '\\';
          name += static_cast<char>(c);
        } else if (c < 0x20) {
          char buf[8];
          std::snprintf(buf, sizeof buf, "\\u%04x", c);
          name += buf;
        } else {
          name += static_cast<char>(c);
        }
      }
      f << (t ? ",\n" : "\n")
        << "{\"type\": \"Feature\", \"properties\": {\"session\": " << (s.sessions.empty() ? 0 : s.sessions.front())
        << ", \"name\": \"" << name << "\", \"map\": " << s.map << ", \"keyframes\": " << s.keyframes.size()
        << std::fixed << std::setprecision(6)
        << ", \"first_stamp_s\": " << (s.keyframes.empty() ? 0.0 : s.keyframes.front().stamp_s)
        << ", \"last_stamp_s\": " << (s.keyframes.empty() ? 0.0 : s.keyframes.back().stamp_s)
        << "}, \"geometry\": {\"type\": \"LineString\", \"coordinates\": [";
      f << std::setprecision(9);
      for (std::size_t i = 0; i < s.keyframes.size(); ++i) {
        const Pose2& p = s.keyframes[i].pose.mean;
        const Eigen::Vector2d ll = latLon(origin, p.x(), p.y());
        f << (i ? ", " : "") << "[" << ll.y() << ", " << ll.x() << "]";
      }
      f << "]}}";
    }
    f << "\n]}\n";
  });
}

}  // namespace core
}  // namespace uw_multislam
