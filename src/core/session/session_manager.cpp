// The session manager: construction and restore, sessions, maps (joins, splits, optimisation)
// and the audit trail. Keyframes and loops: session_keyframes.cpp; stored sessions:
// session_stored.cpp; other vehicles' sessions: session_fleet.cpp; queries: session_queries.cpp.
#include "uw_multislam/core/session/session_manager.h"

#include <filesystem>
#include <stdexcept>
#include <utility>

#include "session_detail.h"
#include "uw_multislam/core/store/interrupted_run.h"
#include "uw_multislam/core/store/map_persistence.h"

namespace uw_multislam {
namespace core {

using namespace session_detail;  // NOLINT: the manager's own helpers

std::string SessionManagerOptions::validate() const {
  const std::string b = backend.validate();
  if (!b.empty()) return b;
  if (num_features < 1) return "num_features must be >= 1";
  if (max_keyframe_gap < 0) return "max_keyframe_gap must be >= 0";
  if (max_empty_sessions < 0) return "max_empty_sessions must be >= 0 (0: no limit)";
  if (!(store_max_mb >= 0.0) || store_max_mb > 1e9) return "store_max_mb must be in [0, 1e9] (0: no cap)";
  if (requester != "tool" && requester != "service") return "requester must be tool or service";
  return "";
}

SessionManagerOptions sessionManagerOptions(const SlamConfig& config, const std::string& store_path) {
  SessionManagerOptions o;
  o.backend = config.backend;
  o.hash_mode = config.loops.global.hash_mode;
  o.projection_seed = config.loops.global.projection_seed;
  o.num_features = config.odometry.features.num_features;
  o.features = config.odometry.features.type;
  o.store_path = store_path;
  return o;
}

const char* sessionEventName(SessionEvent::Kind k) {
  using K = SessionEvent::Kind;
  switch (k) {
    case K::kSessionStarted:
      return "session_started";
    case K::kSessionEnded:
      return "session_ended";
    case K::kKeyframeAdded:
      return "keyframe_added";
    case K::kLoopAccepted:
      return "loop_accepted";
    case K::kLoopRefused:
      return "loop_refused";
    case K::kMapsJoined:
      return "maps_joined";
    case K::kMapSplit:
      return "map_split";
    case K::kMapOptimised:
      return "map_optimised";
  }
  return "?";
}

SessionManager::SessionManager(const SessionManagerOptions& options, EventSink events, Log log)
    : SessionQueries(options, std::move(events), std::move(log)) {
  if (options_.store_path.empty()) return;
  const std::filesystem::path dir = std::filesystem::path(options_.store_path).parent_path();
  std::error_code ec;
  if (!dir.empty() && !std::filesystem::exists(dir, ec)) {  // a failure shows in the open below
    std::filesystem::create_directories(dir, ec);
    std::filesystem::permissions(dir, std::filesystem::perms::owner_all, ec);  // 0700: the owner's missions only
  }
  store_ = std::make_unique<SessionStore>(options_.store_path);
  if (options_.store_max_mb > 0.0) store_->setMaxBytes(static_cast<std::uint64_t>(options_.store_max_mb * 1048576.0));
  store_->checkHashSettings(hashSettings());
  restore();
}

SessionManager::~SessionManager() {
  try {
    fleet_.finishAll();
  } catch (const std::exception& e) {  // never out of a destructor: the store keeps what was written
    say(std::string("other vehicles' sessions not finished at shutdown: ") + e.what());
  }
}

void SessionManager::restore() {
  const RestoredStore r = restoreStore(*store_, backend_.get(), nullptr, nullptr);
  for (const std::string& note : r.notes) say(note);
  const std::vector<StoredSession> stored = store_->sessions();
  for (std::size_t b = 0; b < r.session_ids.size(); ++b) {
    // A session's id is its store id, for life: the same after every restart, in every service
    // answer, export file name and export_survey, and no id ever names two sessions.
    if (r.session_ids[b] < 0 || r.session_ids[b] > kMaxSessionId)
      throw StoreError("session store " + options_.store_path + ": a session with store id " +
                       std::to_string(r.session_ids[b]) + ", outside [0, " + std::to_string(kMaxSessionId) +
                       "]: session ids are store ids, so it cannot be used");
    const int id = static_cast<int>(r.session_ids[b]);
    Session s;
    s.backend = static_cast<int>(b);
    s.store_id = r.session_ids[b];
    s.name = backend_->session(s.backend).name;
    for (const StoredSession& st : stored)
      if (st.id == s.store_id) s.camera = st.camera;
    for (const StoredKeyframe& k : store_->keyframes(s.store_id, false)) {
      s.stamps.push_back(k.stamp_s);
      s.frames.push_back(k.frame_index);
    }
    s.odometry.push_back(Pose2());
    for (const UncertainPose2& m : store_->odometry(s.store_id))
      s.odometry.push_back(compose(s.odometry.back(), m.mean));
    s.sources.push_back(MotionSource::kVisual);
    for (const MotionSource m : store_->motionSources(s.store_id)) s.sources.push_back(m);
    s.origin_received = true;
    s.unloaded = true;
    s.stored = static_cast<int>(s.stamps.size());
    sessions_.emplace(id, std::move(s));
    id_of_backend_.push_back(id);
  }
  // Other vehicles' sessions (hash exchange) keep their vehicle and id there: list_sessions says
  // whose they are, and the host can still ask that vehicle for their features.
  for (const SessionProvenance& p : store_->provenance()) {
    if (p.source_file.rfind("fleet:", 0) != 0) continue;
    for (auto& [id, s] : sessions_)
      if (s.store_id == p.session && validVehicleName(p.vehicle)) {
        s.vehicle = p.vehicle;
        s.remote_id = static_cast<int>(p.source_session);
      }
  }
  store_loops_ = r.loop_ids;
  for (std::size_t i = 0; i < r.loops.size(); ++i) {
    const BackendLoop bl = backend_->loopRecord(static_cast<int>(i)).loop;
    Loop l;
    l.kind = r.loops[i].global ? Loop::Kind::kGlobal : Loop::Kind::kLocal;
    l.session_a = idOfBackend(bl.session_a);
    l.keyframe_a = bl.keyframe_a;
    l.frame_a = at(l.session_a).frames.at(bl.keyframe_a);
    l.session_b = idOfBackend(bl.session_b);
    l.keyframe_b = bl.keyframe_b;
    l.frame_b = at(l.session_b).frames.at(bl.keyframe_b);
    l.z = bl.z;
    l.inliers = r.loops[i].inliers;
    l.nav_placement = r.loops[i].nav_placement;
    loops_.push_back(l);
    ++at(l.session_a).loops;
    if (l.session_b != l.session_a) ++at(l.session_b).loops;
  }
  restored_sessions_ = static_cast<int>(sessions_.size());
  // This run's sessions take their ids past every id the store holds or held. The id is the
  // store id its row gets when the session is first written (addStoreRow), not reserved by an
  // empty row at once: the store is held by this process alone (its lock), so no other writer
  // can take the id meanwhile, and a session that never gets a keyframe leaves no row behind.
  // nextSessionId() also counts deleted sessions, so an id is never given twice.
  const std::int64_t next = store_->nextSessionId();
  next_id_floor_ = static_cast<int>(std::min<std::int64_t>(next, kMaxSessionId + 1));
  first_new_id_ = nextId();
  history_ = store_->history();
  history_restored_ = static_cast<std::ptrdiff_t>(history_.size());
  backend_->takeMapChanges();  // restoring is no join
  seen_joins_ = backend_->stats().joins;
  seen_splits_ = backend_->stats().splits;
  seen_optimisations_ = backend_->stats().optimisations;
  say("session store " + options_.store_path + ": " + std::to_string(sessions_.size()) + " stored sessions (" +
      std::to_string(r.keyframes) + " keyframes, " + std::to_string(loops_.size()) + " loops, " +
      std::to_string(backend_->mapIds().size()) + " maps) listed UNLOADED");
  // Which ones, so that an operator sees at start-up what an earlier run left (at most 20 named).
  std::string which;
  int named = 0;
  for (const auto& [id, s] : sessions_) {
    if (named++ == 20) {
      which += ", ... (list_sessions shows all)";
      break;
    }
    which += (which.empty() ? "" : ", ") + std::to_string(id) + " '" + s.name + "' (" +
             std::to_string(s.stamps.size()) + " keyframes, map " + std::to_string(mapOf(id)) + ")";
  }
  if (!which.empty()) say("restored sessions: " + which);
}

Status SessionManager::open(int id, const std::string& name, double stamp_s, const std::string& vehicle,
                            int remote_id) {
  const bool foreign = !vehicle.empty();
  if (!foreign && active_ >= 0) endSession(at(active_).stamps.back());
  Session s;
  s.vehicle = vehicle;
  s.remote_id = remote_id;
  s.name = name.empty() ? defaultSessionName(id) : name;
  s.backend = backend_->startSession(s.name);
  if (s.backend != static_cast<int>(id_of_backend_.size()))
    throw std::logic_error("session manager: back-end ids drifted");
  id_of_backend_.push_back(id);
  s.stamps.push_back(stamp_s);
  s.odometry.push_back(Pose2());
  s.frames.push_back(0);
  s.sources.push_back(MotionSource::kVisual);
  const std::string n = s.name;
  sessions_.emplace(id, std::move(s));
  if (foreign) {
    foreign_ids_[{vehicle, remote_id}] = id;
  } else {
    active_ = id;
  }
  emit(SessionEvent::Kind::kSessionStarted, id, -1, id,
       "session " + std::to_string(id) + " '" + n + "' started" +
           (foreign ? " (vehicle " + vehicle + "'s session " + std::to_string(remote_id) + ")" : ""));
  return Status::Ok();
}

Status SessionManager::startSession(const std::string& name, double stamp_s, int id, int* started) {
  if (name.size() > kMaxSessionNameLength)
    return {StatusCode::kInvalidArgument, "a session name of " + std::to_string(name.size()) + " bytes: at most " +
                                              std::to_string(kMaxSessionNameLength)};
  const int other = name.empty() ? -1 : idOfName(name);
  if (other >= 0)
    return {StatusCode::kAlreadyExists,
            "a session is already named '" + name + "' (session " + std::to_string(other) + ")"};
  const int empty = trailingEmptySessions();
  if (options_.max_empty_sessions > 0 && empty >= options_.max_empty_sessions)
    return {StatusCode::kResourceExhausted,
            "session " + std::to_string(sessions_.rbegin()->first) + " '" + sessions_.rbegin()->second.name +
                "' has no keyframe yet (" + std::to_string(empty) + " sessions in a row without one, " +
                "max_empty_sessions " + std::to_string(options_.max_empty_sessions) +
                "): the odometry's next keyframe starts it; call again once it has one"};
  if (id < 0 && nextId() > kMaxSessionId)
    return {StatusCode::kResourceExhausted,
            "no session id left: the largest, " + std::to_string(kMaxSessionId) + ", is taken"};
  if (id < 0) id = nextId();
  if (id > kMaxSessionId) return badSessionId("start_session", id);
  if (id < nextId())
    return {StatusCode::kInvalidArgument,
            "session id " + std::to_string(id) + " is not new (the next free id is " + std::to_string(nextId()) + ")"};
  open(id, name, stamp_s);
  if (started) *started = id;
  return Status::Ok();
}

Status SessionManager::endSession(double stamp_s) {
  if (active_ < 0) return {StatusCode::kFailedPrecondition, "no session is recording"};
  const int id = active_;
  Session& s = at(id);
  backend_->endSession(s.backend);
  active_ = -1;
  storeWrite("ending a session", [&] {
    if (s.store_id >= 0) store_->endSession(s.store_id, stamp_s);
  });
  emit(SessionEvent::Kind::kSessionEnded, id, -1, mapOf(id),
       "session " + std::to_string(id) + " ended with " + std::to_string(s.stamps.size()) + " keyframes");
  afterBackendChange();
  saveMaps();
  return Status::Ok();
}

Status SessionManager::setLocalisation(bool on) {
  if (on == localising_) return Status::Ok(on ? "already in localisation mode" : "already in mapping mode");
  // The mode change goes into the audit trail when mapping resumes: in localisation mode the
  // store is not written (a run that ends localising leaves it byte-identical).
  if (on) localising_since_ = utcTimestamp();
  localising_ = on;
  backend_->setAutomaticJoins(!on);
  if (!on) {
    int memory_only = 0;
    for (const auto& [id, x] : sessions_)
      if (x.memory_only) memory_only += static_cast<int>(x.stamps.size()) - x.stored;
    record("mode", "", "",
           "localisation mode from " + localising_since_ + " to " + utcTimestamp() + " (" +
               std::to_string(memory_only) + " keyframes kept in memory only), mapping again",
           options_.requester.c_str());
  }
  say(on ? "localisation mode: nothing is written to the store, no stored map changes, automatic joins wait"
         : "mapping mode: the store is written again (keyframes kept in memory only stay so)");
  return Status::Ok();
}

Status SessionManager::optimisePending(int* maps) {
  if (maps) *maps = 0;
  if (const Status mode = storedMapsMayChange("optimise"); !mode.ok()) return mode;
  if (!options_.backend.optimise)
    return {StatusCode::kFailedPrecondition, "optimisation is off (backend.optimise: false)"};
  const int n = backend_->optimisePending();
  if (maps) *maps = n;
  afterBackendChange();
  return Status::Ok(n == 0 ? "no map has loops waiting for optimisation"
                           : std::to_string(n) + (n == 1 ? " map" : " maps") + " optimised");
}

HistoryEntry SessionManager::nextEntry(const std::string& kind, const std::string& sessions, const std::string& loops,
                                       const std::string& message, const char* cause) const {
  return {history_.empty() ? 1 : history_.back().id + 1,
          utcTimestamp(),
          kind,
          cause ? cause : cause_,
          sessions,
          loops,
          message};
}

void SessionManager::record(const std::string& kind, const std::string& sessions, const std::string& loops,
                            const std::string& message, const char* cause) {
  HistoryEntry e = nextEntry(kind, sessions, loops, message, cause);
  storeWrite("writing the history", [&] { store_->addHistory(e); });
  history_.push_back(std::move(e));
}

void SessionManager::recordMapChanges() {
  for (const MapChange& c : backend_->takeMapChanges()) {
    const std::string first = chainText(c.first), second = chainText(c.second);
    if (c.join) {
      record("join", first + "+" + second, loopsText(c.loops),
             "map " + std::to_string(idOfBackend(c.second.front())) + " (sessions " + second + ") joined to map " +
                 std::to_string(idOfBackend(c.first.front())) + " (sessions " + first + ") from " +
                 std::to_string(c.loops.size()) + " loops" +
                 (c.refused > 0 ? ", " + std::to_string(c.refused) + " inconsistent loops refused" : ""));
      continue;
    }
    // Undoing the last join is a split, and says so: the last change of the maps was a join of
    // exactly this session and the rest.
    // Only among this run's entries: stores written before session ids were store ids numbered
    // the stored sessions 0..k-1 at each restart, so an earlier run's entries may name others.
    std::string undo;
    for (auto it = history_.rbegin(); it != history_.rend() - history_restored_; ++it) {
      if (it->kind == "delete") break;  // the ids after a deleted one could be taken for others
      if (it->kind != "join" && it->kind != "split") continue;
      if (it->kind == "join" && (it->sessions == first + "+" + second || it->sessions == second + "+" + first))
        undo = " (undoes join #" + std::to_string(it->id) + ")";
      break;
    }
    record("split", first + "+" + second, loopsText(c.loops),
           "session " + first + " split off map " + std::to_string(idOfBackend(c.second.front())) + " (sessions " +
               second + "), " + std::to_string(c.loops.size()) + " loops between them kept for a later join" + undo);
  }
}

void SessionManager::afterBackendChange() {
  if (!hold_changes_) recordMapChanges();
  const BackendStats& st = backend_->stats();
  const bool joined = st.joins != seen_joins_, split = st.splits != seen_splits_;
  if (joined) emit(SessionEvent::Kind::kMapsJoined, -1, -1, -1, "maps joined");
  if (split) emit(SessionEvent::Kind::kMapSplit, -1, -1, -1, "map split");
  if (st.optimisations != seen_optimisations_) emit(SessionEvent::Kind::kMapOptimised, -1, -1, -1, "");
  seen_joins_ = st.joins;
  seen_splits_ = st.splits;
  seen_optimisations_ = st.optimisations;
  if (joined || split) saveMaps();
}

void SessionManager::saveMaps() {
  storeWrite("saving the maps", [&] {
    std::vector<std::int64_t> ids(id_of_backend_.size(), -1);
    for (std::size_t b = 0; b < ids.size(); ++b) ids[b] = at(id_of_backend_[b]).store_id;
    // A session whose store row could not be written (a failed write) gets it now: every
    // session of every map must have one, or the maps could not be saved at all.
    for (std::size_t b = 0; b < ids.size(); ++b) {
      if (ids[b] >= 0) continue;
      Session& s = at(id_of_backend_[b]);
      addStoreRow(s, s.stamps.front());
      ids[b] = s.store_id;
    }
    saveBackendMaps(store_.get(), *backend_, ids, store_loops_);
  });
}

Status SessionManager::join(int session_a, int session_b, int min_loops) {
  for (int s : {session_a, session_b}) {
    if (!validSessionId(s)) return badSessionId("join_sessions", s);
    if (!has(s)) return notFound(s);
  }
  if (min_loops < 0) return {StatusCode::kInvalidArgument, "min_loops must be >= 0 (0: the configured rule)"};
  if (const Status mode = storedMapsMayChange("join_sessions"); !mode.ok()) return mode;
  const Status st = backend_->join(at(session_a).backend, at(session_b).backend, min_loops);
  if (st.ok()) {
    say("join_sessions " + std::to_string(session_a) + " " + std::to_string(session_b) + ": " + st.message);
    cause_ = options_.requester.c_str();
    afterBackendChange();
    cause_ = "automatic";
  }
  return st;
}

Status SessionManager::split(int session) {
  if (!validSessionId(session)) return badSessionId("split_session", session);
  if (!has(session)) return notFound(session);
  if (const Status mode = storedMapsMayChange("split_session"); !mode.ok()) return mode;
  const Status st = backend_->split(at(session).backend);
  if (st.ok()) {
    say("split_session " + std::to_string(session) + ": " + st.message);
    cause_ = options_.requester.c_str();
    afterBackendChange();
    cause_ = "automatic";
  }
  return st;
}

void SessionManager::flush() {
  backend_->flush();
  afterBackendChange();
  saveMaps();
}

std::optional<MapOptimisation> SessionManager::nextOptimisation() const {
  const std::vector<int> due = backend_->dueMaps();
  if (due.empty()) return std::nullopt;
  return MapOptimisation{idOfBackend(due.front()), backend_->prepareOptimisation(due.front())};
}

bool SessionManager::applyOptimisation(const MapOptimisation& o) {
  if (!backend_->applyOptimisation(o.job)) {
    say("map " + std::to_string(o.map) + " changed while it was optimised: the result is dropped, optimised again");
    return false;
  }
  afterBackendChange();
  bool recording = false;
  for (int s : backend_->chain(o.job.map)) recording = recording || backend_->session(s).recording;
  if (!recording) saveMaps();  // a finished map's optimisation is not lost with the next crash
  return true;
}

}  // namespace core
}  // namespace uw_multislam
