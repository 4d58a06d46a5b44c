// The session store's reads: sessions, keyframes (all of them, or one keyframe's features), the
// odometry, loops, maps, split pairs, provenance and the audit trail. Every value is checked as it
// is read: a damaged row is a StoreError naming its column and table.
#include "uw_multislam/core/store/session_store.h"

#include <sqlite3.h>

#include <cmath>
#include <cstring>
#include <map>
#include <set>

#include "session_store_detail.h"

namespace uw_multislam {
namespace core {

using namespace store_detail;  // NOLINT: the store's own helpers

std::vector<StoredSession> SessionStore::sessions() const {
  Statement st(this,
               "SELECT s.id, s.name, s.state, s.start_stamp, s.end_stamp, s.cam_width, s.cam_height, s.cam_fx, "
               "s.cam_fy, s.cam_cx, s.cam_cy, (SELECT COUNT(*) FROM keyframes k WHERE k.session = s.id) "
               "FROM sessions s ORDER BY s.id");
  std::vector<StoredSession> out;
  while (st.step()) {
    sqlite3_stmt* q = st.get();
    StoredSession s;
    s.id = sqlite3_column_int64(q, 0);
    s.name = reinterpret_cast<const char*>(sqlite3_column_text(q, 1));
    s.state = checkedText(q, 2, path_, {"recording", "finished"}) == "finished" ? StoredSessionState::kFinished
                                                                                : StoredSessionState::kRecording;
    s.start_stamp_s = realColumn(q, 3, path_);
    s.end_stamp_s = realColumn(q, 4, path_);
    s.camera.width = intColumn(q, 5, path_);
    s.camera.height = intColumn(q, 6, path_);
    s.camera.fx = realColumn(q, 7, path_);
    s.camera.fy = realColumn(q, 8, path_);
    s.camera.cx = realColumn(q, 9, path_);
    s.camera.cy = realColumn(q, 10, path_);
    s.keyframes = intColumn(q, 11, path_);
    // 0x0: unknown (a session without keyframes; older stores kept it for some with keyframes);
    // anything else must be a camera the odometry could have run with.
    if (const std::string bad = unusableCamera(s.camera); !bad.empty())
      throw StoreError("session store " + path_ + ": session " + std::to_string(s.id) + " '" + s.name +
                       "' has a damaged camera row (" + bad + ")");
    out.push_back(s);
  }
  return out;
}

// The columns of a keyframe row as keyframes() and keyframeFeatures() read them: frame data from
// column 0 (keyframe, frame_index, stamp, altitude, image size, num_features), then points,
// descriptors, hash and thumbnail (NULL where not read).
void SessionStore::readKeyframe(sqlite3_stmt* q, std::int64_t session, KeyframeColumns columns, bool features,
                                StoredKeyframe* k) const {
  k->session = session;
  k->keyframe = intColumn(q, 0, path_);
  k->frame_index = intColumn(q, 1, path_);
  k->stamp_s = realColumn(q, 2, path_);
  k->altitude_m = realColumn(q, 3, path_);
  // Every stored keyframe had a finite stamp (a text 'nan' is refused above as not a number; an
  // infinite one passed). An altitude that is not usable is the exports' to count as missing
  // (test_export_survey: a keyframe without valid altitude is left out of the mosaic).
  if (!std::isfinite(k->stamp_s))
    throw StoreError("session store " + path_ + ": keyframe " + std::to_string(k->keyframe) + " of session " +
                     std::to_string(session) + " has stamp " + std::to_string(k->stamp_s) + " (damaged)");
  k->image_size = cv::Size(intColumn(q, 4, path_), intColumn(q, 5, path_));
  const int n = intColumn(q, 6, path_);
  const auto corrupt = [&] {
    return StoreError("session store " + path_ + ": keyframe " + std::to_string(k->keyframe) + " of session " +
                      std::to_string(session) + " has blobs of the wrong size (corrupt)");
  };
  if (features) {
    k->points = blobPrefix<cv::Point2f>(q, 7, path_);
    const std::vector<std::uint8_t> d = blobPrefix<std::uint8_t>(q, 8, path_);
    // n x 128 bytes (SIFT) or n x 32 (ORB): the blob's size tells which (the store's meta row
    // `features` says which kind all its sessions hold).
    const std::size_t sift = descriptorBytes(FeatureType::kSift), orb = descriptorBytes(FeatureType::kOrb);
    const std::size_t un = n < 0 ? 0 : static_cast<std::size_t>(n);
    if (n < 0 || static_cast<int>(k->points.size()) != n || (d.size() != un * sift && d.size() != un * orb))
      throw corrupt();
    // With no feature the blob says nothing: the store's kind, once known (0 x 32 stays ORB).
    const std::size_t width = n > 0 ? (d.size() == un * orb ? orb : sift)
                                    : (descriptor_bytes_ > 0 ? static_cast<std::size_t>(descriptor_bytes_) : sift);
    k->descriptors = cv::Mat(n, static_cast<int>(width), CV_8U);
    if (n > 0) std::memcpy(k->descriptors.data, d.data(), d.size());
  }
  if (columns != KeyframeColumns::kFrame) {
    const std::vector<float> h = blobPrefix<float>(q, 9, path_);
    if (h.empty() && sqlite3_column_type(q, 9) == SQLITE_BLOB && n == 0) {
      k->hash = Eigen::VectorXf::Zero(HalocProjections::kHashSize);  // a keyframe that never arrived
    } else {
      if (h.size() != static_cast<std::size_t>(HalocProjections::kHashSize)) throw corrupt();
      k->hash = Eigen::Map<const Eigen::VectorXf>(h.data(), static_cast<Eigen::Index>(h.size()));
    }
  }
  if (columns == KeyframeColumns::kAll) k->thumbnail = blobVector<std::uint8_t>(q, 10, path_);
}

std::vector<StoredKeyframe> SessionStore::keyframes(std::int64_t session, KeyframeColumns columns) const {
  const char* sql =
      columns == KeyframeColumns::kAll
          ? "SELECT keyframe, frame_index, stamp, altitude, image_width, image_height, num_features, points, "
            "descriptors, hash, thumbnail FROM keyframes WHERE session = ? ORDER BY keyframe"
      : columns == KeyframeColumns::kHash
          ? "SELECT keyframe, frame_index, stamp, altitude, image_width, image_height, num_features, NULL, NULL, "
            "hash, NULL FROM keyframes WHERE session = ? ORDER BY keyframe"
          : "SELECT keyframe, frame_index, stamp, altitude, image_width, image_height, num_features "
            "FROM keyframes WHERE session = ? ORDER BY keyframe";
  Statement st(this, sql);
  st.bind(1, session);
  std::vector<StoredKeyframe> out;
  while (st.step()) {
    StoredKeyframe k;
    readKeyframe(st.get(), session, columns, columns == KeyframeColumns::kAll, &k);
    out.push_back(std::move(k));
  }
  return out;
}

std::vector<std::vector<std::uint8_t>> SessionStore::thumbnails(std::int64_t session) const {
  Statement st(this, "SELECT thumbnail FROM keyframes WHERE session = ? ORDER BY keyframe");
  st.bind(1, session);
  std::vector<std::vector<std::uint8_t>> out;
  while (st.step()) out.push_back(blobVector<std::uint8_t>(st.get(), 0, path_));
  return out;
}

StoredKeyframe SessionStore::keyframeFeatures(std::int64_t session, int keyframe) const {
  Statement st(this,
               "SELECT keyframe, frame_index, stamp, altitude, image_width, image_height, num_features, points, "
               "descriptors FROM keyframes WHERE session = ? AND keyframe = ?");
  st.bind(1, session).bind(2, keyframe);
  if (!st.step())
    throw StoreError("session store " + path_ + ": keyframe " + std::to_string(keyframe) + " of session " +
                     std::to_string(session) + " is not in the store");
  StoredKeyframe k;
  readKeyframe(st.get(), session, KeyframeColumns::kFrame, true, &k);
  return k;
}

std::vector<UncertainPose2> SessionStore::odometry(std::int64_t session) const {
  Statement st(this, "SELECT keyframe, x, y, yaw, cov FROM motions WHERE session = ? ORDER BY keyframe");
  st.bind(1, session);
  std::vector<UncertainPose2> out;
  while (st.step()) {
    sqlite3_stmt* q = st.get();
    if (intColumn(q, 0, path_) != static_cast<int>(out.size()) + 1)
      throw StoreError("session store " + path_ + ": session " + std::to_string(session) +
                       " misses the motion to keyframe " + std::to_string(out.size() + 1));
    const std::vector<double> c = blobVector<double>(q, 4, path_);
    if (c.size() != 9) throw StoreError("session store " + path_ + ": a motion covariance has the wrong size");
    out.emplace_back(Pose2(realColumn(q, 1, path_), realColumn(q, 2, path_), realColumn(q, 3, path_)),
                     covFrom(c.data()));
  }
  return out;
}

std::vector<MotionSource> SessionStore::motionSources(std::int64_t session) const {
  Statement st(this, "SELECT source FROM motions WHERE session = ? ORDER BY keyframe");
  st.bind(1, session);
  std::vector<MotionSource> out;
  while (st.step()) {
    const unsigned char* t = sqlite3_column_text(st.get(), 0);
    MotionSource s = MotionSource::kVisual;
    if (!t || !parseMotionSource(reinterpret_cast<const char*>(t), &s))
      throw StoreError("session store " + path_ + ": a motion has an unknown source");
    out.push_back(s);
  }
  return out;
}

std::vector<StoredLoop> SessionStore::loops() const {
  Statement st(this,
               "SELECT id, session_a, keyframe_a, session_b, keyframe_b, kind, inliers, x, y, yaw, cov, summarised, "
               "applied, refused FROM loops ORDER BY id");
  std::vector<StoredLoop> out;
  while (st.step()) {
    sqlite3_stmt* q = st.get();
    StoredLoop l;
    l.id = sqlite3_column_int64(q, 0);
    l.session_a = int64Column(q, 1, path_);
    l.keyframe_a = intColumn(q, 2, path_);
    l.session_b = int64Column(q, 3, path_);
    l.keyframe_b = intColumn(q, 4, path_);
    l.global = checkedText(q, 5, path_, {"local", "global"}) == "global";
    l.inliers = intColumn(q, 6, path_);
    const std::vector<double> c = blobVector<double>(q, 10, path_);
    if (c.size() != 9) throw StoreError("session store " + path_ + ": a loop covariance has the wrong size");
    l.z = UncertainPose2(Pose2(realColumn(q, 7, path_), realColumn(q, 8, path_), realColumn(q, 9, path_)),
                         covFrom(c.data()));
    l.summarised = intColumn(q, 11, path_) != 0;
    l.applied = intColumn(q, 12, path_) != 0;
    l.refused = intColumn(q, 13, path_) != 0;
    out.push_back(l);
  }
  if (hasTable("nav_placements")) {
    std::set<std::int64_t> placements;
    Statement np(this, "SELECT loop FROM nav_placements");
    while (np.step()) placements.insert(sqlite3_column_int64(np.get(), 0));
    for (StoredLoop& l : out) l.nav_placement = placements.count(l.id) > 0;
  }
  return out;
}

std::vector<StoredMap> SessionStore::maps() const {
  std::vector<StoredMap> out;
  std::map<std::int64_t, std::size_t> at;
  Statement st(this, "SELECT id, pending, motions FROM maps ORDER BY id");
  while (st.step()) {
    sqlite3_stmt* q = st.get();
    StoredMap m;
    m.pending = intColumn(q, 1, path_);
    const std::vector<double> v = blobVector<double>(q, 2, path_);
    if (v.size() % 12 != 0) throw StoreError("session store " + path_ + ": map motions have the wrong size");
    for (std::size_t i = 0; i < v.size(); i += 12)
      m.motions.emplace_back(Pose2(v[i], v[i + 1], v[i + 2]), covFrom(&v[i + 3]));
    at[sqlite3_column_int64(q, 0)] = out.size();
    out.push_back(std::move(m));
  }
  Statement ms(this, "SELECT map, session FROM map_sessions ORDER BY map, position");
  while (ms.step()) {
    const auto it = at.find(int64Column(ms.get(), 0, path_));
    if (it == at.end()) throw StoreError("session store " + path_ + ": a map session of no map");
    out[it->second].chain.push_back(int64Column(ms.get(), 1, path_));
  }
  Statement ln(this, "SELECT map, x, y, yaw, cov, loops FROM links ORDER BY map, position");
  while (ln.step()) {
    sqlite3_stmt* q = ln.get();
    const auto it = at.find(int64Column(q, 0, path_));
    if (it == at.end()) throw StoreError("session store " + path_ + ": a link of no map");
    const std::vector<double> c = blobVector<double>(q, 4, path_);
    if (c.size() != 9) throw StoreError("session store " + path_ + ": a link covariance has the wrong size");
    StoredLink l;
    l.measured = UncertainPose2(Pose2(realColumn(q, 1, path_), realColumn(q, 2, path_), realColumn(q, 3, path_)),
                                covFrom(c.data()));
    l.loops = blobVector<std::int64_t>(q, 5, path_);
    out[it->second].links.push_back(std::move(l));
  }
  if (hasTable("position_priors")) {
    Statement pr(this,
                 "SELECT map, session, keyframe, x, y, cxx, cxy, cyy, applied FROM position_priors ORDER BY rowid");
    while (pr.step()) {
      sqlite3_stmt* q = pr.get();
      const auto it = at.find(int64Column(q, 0, path_));
      if (it == at.end()) continue;  // a prior of a map that is gone: its frame with it
      StoredPrior p;
      p.session = int64Column(q, 1, path_);
      p.keyframe = intColumn(q, 2, path_);
      p.position = Eigen::Vector2d(realColumn(q, 3, path_), realColumn(q, 4, path_));
      p.covariance << realColumn(q, 5, path_), realColumn(q, 6, path_), realColumn(q, 6, path_),
          realColumn(q, 7, path_);
      p.applied = intColumn(q, 8, path_) != 0;
      out[it->second].priors.push_back(p);
    }
  }
  for (const StoredMap& m : out) {
    if (m.chain.empty() || m.links.size() + 1 != m.chain.size())
      throw StoreError("session store " + path_ + ": a stored map has " + std::to_string(m.chain.size()) +
                       " sessions and " + std::to_string(m.links.size()) + " links (corrupt)");
    // A session is in one place of one chain (it silently became two maps).
    std::set<std::int64_t> seen;
    for (std::int64_t s : m.chain)
      if (!seen.insert(s).second)
        throw StoreError("session store " + path_ + ": the stored map of session " + std::to_string(m.chain.front()) +
                         " names session " + std::to_string(s) + " twice (corrupt)");
  }
  return out;
}

std::vector<std::pair<std::int64_t, std::int64_t>> SessionStore::splitPairs() const {
  Statement st(this, "SELECT session_a, session_b FROM split_pairs ORDER BY session_a, session_b");
  std::vector<std::pair<std::int64_t, std::int64_t>> out;
  while (st.step()) out.emplace_back(int64Column(st.get(), 0, path_), int64Column(st.get(), 1, path_));
  return out;
}
std::vector<SessionProvenance> SessionStore::provenance() const {
  std::vector<SessionProvenance> out;
  if (!hasTable("provenance")) return out;
  Statement st(
      this, "SELECT session, source_file, source_session, source_name, vehicle, dive FROM provenance ORDER BY session");
  auto text = [&](int col) { return columnText(st.get(), col); };
  while (st.step()) {
    SessionProvenance p;
    p.session = int64Column(st.get(), 0, path_);
    p.source_file = text(1);
    p.source_session = int64Column(st.get(), 2, path_);
    p.source_name = text(3);
    p.vehicle = text(4);
    p.dive = text(5);
    out.push_back(std::move(p));
  }
  return out;
}
std::vector<HistoryEntry> SessionStore::history() const {
  std::vector<HistoryEntry> out;
  if (!hasTable("history")) return out;
  Statement st(this, "SELECT id, time_utc, kind, cause, sessions, loops, message FROM history ORDER BY id");
  auto text = [&](int col) { return columnText(st.get(), col); };
  while (st.step())
    out.push_back({sqlite3_column_int64(st.get(), 0), text(1), text(2), text(3), text(4), text(5), text(6)});
  return out;
}

std::optional<std::string> SessionStore::datum() const {
  Statement st(this, "SELECT value FROM meta WHERE key = ?");
  st.bind(1, std::string(kDatumKey));
  if (!st.step()) return std::nullopt;
  return columnText(st.get(), 0);
}

}  // namespace core
}  // namespace uw_multislam
