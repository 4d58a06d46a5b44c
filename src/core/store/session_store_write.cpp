// The session store's writes: sessions, keyframes with their motions and loops (one
// transaction each), the maps, deletions, provenance and the audit trail.
#include "uw_multislam/core/store/session_store.h"

#include <sqlite3.h>

#include <algorithm>
#include <set>

#include "session_store_detail.h"

namespace uw_multislam {
namespace core {

using namespace store_detail;  // NOLINT: the store's own helpers

namespace {
// The meta row that keeps the ids of deleted sessions from being given again: `id INTEGER PRIMARY
// KEY` without AUTOINCREMENT reuses the largest id once its row is gone, and a schema change
// (AUTOINCREMENT) would make older builds' stores unreadable for nothing. A store without the row
// has deleted no session (or only below its largest id).
const char* kDeletedIdsKey = "next_session_id";

// A keyframe that never arrived (no features, no image, a zero hash): its row is the minimal
// form, an empty hash blob instead of 384 zeros, so a gap of lost keyframes costs a few bytes per
// keyframe of store rather than 1.5 kB each (readKeyframe gives it back as the zero hash).
bool isPlaceholder(const StoredKeyframe& kf) {
  return kf.points.empty() && kf.descriptors.empty() && kf.thumbnail.empty() && kf.hash.isZero(0.0f);
}

const char* kInsertPrior =
    "INSERT INTO position_priors(map, session, keyframe, x, y, cxx, cxy, cyy, applied) "
    "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)";

// A template: SessionStore::Statement is the store's own (private) class.
template <typename S>
S& bindPrior(S* pr, std::int64_t map, const StoredPrior& p) {
  return pr->bind(1, map)
      .bind(2, p.session)
      .bind(3, p.keyframe)
      .bind(4, p.position.x())
      .bind(5, p.position.y())
      .bind(6, p.covariance(0, 0))
      .bind(7, p.covariance(0, 1))
      .bind(8, p.covariance(1, 1))
      .bind(9, p.applied ? 1 : 0);
}
}  // namespace

std::int64_t SessionStore::nextSessionId() const {
  Statement st(this,
               "SELECT COALESCE((SELECT MAX(id) + 1 FROM sessions), 0), "
               "COALESCE((SELECT CAST(value AS INTEGER) FROM meta WHERE key = ?), 0)");
  st.bind(1, std::string(kDeletedIdsKey));
  if (!st.step()) throw StoreError("session store " + path_ + ": its session ids could not be read");
  return std::max(sqlite3_column_int64(st.get(), 0), sqlite3_column_int64(st.get(), 1));
}

std::int64_t SessionStore::addSession(const std::string& name, const CameraIntrinsics& c, double start_stamp_s,
                                      std::int64_t id) {
  if (const std::string bad = unusableCamera(c); !bad.empty())
    throw StoreError("session store " + path_ + ": session '" + name + "' not added: its camera is not usable (" + bad +
                     ")");
  Statement deleted(this, "SELECT CAST(value AS INTEGER) FROM meta WHERE key = ?");
  deleted.bind(1, std::string(kDeletedIdsKey));
  const std::int64_t floor = deleted.step() ? sqlite3_column_int64(deleted.get(), 0) : 0;
  if (id >= 0 && id < floor) {
    Statement taken(this, "SELECT count(*) FROM sessions WHERE id = ?");
    taken.bind(1, id);
    if (!taken.step() || sqlite3_column_int(taken.get(), 0) == 0)
      throw StoreError("session store " + path_ + ": session '" + name + "' not added: id " + std::to_string(id) +
                       " was a deleted session's (ids are never given twice)");
  }
  // Without an id (merge_stores, tools): the next one no session has had, from 0 like the session
  // manager's, so that a store's ids are the ids the engine gave (SQLite would start at 1).
  if (id < 0) id = nextSessionId();
  Statement st(this,
               "INSERT INTO sessions(id, name, state, start_stamp, end_stamp, cam_width, cam_height, cam_fx, cam_fy, "
               "cam_cx, cam_cy) VALUES (?, ?, 'recording', ?, ?, ?, ?, ?, ?, ?, ?)");
  st.bind(1, id);
  st.bind(2, name).bind(3, start_stamp_s).bind(4, start_stamp_s).bind(5, c.width).bind(6, c.height);
  st.bind(7, c.fx).bind(8, c.fy).bind(9, c.cx).bind(10, c.cy).run();
  return sqlite3_last_insert_rowid(db_);
}

void SessionStore::setSessionCamera(std::int64_t session, const CameraIntrinsics& c) {
  if (const std::string bad = unusableCamera(c); !bad.empty())
    throw StoreError("session store " + path_ + ": session " + std::to_string(session) +
                     ": camera not stored, it is not usable (" + bad + ")");
  Statement st(this,
               "UPDATE sessions SET cam_width = ?, cam_height = ?, cam_fx = ?, cam_fy = ?, cam_cx = ?, cam_cy = ? "
               "WHERE id = ?");
  st.bind(1, c.width).bind(2, c.height).bind(3, c.fx).bind(4, c.fy).bind(5, c.cx).bind(6, c.cy).bind(7, session).run();
}

void SessionStore::endSession(std::int64_t session, double end_stamp_s) {
  Statement st(this, "UPDATE sessions SET state = 'finished', end_stamp = ? WHERE id = ?");
  st.bind(1, end_stamp_s).bind(2, session).run();
}
void SessionStore::insertKeyframe(const StoredKeyframe& kf, const UncertainPose2* motion) {
  if (kf.hash.size() != HalocProjections::kHashSize)
    throw StoreError("session store " + path_ + ": keyframe " + std::to_string(kf.keyframe) + ": hash of " +
                     std::to_string(kf.hash.size()) + " values");
  cv::Mat desc;
  if (!kf.descriptors.empty()) kf.descriptors.convertTo(desc, CV_8U);
  if (!desc.empty() &&
      (desc.rows != static_cast<int>(kf.points.size()) ||
       (desc.cols != descriptorBytes(FeatureType::kSift) && desc.cols != descriptorBytes(FeatureType::kOrb)) ||
       !desc.isContinuous()))
    throw StoreError("session store " + path_ + ": keyframe " + std::to_string(kf.keyframe) +
                     ": descriptors do not match the points");
  if (!desc.empty() && descriptor_bytes_ > 0 && desc.cols != descriptor_bytes_)
    throw StoreError("session store " + path_ + ": keyframe " + std::to_string(kf.keyframe) + " has descriptors of " +
                     std::to_string(desc.cols) + " bytes; this store's kind has " + std::to_string(descriptor_bytes_));
  Statement& k = cached(
      "INSERT INTO keyframes(session, keyframe, frame_index, stamp, altitude, image_width, image_height, "
      "num_features, points, descriptors, hash, thumbnail) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)");
  k.bind(1, kf.session).bind(2, kf.keyframe).bind(3, kf.frame_index).bind(4, kf.stamp_s).bind(5, kf.altitude_m);
  k.bind(6, kf.image_size.width).bind(7, kf.image_size.height).bind(8, static_cast<int>(kf.points.size()));
  k.blob(9, kf.points.data(), kf.points.size() * sizeof(cv::Point2f));
  k.blob(10, desc.data, desc.total());
  if (isPlaceholder(kf)) {
    k.emptyBlob(11);  // not NULL: the column is NOT NULL, and NULL would read as damage
  } else {
    k.blob(11, kf.hash.data(), sizeof(float) * kf.hash.size());
  }
  k.blob(12, kf.thumbnail);
  k.run();
  if (motion) {
    const std::vector<double> cov = covBlob(motion->covariance);
    Statement& m =
        cached("INSERT INTO motions(session, keyframe, x, y, yaw, cov, source) VALUES (?, ?, ?, ?, ?, ?, ?)");
    m.bind(1, kf.session).bind(2, kf.keyframe).bind(3, motion->mean.x()).bind(4, motion->mean.y());
    m.bind(5, motion->mean.yaw()).blob(6, cov).bind(7, std::string(motionSourceName(kf.motion_source))).run();
  }
}

void SessionStore::addKeyframe(const StoredKeyframe& kf, const UncertainPose2* motion, std::vector<StoredLoop>* loops,
                               const std::vector<StoredKeyframe>& gap, const UncertainPose2* gap_motion) {
  if (!gap.empty() && !gap_motion)
    throw StoreError("session store " + path_ + ": keyframe " + std::to_string(kf.keyframe) +
                     ": a gap without its motion");
  begin();
  try {
    for (const StoredKeyframe& lost : gap) {
      if (!isPlaceholder(lost))
        throw StoreError("session store " + path_ + ": keyframe " + std::to_string(lost.keyframe) +
                         " of a gap has features, an image or a hash");
      insertKeyframe(lost, gap_motion);
    }
    insertKeyframe(kf, motion);
    if (loops) insertLoops(loops);
    commit();
  } catch (...) {
    rollback();
    throw;
  }
}

void SessionStore::insertLoops(std::vector<StoredLoop>* loops) {
  Statement& l = cached(
      "INSERT INTO loops(session_a, keyframe_a, session_b, keyframe_b, kind, inliers, x, y, yaw, cov, summarised, "
      "applied, refused) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)");
  for (StoredLoop& lp : *loops) {
    const std::vector<double> cov = covBlob(lp.z.covariance);
    l.bind(1, lp.session_a).bind(2, lp.keyframe_a).bind(3, lp.session_b).bind(4, lp.keyframe_b);
    l.bind(5, std::string(lp.global ? "global" : "local")).bind(6, lp.inliers);
    l.bind(7, lp.z.mean.x()).bind(8, lp.z.mean.y()).bind(9, lp.z.mean.yaw()).blob(10, cov);
    l.bind(11, lp.summarised ? 1 : 0).bind(12, lp.applied ? 1 : 0).bind(13, lp.refused ? 1 : 0).run();
    lp.id = sqlite3_last_insert_rowid(db_);
    if (lp.nav_placement) cached("INSERT INTO nav_placements(loop) VALUES (?)").bind(1, lp.id).run();
  }
}

void SessionStore::addLoops(std::vector<StoredLoop>* loops) {
  if (loops->empty()) return;
  begin();
  try {
    insertLoops(loops);
    commit();
  } catch (...) {
    rollback();
    throw;
  }
}

void SessionStore::addPositionPrior(std::int64_t map, const StoredPrior& p) {
  begin();
  try {
    // A session alone in its map since it started has no stored map until a join, a split or its
    // end saves the maps: without one, a restart would have no frame to put the prior in.
    Statement stored(this,
                     "SELECT (SELECT count(*) FROM maps WHERE id = ?1) + "
                     "(SELECT count(*) FROM map_sessions WHERE session = ?1)");
    stored.bind(1, map);
    const bool unsaved = stored.step() && sqlite3_column_int64(stored.get(), 0) == 0;
    stored.reset();
    if (unsaved && map == p.session) {
      // Without motions: restored from the session's odometry.
      Statement m(this, "INSERT INTO maps(id, pending, motions) VALUES (?, 0, NULL)");
      m.bind(1, map).run();
      Statement ms(this, "INSERT INTO map_sessions(map, position, session) VALUES (?, 0, ?)");
      ms.bind(1, map).bind(2, map).run();
    }
    // The stored motions are without it: the map is optimised again after a restart (the
    // back-end counts a new prior as pending too).
    Statement due(this, "UPDATE maps SET pending = pending + 1 WHERE id = ?");
    due.bind(1, map).run();
    // No stored map row to hang it on (a join whose save failed): a restart would drop it silently.
    if (sqlite3_changes(db_) == 0)
      throw StoreError("session store " + path_ + ": position prior on keyframe " + std::to_string(p.keyframe) +
                       " of session " + std::to_string(p.session) + " not stored: map " + std::to_string(map) +
                       " is not in the store");
    Statement pr(this, kInsertPrior);
    bindPrior(&pr, map, p).run();
    commit();
  } catch (...) {
    rollback();
    throw;
  }
}

void SessionStore::saveMaps(const std::vector<StoredMap>& maps, const std::vector<StoredLoop>& loop_states,
                            const std::vector<std::pair<std::int64_t, std::int64_t>>& split_pairs) {
  begin();
  try {
    exec("DELETE FROM split_pairs;");
    writeMaps(maps);
    Statement ls(this, "UPDATE loops SET summarised = ?, applied = ?, refused = ? WHERE id = ?");
    for (const StoredLoop& l : loop_states)
      ls.bind(1, l.summarised ? 1 : 0).bind(2, l.applied ? 1 : 0).bind(3, l.refused ? 1 : 0).bind(4, l.id).run();
    Statement sp(this, "INSERT OR IGNORE INTO split_pairs(session_a, session_b) VALUES (?, ?)");
    for (const auto& [a, b] : split_pairs) sp.bind(1, a).bind(2, b).run();
    commit();
  } catch (...) {
    rollback();
    throw;
  }
}

void SessionStore::writeMaps(const std::vector<StoredMap>& maps) {
  exec("DELETE FROM maps; DELETE FROM map_sessions; DELETE FROM links; DELETE FROM position_priors;");
  {
    Statement pr(this, kInsertPrior);
    for (const StoredMap& map : maps)
      for (const StoredPrior& p : map.priors) bindPrior(&pr, map.chain.at(0), p).run();
  }
  {
    Statement m(this, "INSERT INTO maps(id, pending, motions) VALUES (?, ?, ?)");
    Statement ms(this, "INSERT INTO map_sessions(map, position, session) VALUES (?, ?, ?)");
    Statement ln(this, "INSERT INTO links(map, position, x, y, yaw, cov, loops) VALUES (?, ?, ?, ?, ?, ?, ?)");
    for (const StoredMap& map : maps) {
      if (map.chain.empty() || map.links.size() + 1 != map.chain.size())
        throw StoreError("session store " + path_ + ": a map to save has a bad chain");
      const std::int64_t id = map.chain.front();
      std::vector<double> motions;
      for (const UncertainPose2& u : map.motions) {
        motions.insert(motions.end(), {u.mean.x(), u.mean.y(), u.mean.yaw()});
        const std::vector<double> c = covBlob(u.covariance);
        motions.insert(motions.end(), c.begin(), c.end());
      }
      m.bind(1, id).bind(2, map.pending).blob(3, motions).run();
      for (std::size_t i = 0; i < map.chain.size(); ++i)
        ms.bind(1, id).bind(2, static_cast<int>(i)).bind(3, map.chain[i]).run();
      for (std::size_t i = 0; i < map.links.size(); ++i) {
        const StoredLink& l = map.links[i];
        const std::vector<double> cov = covBlob(l.measured.covariance);
        ln.bind(1, id).bind(2, static_cast<int>(i)).bind(3, l.measured.mean.x()).bind(4, l.measured.mean.y());
        ln.bind(5, l.measured.mean.yaw()).blob(6, cov).blob(7, l.loops).run();
      }
    }
  }
}

void SessionStore::deleteSessions(const std::vector<std::int64_t>& sessions, const HistoryEntry* entry) {
  begin();
  try {
    for (const std::int64_t s : sessions) deleteOne(s);
    if (entry) addHistory(*entry);
    commit();
  } catch (...) {
    rollback();
    throw;
  }
}

void SessionStore::deleteOne(std::int64_t session) {
  Statement has(this, "SELECT count(*) FROM sessions WHERE id = ?");
  has.bind(1, session);
  if (!has.step() || sqlite3_column_int(has.get(), 0) == 0)
    throw StoreError("session store " + path_ + ": no session with store id " + std::to_string(session) + " to delete");
  has.reset();
  // Ids are for life: the deleted id (and every one below the largest so far) is never given
  // again, also after a restart (nextSessionId).
  Statement mark(this, "INSERT OR REPLACE INTO meta(key, value) VALUES (?, ?)");
  mark.bind(1, std::string(kDeletedIdsKey)).bind(2, std::to_string(nextSessionId())).run();
  std::set<std::int64_t> gone_loops;
  Statement gl(this, "SELECT id FROM loops WHERE session_a = ? OR session_b = ?");
  gl.bind(1, session).bind(2, session);
  while (gl.step()) gone_loops.insert(sqlite3_column_int64(gl.get(), 0));
  // The maps without the session: a chain loses it and the link(s) that reached it; a chain it
  // sat in the middle of falls apart into the sessions before and those after (their link to
  // it measured nothing between them). A map that changed keeps no optimised motions (their
  // layout was the whole chain's): it is restored from the odometry and its links, and
  // optimised again at the next flush (pending >= 1).
  std::vector<StoredMap> kept;
  for (const StoredMap& m : maps()) {
    const auto at = std::find(m.chain.begin(), m.chain.end(), session);
    if (at == m.chain.end()) {
      StoredMap c = m;
      for (StoredLink& l : c.links)
        l.loops.erase(
            std::remove_if(l.loops.begin(), l.loops.end(), [&](std::int64_t id) { return gone_loops.count(id) > 0; }),
            l.loops.end());
      kept.push_back(std::move(c));
      continue;
    }
    const std::size_t i = static_cast<std::size_t>(at - m.chain.begin());
    for (const auto& [first, last] : {std::make_pair(std::size_t{0}, i), std::make_pair(i + 1, m.chain.size())}) {
      if (first >= last) continue;
      StoredMap part;
      part.chain.assign(m.chain.begin() + static_cast<std::ptrdiff_t>(first),
                        m.chain.begin() + static_cast<std::ptrdiff_t>(last));
      part.links.assign(m.links.begin() + static_cast<std::ptrdiff_t>(first),
                        m.links.begin() + static_cast<std::ptrdiff_t>(last - 1));
      part.pending = std::max(m.pending, 1);
      // The part before the session keeps the map's first session, so its frame: its priors hold.
      // The part after it starts a new frame; its priors, in the old one, go.
      for (const StoredPrior& p : m.priors)
        if (first == 0 && std::find(part.chain.begin(), part.chain.end(), p.session) != part.chain.end())
          part.priors.push_back(p);
      kept.push_back(std::move(part));
    }
  }
  for (const char* sql :
       {"DELETE FROM keyframes WHERE session = ?1", "DELETE FROM motions WHERE session = ?1",
        "DELETE FROM nav_placements WHERE loop IN (SELECT id FROM loops WHERE session_a = ?1 OR session_b = ?1)",
        "DELETE FROM loops WHERE session_a = ?1 OR session_b = ?1",
        "DELETE FROM split_pairs WHERE session_a = ?1 OR session_b = ?1", "DELETE FROM sessions WHERE id = ?1"}) {
    Statement d(this, sql);
    d.bind(1, session).run();
  }
  writeMaps(kept);
}
void SessionStore::addProvenance(const SessionProvenance& p) {
  bool stored = false;
  {
    Statement st(this, "SELECT 1 FROM sessions WHERE id = ?");
    st.bind(1, p.session);
    stored = st.step();
  }
  if (!stored)
    throw StoreError("session store " + path_ + ": provenance of session " + std::to_string(p.session) +
                     ", which is not stored");
  Statement st(this,
               "INSERT OR REPLACE INTO provenance(session, source_file, source_session, source_name, vehicle, dive) "
               "VALUES (?, ?, ?, ?, ?, ?)");
  st.bind(1, p.session).bind(2, p.source_file).bind(3, p.source_session).bind(4, p.source_name);
  st.bind(5, p.vehicle).bind(6, p.dive).run();
}
std::int64_t SessionStore::addHistory(HistoryEntry e) {
  if (e.id == 0) {
    Statement last(this, "SELECT COALESCE(MAX(id), 0) FROM history");
    last.step();
    e.id = sqlite3_column_int64(last.get(), 0) + 1;
  }
  Statement st(this,
               "INSERT INTO history(id, time_utc, kind, cause, sessions, loops, message) VALUES (?, ?, ?, ?, ?, ?, ?)");
  st.bind(1, e.id).bind(2, e.time_utc).bind(3, e.kind).bind(4, e.cause).bind(5, e.sessions).bind(6, e.loops);
  st.bind(7, e.message).run();
  return e.id;
}

void SessionStore::setDatum(const std::string& text) {
  Statement st(this, "INSERT OR REPLACE INTO meta(key, value) VALUES (?, ?)");
  st.bind(1, std::string(kDatumKey)).bind(2, text).run();
}

}  // namespace core
}  // namespace uw_multislam
