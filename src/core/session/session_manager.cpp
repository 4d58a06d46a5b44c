// The session manager: construction and restore, sessions, maps (joins, splits, optimisation)
// and the audit trail. Keyframes and loops: session_keyframes.cpp; stored sessions:
// session_stored.cpp; other vehicles' sessions: session_fleet.cpp; its state and the id maps'
// invariants: session_table.cpp; queries: session_queries.cpp.
#include "uw_multislam/core/session/session_manager.h"

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
    : events_(std::move(events)), log_(std::move(log)), table_(options, [this](const std::string& l) { say(l); }) {
  if (options.store_path.empty()) return;
  for (const std::string& note : table_.openStore()) say(note);
  const BackendStats& st = table_.backend().stats();
  seen_joins_ = st.joins;
  seen_splits_ = st.splits;
  seen_optimisations_ = st.optimisations;
  std::size_t keyframes = 0;
  for (const auto& [id, s] : table_.sessions()) keyframes += s.stamps.size();
  say("session store " + options.store_path + ": " + std::to_string(table_.sessions().size()) + " stored sessions (" +
      std::to_string(keyframes) + " keyframes, " + std::to_string(table_.loops().size()) + " loops, " +
      std::to_string(table_.backend().mapIds().size()) + " maps) listed UNLOADED");
  // Which ones, so that an operator sees at start-up what an earlier run left (at most 20 named).
  std::string which;
  int named = 0;
  for (const auto& [id, s] : table_.sessions()) {
    if (named++ == 20) {
      which += ", ... (list_sessions shows all)";
      break;
    }
    which += (which.empty() ? "" : ", ") + std::to_string(id) + " '" + s.name() + "' (" +
             std::to_string(s.stamps.size()) + " keyframes, map " + std::to_string(view_.mapOf(id)) + ")";
  }
  if (!which.empty()) say("restored sessions: " + which);
}

SessionManager::~SessionManager() {
  try {
    fleet_.finishAll();
  } catch (const std::exception& e) {  // never out of a destructor: the store keeps what was written
    say(std::string("other vehicles' sessions not finished at shutdown: ") + e.what());
  }
}

void SessionManager::say(const std::string& line) const {
  if (log_) log_(line);
}

void SessionManager::emit(SessionEvent::Kind kind, int session, int other, int map, const std::string& message) const {
  if (!events_) return;
  const bool known = table_.has(session);
  events_({kind, session, other, map, message, known ? table_.at(session).vehicle() : std::string()});
}

Status SessionManager::open(int id, const std::string& name, double stamp_s, const std::string& vehicle,
                            int remote_id) {
  const bool foreign = !vehicle.empty();
  if (!foreign && table_.active() >= 0) endSession(table_.at(table_.active()).stamps.back());
  const std::string n = table_.open(id, name, stamp_s, vehicle, remote_id).name();
  emit(SessionEvent::Kind::kSessionStarted, id, -1, id,
       "session " + std::to_string(id) + " '" + n + "' started" +
           (foreign ? " (vehicle " + vehicle + "'s session " + std::to_string(remote_id) + ")" : ""));
  return Status::Ok();
}

Status SessionManager::startSession(const std::string& name, double stamp_s, int id, int* started) {
  if (name.size() > kMaxSessionNameLength)
    return {StatusCode::kInvalidArgument, "a session name of " + std::to_string(name.size()) + " bytes: at most " +
                                              std::to_string(kMaxSessionNameLength)};
  if (nameIsAnId(name))
    return {StatusCode::kInvalidArgument, "a session name made only of digits ('" + name + "') would read as session " +
                                              name + "'s id wherever a name or an id is taken: add a letter"};
  const int other = name.empty() ? -1 : table_.idOfName(name);
  if (other >= 0)
    return {StatusCode::kAlreadyExists,
            "a session is already named '" + name + "' (session " + std::to_string(other) + ")"};
  const int empty = table_.trailingEmptySessions();
  const int max_empty = table_.options().max_empty_sessions;
  if (max_empty > 0 && empty >= max_empty) {
    const auto& [newest, s] = *table_.sessions().rbegin();
    return {StatusCode::kResourceExhausted,
            "session " + std::to_string(newest) + " '" + s.name() + "' has no keyframe yet (" + std::to_string(empty) +
                " sessions in a row without one, " + "max_empty_sessions " + std::to_string(max_empty) +
                "): the odometry's next keyframe starts it; call again once it has one"};
  }
  const int next = table_.nextId();
  if (id < 0 && next > kMaxSessionId)
    return {StatusCode::kResourceExhausted,
            "no session id left: the largest, " + std::to_string(kMaxSessionId) + ", is taken"};
  if (id < 0) id = next;
  if (id > kMaxSessionId) return badSessionId("start_session", id);
  if (id < next)
    return {StatusCode::kInvalidArgument,
            "session id " + std::to_string(id) + " is not new (the next free id is " + std::to_string(next) + ")"};
  open(id, name, stamp_s);
  if (started) *started = id;
  return Status::Ok();
}

Status SessionManager::endSession(double stamp_s) {
  const int id = table_.active();
  if (id < 0) return {StatusCode::kFailedPrecondition, "no session is recording"};
  table_.endActive();
  const Session& s = table_.at(id);
  storeWrite("ending a session", [&] {
    if (s.storeRow() >= 0) table_.store()->endSession(s.storeRow(), stamp_s);
  });
  emit(SessionEvent::Kind::kSessionEnded, id, -1, view_.mapOf(id),
       "session " + std::to_string(id) + " ended with " + std::to_string(s.keyframes()) + " keyframes");
  afterBackendChange();
  saveMaps();
  return Status::Ok();
}

Status SessionManager::setLocalisation(bool on) {
  if (on == table_.localising()) return Status::Ok(on ? "already in localisation mode" : "already in mapping mode");
  // The mode change goes into the audit trail when mapping resumes: in localisation mode the
  // store is not written (a run that ends localising leaves it byte-identical).
  table_.setLocalising(on, on ? utcTimestamp() : std::string());
  table_.backend().setAutomaticJoins(!on);
  if (!on) {
    int memory_only = 0;
    for (const auto& [id, x] : table_.sessions())
      if (x.memory_only) memory_only += static_cast<int>(x.stamps.size()) - x.stored;
    record("mode", "", "",
           "localisation mode from " + table_.localisingSince() + " to " + utcTimestamp() + " (" +
               std::to_string(memory_only) + " keyframes kept in memory only), mapping again",
           table_.options().requester.c_str());
  }
  say(on ? "localisation mode: nothing is written to the store, no stored map changes, automatic joins wait"
         : "mapping mode: the store is written again (keyframes kept in memory only stay so)");
  return Status::Ok();
}

Status SessionManager::addPositionPrior(int session, int keyframe, const Eigen::Vector2d& position,
                                        const Eigen::Matrix2d& covariance) {
  if (!view_.has(session) || !view_.hasKeyframe(session))
    return {StatusCode::kNotFound, "position prior: no session " + std::to_string(session) + " with keyframes"};
  const Session& s = table_.at(session);
  if (keyframe < 0 || keyframe >= s.keyframes() || s.phantoms.count(keyframe) > 0)
    return {StatusCode::kNotFound,
            "position prior: session " + std::to_string(session) + " has no keyframe " + std::to_string(keyframe)};
  Status st = table_.backend().addPositionPrior(s.backend(), keyframe, position, covariance);
  if (st.code == StatusCode::kInvalidArgument && st.message.find("no keyframe") != std::string::npos)
    st.code = StatusCode::kNotFound;
  if (!st.ok()) return st;
  storePositionPrior(session, keyframe, position, covariance);
  afterBackendChange();
  return st;
}

void SessionManager::storePositionPrior(int session, int keyframe, const Eigen::Vector2d& position,
                                        const Eigen::Matrix2d& covariance) {
  // Written when accepted, as a loop is (saveMaps comes only with a join, a split or an end: a
  // crash before it lost every fix since), by the rules addLoopIn writes a loop by.
  if (!table_.store() || table_.localising()) return;
  const Session& s = table_.at(session);
  if (!table_.keyframeStored(session, keyframe)) {
    if (!s.memory_only) ++table_.stats().store_failures;  // on a keyframe the store lacks (a failed write)
    return;
  }
  // Its map's frame is that of the map's first session (where addPositionPrior put it).
  const int first = table_.idOfBackend(table_.backend().mapOf(s.backend()));
  const std::int64_t map_row = table_.at(first).storeRow();
  if (map_row < 0) {
    ++table_.stats().store_failures;
    return;
  }
  storeWrite("writing a position prior", [&] {
    table_.store()->addPositionPrior(map_row, {s.storeRow(), keyframe, position, covariance, false});
  });
}

Status SessionManager::storeDatum(const std::string& text) {
  if (!table_.store()) return {StatusCode::kFailedPrecondition, "no session store (~store_path is empty)"};
  if (table_.localising())
    return {StatusCode::kFailedPrecondition, "localisation mode writes nothing to the session store"};
  try {
    table_.store()->setDatum(text);
  } catch (const StoreError& e) {
    ++table_.stats().store_failures;
    return {StatusCode::kDataLoss, std::string("the session store could not keep it: ") + e.what()};
  }
  return Status::Ok();
}

Status SessionManager::optimisePending(int* maps) {
  if (maps) *maps = 0;
  if (const Status mode = view_.storedMapsMayChange("optimise"); !mode.ok()) return mode;
  if (!table_.options().backend.optimise)
    return {StatusCode::kFailedPrecondition, "optimisation is off (backend.optimise: false)"};
  const int n = table_.backend().optimisePending();
  if (maps) *maps = n;
  afterBackendChange();
  return Status::Ok(n == 0 ? "no map has loops waiting for optimisation"
                           : std::to_string(n) + (n == 1 ? " map" : " maps") + " optimised");
}

HistoryEntry SessionManager::nextEntry(const std::string& kind, const std::string& sessions, const std::string& loops,
                                       const std::string& message, const char* cause) const {
  return {table_.history().empty() ? 1 : table_.history().back().id + 1,
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
  storeWrite("writing the history", [&] { table_.store()->addHistory(e); });
  table_.appendHistory(std::move(e));
}

void SessionManager::recordMapChanges() {
  for (const MapChange& c : table_.backend().takeMapChanges()) {
    const std::string first = chainText(c.first), second = chainText(c.second);
    if (c.join) {
      record("join", first + "+" + second, loopsText(c.loops),
             "map " + std::to_string(table_.idOfBackend(c.second.front())) + " (sessions " + second +
                 ") joined to map " + std::to_string(table_.idOfBackend(c.first.front())) + " (sessions " + first +
                 ") from " + std::to_string(c.loops.size()) + " loops" +
                 (c.refused > 0 ? ", " + std::to_string(c.refused) + " inconsistent loops refused" : ""));
      continue;
    }
    // Undoing the last join is a split, and says so: the last change of the maps was a join of
    // exactly this session and the rest.
    // Only among this run's entries: stores written before session ids were store ids numbered
    // the stored sessions 0..k-1 at each restart, so an earlier run's entries may name others.
    std::string undo;
    const std::vector<HistoryEntry>& history = table_.history();
    for (auto it = history.rbegin(); it != history.rend() - table_.historyRestored(); ++it) {
      if (it->kind == "delete") break;  // the ids after a deleted one could be taken for others
      if (it->kind != "join" && it->kind != "split") continue;
      if (it->kind == "join" && (it->sessions == first + "+" + second || it->sessions == second + "+" + first))
        undo = " (undoes join #" + std::to_string(it->id) + ")";
      break;
    }
    record("split", first + "+" + second, loopsText(c.loops),
           "session " + first + " split off map " + std::to_string(table_.idOfBackend(c.second.front())) +
               " (sessions " + second + "), " + std::to_string(c.loops.size()) +
               " loops between them kept for a later join" + undo);
  }
}

void SessionManager::afterBackendChange() {
  if (!hold_changes_) recordMapChanges();
  const BackendStats& st = table_.backend().stats();
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
    const int n = table_.backend().numSessions();
    std::vector<std::int64_t> ids(static_cast<std::size_t>(n), -1);
    for (int b = 0; b < n; ++b) {
      const int id = table_.idOfBackend(b);
      // A session whose store row could not be written (a failed write) gets it now: every
      // session of every map must have one, or the maps could not be saved at all. One without a
      // keyframe (start_session, nothing since) has nothing to store: no row, and its map (it
      // alone) is left out.
      const Session& s = table_.at(id);
      if (s.storeRow() < 0 && s.origin_received) addStoreRow(id, s.stamps.front());
      ids[static_cast<std::size_t>(b)] = table_.at(id).storeRow();
    }
    saveBackendMaps(table_.store(), table_.backend(), ids, table_.loopStoreRows());
  });
}

std::string SessionManager::chainText(const std::vector<int>& backend_sessions) const {
  std::string t;
  for (int b : backend_sessions) t += (t.empty() ? "" : ",") + std::to_string(table_.idOfBackend(b));
  return t;
}

std::string SessionManager::loopsText(const std::vector<int>& backend_loops) const {
  std::string t;
  for (int i : backend_loops)  // loops()[i] is the back-end's loop i
    t += (t.empty() ? "" : " ") + loopText(table_.loops().at(static_cast<std::size_t>(i)));
  return t;
}

Status SessionManager::join(int session_a, int session_b, int min_loops) {
  for (int s : {session_a, session_b}) {
    if (!validSessionId(s)) return badSessionId("join_sessions", s);
    if (!table_.has(s)) return notFound(s);
  }
  if (min_loops < 0) return {StatusCode::kInvalidArgument, "min_loops must be >= 0 (0: the configured rule)"};
  if (const Status mode = view_.storedMapsMayChange("join_sessions"); !mode.ok()) return mode;
  const Status st = table_.backend().join(table_.at(session_a).backend(), table_.at(session_b).backend(), min_loops);
  if (st.ok()) {
    say("join_sessions " + std::to_string(session_a) + " " + std::to_string(session_b) + ": " + st.message);
    cause_ = table_.options().requester.c_str();
    afterBackendChange();
    cause_ = "automatic";
  }
  return st;
}

Status SessionManager::split(int session) {
  if (!validSessionId(session)) return badSessionId("split_session", session);
  if (!table_.has(session)) return notFound(session);
  if (const Status mode = view_.storedMapsMayChange("split_session"); !mode.ok()) return mode;
  const Status st = table_.backend().split(table_.at(session).backend());
  if (st.ok()) {
    say("split_session " + std::to_string(session) + ": " + st.message);
    cause_ = table_.options().requester.c_str();
    afterBackendChange();
    cause_ = "automatic";
  }
  return st;
}

void SessionManager::flush() {
  table_.backend().flush();
  afterBackendChange();
  saveMaps();
}

std::optional<MapOptimisation> SessionManager::nextOptimisation() const {
  const std::vector<int> due = table_.backend().dueMaps();
  if (due.empty()) return std::nullopt;
  return MapOptimisation{table_.idOfBackend(due.front()), table_.backend().prepareOptimisation(due.front())};
}

bool SessionManager::applyOptimisation(const MapOptimisation& o) {
  if (!table_.backend().applyOptimisation(o.job)) {
    say("map " + std::to_string(o.map) + " changed while it was optimised: the result is dropped, optimised again");
    return false;
  }
  afterBackendChange();
  bool recording = false;
  for (int s : table_.backend().chain(o.job.map)) recording = recording || table_.backend().session(s).recording;
  if (!recording) saveMaps();  // a finished map's optimisation is not lost with the next crash
  return true;
}

}  // namespace core
}  // namespace uw_multislam
