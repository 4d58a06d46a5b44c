#include "uw_multislam/core/store/map_persistence.h"

#include <algorithm>
#include <map>
#include <set>
#include <stdexcept>
#include <string>

namespace uw_multislam {
namespace core {

RestoredStore restoreStore(const SessionStore& store, MultiSessionBackend* backend, LoopDetector* detector,
                           std::vector<std::unique_ptr<CameraIntrinsics>>* cameras) {
  if (backend->numSessions() != 0 || backend->numLoops() != 0)
    throw std::invalid_argument("restoreStore: the back-end must be empty");
  RestoredStore out;
  std::map<std::int64_t, int> session_of;  // store id -> back-end id
  std::set<std::int64_t> rows;             // every stored session, with keyframes or not
  for (const StoredSession& s : store.sessions()) {
    rows.insert(s.id);
    if (s.keyframes == 0) continue;  // created, then a crash before its first keyframe
    const std::vector<UncertainPose2> odo = store.odometry(s.id);
    const std::vector<StoredKeyframe> kfs = store.keyframes(s.id, detector != nullptr);
    if (static_cast<int>(odo.size()) + 1 != static_cast<int>(kfs.size()))
      throw StoreError("session store " + store.path() + ": session " + std::to_string(s.id) + " has " +
                       std::to_string(kfs.size()) + " keyframes and " + std::to_string(odo.size()) + " motions");
    int id = -1;
    try {
      id = backend->restoreSession(s.name, odo);
    } catch (const std::invalid_argument& e) {  // a damaged motion: name the file and the session
      throw StoreError("session store " + store.path() + ": session " + std::to_string(s.id) + ": " + e.what());
    }
    session_of[s.id] = id;
    out.session_ids.push_back(s.id);
    out.frame_of_keyframe.emplace_back();
    const CameraIntrinsics* cam = nullptr;
    if (detector) {
      cameras->push_back(std::make_unique<CameraIntrinsics>(s.camera));
      cam = cameras->back().get();
    }
    for (const StoredKeyframe& k : kfs) {
      if (k.keyframe != static_cast<int>(out.frame_of_keyframe.back().size()))
        throw StoreError("session store " + store.path() + ": session " + std::to_string(s.id) + " misses keyframe " +
                         std::to_string(out.frame_of_keyframe.back().size()));
      out.frame_of_keyframe.back().push_back(k.frame_index);
      ++out.keyframes;
      if (!detector) continue;
      detector->addStoredKeyframe(id, k.keyframe, k.frame_index, k.altitude_m, cam, k.features(), k.hash);
    }
  }
  // Maps restored unjoined (a damaged link, a session the store does not hold): the loops their
  // links summarised are pending again, so that the next optimisation can find the join again
  // (summarised, they would be left out of every join for good).
  // unjoined[i]: why maps[i] is restored as its sessions unjoined ("" when it is restored).
  const std::vector<StoredMap> maps = store.maps();
  std::vector<std::string> unjoined(maps.size());
  std::set<std::int64_t> unsummarised;
  for (std::size_t i = 0; i < maps.size(); ++i) {
    const StoredMap& sm = maps[i];
    // A session without keyframes (started, never given one) is left out with its map, as
    // always. A map naming a session the store does not hold at all is damaged.
    const auto absent =
        std::find_if(sm.chain.begin(), sm.chain.end(), [&](std::int64_t s) { return !session_of.count(s); });
    if (absent != sm.chain.end()) {
      if (!rows.count(*absent))
        unjoined[i] = "session store " + store.path() + ": the map of session " + std::to_string(sm.chain.front()) +
                      " names session " + std::to_string(*absent) +
                      ", which the store does not hold: its sessions are restored unjoined";
    } else {
      // A link is a measurement (the loops it summarises), not derived data: nothing to rebuild
      // it from here.
      for (const StoredLink& l : sm.links) {
        const std::string bad = checkUncertainPose(l.measured);
        if (bad.empty()) continue;
        unjoined[i] = "session store " + store.path() + ": a link of the map of session " +
                      std::to_string(sm.chain.front()) + " is damaged (" + bad +
                      "): its sessions are restored unjoined";
        break;
      }
    }
    if (!unjoined[i].empty())
      for (const StoredLink& l : sm.links) unsummarised.insert(l.loops.begin(), l.loops.end());
  }
  std::map<std::int64_t, int> loop_of;
  for (const StoredLoop& l : store.loops()) {
    // Built only when refusing the loop: a restart restores every stored loop.
    const auto where = [&] {
      return "session store " + store.path() + ": loop " + std::to_string(l.id) + " (session " +
             std::to_string(l.session_a) + " keyframe " + std::to_string(l.keyframe_a) + " -> session " +
             std::to_string(l.session_b) + " keyframe " + std::to_string(l.keyframe_b) + "): ";
    };
    // Rows no build writes: a loop naming a session the store does not hold (it was dropped
    // without a word), or from a keyframe to itself (it was kept).
    if (!rows.count(l.session_a) || !rows.count(l.session_b))
      throw StoreError(where() + "names a session the store does not hold (damaged)");
    if (l.session_a == l.session_b && l.keyframe_a == l.keyframe_b)
      throw StoreError(where() + "from a keyframe to itself (damaged)");
    const auto a = session_of.find(l.session_a), b = session_of.find(l.session_b);
    if (a == session_of.end() || b == session_of.end()) continue;  // a session without keyframes
    const bool again = unsummarised.count(l.id) > 0;
    LoopRecord r{{a->second, l.keyframe_a, b->second, l.keyframe_b, l.z, l.inliers, l.nav_placement},
                 l.summarised && !again,
                 l.applied && !again,
                 l.refused};
    try {
      loop_of[l.id] = backend->restoreLoop(r);
    } catch (const std::invalid_argument& e) {  // a damaged pose or covariance, a keyframe past the session
      throw StoreError(where() + e.what());
    }
    out.loop_ids.push_back(l.id);
    out.loops.push_back(l);
  }
  std::vector<bool> in_map(backend->numSessions(), false);
  for (std::size_t i = 0; i < maps.size(); ++i) {
    const StoredMap& sm = maps[i];
    if (!unjoined[i].empty()) {  // its sessions come back as maps of their own
      out.notes.push_back(unjoined[i]);
      continue;
    }
    MapState st;
    int motions = static_cast<int>(sm.links.size());
    bool ok = true;
    for (std::int64_t s : sm.chain) {
      const auto it = session_of.find(s);
      if (it == session_of.end()) {  // a session without keyframes (above)
        ok = false;
        break;
      }
      st.chain.push_back(it->second);
      motions += backend->session(it->second).keyframes - 1;
    }
    if (!ok) continue;
    for (const StoredLink& l : sm.links) {
      MapLinkState ls{l.measured, {}};
      for (std::int64_t id : l.loops)
        if (loop_of.count(id)) ls.loops.push_back(loop_of[id]);
      st.links.push_back(ls);
    }
    st.motions = sm.motions;
    st.pending = sm.pending;
    // The optimised motions are derived data (odometry + links + loops): damaged ones (a bad
    // page, a NaN written by an older build) are rebuilt rather than turning every pose NaN.
    for (std::size_t k = 0; k < st.motions.size(); ++k) {
      const std::string bad = checkUncertainPose(st.motions[k]);
      if (bad.empty()) continue;
      out.notes.push_back("session store " + store.path() + ": map of session " + std::to_string(sm.chain.front()) +
                          ": stored motion " + std::to_string(k) + " is damaged (" + bad +
                          "): the map's motions are rebuilt from its sessions' odometry and links and optimised again "
                          "(offline_slam --db on the store saves it repaired)");
      st.motions.clear();
      st.pending = std::max(st.pending, 1);
      break;
    }
    if (!st.motions.empty() && static_cast<int>(st.motions.size()) != motions) {
      // The last session grew after the map was saved (a crash): extend with its odometry and
      // optimise again at the next flush.
      const int missing = motions - static_cast<int>(st.motions.size());
      const std::vector<UncertainPose2> odo = store.odometry(out.session_ids[st.chain.back()]);
      if (missing > 0 && missing <= static_cast<int>(odo.size())) {
        st.motions.insert(st.motions.end(), odo.end() - missing, odo.end());
      } else {
        st.motions.clear();
      }
      st.pending = std::max(st.pending, 1);
    }
    const BackendStatus status = backend->restoreMap(st);
    if (!status.ok()) throw StoreError("session store " + store.path() + ": " + status.message);
    for (const StoredPrior& p : sm.priors) {
      const auto it = session_of.find(p.session);
      const BackendStatus kept =
          it == session_of.end()
              ? BackendStatus{StatusCode::kNotFound, "no session " + std::to_string(p.session)}
              : backend->restorePositionPrior({it->second, p.keyframe, p.position, p.covariance, p.applied});
      if (!kept.ok())
        out.notes.push_back("session store " + store.path() + ": a position prior on keyframe " +
                            std::to_string(p.keyframe) + " of session " + std::to_string(p.session) +
                            " is left out: " + kept.message);
    }
    for (int s : st.chain) in_map[s] = true;
  }
  // Sessions whose map was never saved (a crash in their first mission): their loops are pending.
  for (int s = 0; s < backend->numSessions(); ++s) {
    if (in_map[s]) continue;
    int pending = 0;
    for (int id = 0; id < backend->numLoops(); ++id) {
      const LoopRecord r = backend->loopRecord(id);
      if (r.loop.session_a == s && r.loop.session_b == s && !r.summarised && !r.refused && !r.applied) ++pending;
    }
    if (pending > 0) backend->restoreMap({{s}, {}, {}, pending});
  }
  for (const auto& [a, b] : store.splitPairs()) {
    const auto ia = session_of.find(a), ib = session_of.find(b);
    if (ia != session_of.end() && ib != session_of.end()) backend->restoreSplitPair(ia->second, ib->second);
  }
  return out;
}

void saveBackendMaps(SessionStore* store, const MultiSessionBackend& backend,
                     const std::vector<std::int64_t>& session_ids, const std::vector<std::int64_t>& loop_ids) {
  auto sid = [&](int s) {
    if (s < 0 || s >= static_cast<int>(session_ids.size()))
      throw std::invalid_argument("saveBackendMaps: session " + std::to_string(s) + " has no store id");
    return session_ids[s];
  };
  std::vector<StoredMap> maps;
  for (int id : backend.mapIds()) {
    const MapState st = backend.mapState(id);
    // A session without a store id has no keyframe yet (nothing of it is stored): its map, which
    // holds it alone (no loop can reach it), is left out.
    if (std::any_of(st.chain.begin(), st.chain.end(), [&](int s) { return sid(s) < 0; })) continue;
    StoredMap m;
    for (int s : st.chain) m.chain.push_back(sid(s));
    for (const MapLinkState& l : st.links) {
      StoredLink sl{l.measured, {}};
      for (int lid : l.loops)
        if (lid < static_cast<int>(loop_ids.size())) sl.loops.push_back(loop_ids[lid]);
      m.links.push_back(sl);
    }
    m.motions = st.motions;
    m.pending = st.pending;
    for (const PriorRecord& p : backend.priors())
      if (backend.mapOf(p.session) == id)
        m.priors.push_back({sid(p.session), p.keyframe, p.position, p.covariance, p.applied});
    maps.push_back(std::move(m));
  }
  std::vector<StoredLoop> states;
  for (int id = 0; id < backend.numLoops() && id < static_cast<int>(loop_ids.size()); ++id) {
    const LoopRecord r = backend.loopRecord(id);
    StoredLoop l;
    l.id = loop_ids[id];
    l.summarised = r.summarised;
    l.applied = r.applied;
    l.refused = r.refused;
    states.push_back(l);
  }
  std::vector<std::pair<std::int64_t, std::int64_t>> pairs;
  for (const auto& [a, b] : backend.splitPairs())
    if (sid(a) >= 0 && sid(b) >= 0) pairs.emplace_back(sid(a), sid(b));
  store->saveMaps(maps, states, pairs);
}

}  // namespace core
}  // namespace uw_multislam
