#include "uw_multislam/core/session/session_manager.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <stdexcept>

#include "uw_multislam/core/session/interrupted_run.h"
#include "uw_multislam/core/session/map_persistence.h"

namespace uw_multislam {
namespace core {

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

const char* sessionStateName(SessionState s) {
  switch (s) {
    case SessionState::kActive:
      return "ACTIVE";
    case SessionState::kFinished:
      return "FINISHED";
    case SessionState::kUnloaded:
      return "UNLOADED";
  }
  return "?";
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

namespace {

BackendOptions checked(const SessionManagerOptions& o) {
  const std::string bad = o.validate();
  if (!bad.empty()) throw std::invalid_argument("session manager: " + bad);
  return o.backend;
}

Status notFound(int session) {
  return {StatusCode::kNotFound, "no session " + std::to_string(session) + " (call list_sessions for the ids)"};
}

bool validSessionId(int id) { return id >= 0 && id <= kMaxSessionId; }

Status badSessionId(const std::string& what, int id) {
  return {StatusCode::kInvalidArgument, what + " names session " + std::to_string(id) + ", outside the ids [0, " +
                                            std::to_string(kMaxSessionId) + "]"};
}

// A loop as the audit trail names it: "a:ka>b:kb" in session ids.
std::string loopText(const Loop& l) {
  return std::to_string(l.session_a) + ":" + std::to_string(l.keyframe_a) + ">" + std::to_string(l.session_b) + ":" +
         std::to_string(l.keyframe_b);
}

}  // namespace

SessionManager::SessionManager(const SessionManagerOptions& options, EventSink events, Log log)
    : options_(options),
      events_(std::move(events)),
      log_(std::move(log)),
      hasher_(options.hash_mode, options.num_features, options.projection_seed),
      backend_(std::make_unique<MultiSessionBackend>(checked(options), [this](const std::string& l) { say(l); })) {
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
    finishForeignSessions();
  } catch (const std::exception& e) {  // never out of a destructor: the store keeps what was written
    say(std::string("other vehicles' sessions not finished at shutdown: ") + e.what());
  }
}

int SessionManager::finishForeignSessions() {
  std::vector<std::pair<std::string, int>> open;
  for (const auto& [key, id] : foreign_ids_) open.push_back(key);
  int ended = 0;
  for (const auto& [vehicle, remote] : open)
    ended += endForeignSession(vehicle, remote, at(foreignSession(vehicle, remote)).stamps.back()).ok() ? 1 : 0;
  return ended;
}

void SessionManager::restore() {
  const RestoredStore r = restoreStore(*store_, backend_.get(), nullptr, nullptr);
  for (const std::string& note : r.notes) say(note);
  const std::vector<StoredSession> stored = store_->sessions();
  for (std::size_t b = 0; b < r.session_ids.size(); ++b) {
    const int id = static_cast<int>(b);  // store order: ids 0..k-1
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
    loops_.push_back(l);
    ++at(l.session_a).loops;
    if (l.session_b != l.session_a) ++at(l.session_b).loops;
  }
  restored_sessions_ = static_cast<int>(sessions_.size());
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

const SessionManager::Session& SessionManager::at(int session) const {
  const auto it = sessions_.find(session);
  if (it == sessions_.end()) throw std::invalid_argument("session manager: no session " + std::to_string(session));
  return it->second;
}

SessionManager::Session& SessionManager::at(int session) {
  return const_cast<Session&>(static_cast<const SessionManager*>(this)->at(session));
}

void SessionManager::say(const std::string& line) const {
  if (log_) log_(line);
}

std::string SessionManager::storeName() const {
  return std::filesystem::path(options_.store_path).filename().string();
}

int SessionManager::trailingEmptySessions() const {
  int n = 0;
  for (auto it = sessions_.rbegin(); it != sessions_.rend() && !it->second.origin_received; ++it) ++n;
  return n;
}

void SessionManager::emit(SessionEvent::Kind kind, int session, int other, int map, const std::string& message) const {
  if (!events_) return;
  const auto s = sessions_.find(session);
  events_({kind, session, other, map, message, s == sessions_.end() ? std::string() : s->second.vehicle});
}

HashSettings SessionManager::hashSettings() const {
  return {options_.hash_mode, options_.projection_seed, options_.num_features, hasher_.projections().toText(),
          options_.features};
}

template <typename F>
bool SessionManager::storeWrite(const char* what, F write) {
  if (!store_ || localising_) return false;  // localisation mode: nothing written (not a failure)
  try {
    write();
    return true;
  } catch (const std::exception& e) {
    ++stats_.store_failures;
    say("session store " + options_.store_path + ": " + what + " failed (" + std::to_string(stats_.store_failures) +
        " failures so far; the map lives on in memory): " + e.what());
    return false;
  }
}

// --- Sessions ---------------------------------------------------------------------------------

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

// --- Keyframes --------------------------------------------------------------------------------

bool SessionManager::keyframeStored(int session, int keyframe, int pending_session, int pending_keyframe) const {
  if (session == pending_session && keyframe == pending_keyframe) return true;
  const auto it = sessions_.find(session);
  return it != sessions_.end() && keyframe >= 0 && keyframe < it->second.stored;
}

void SessionManager::addStoreRow(Session& s, double stamp_s) {
  s.store_id = store_->addSession(s.name, s.camera, stamp_s);
  if (!s.vehicle.empty()) {  // another vehicle's: where it came from, as merge_stores records it
    SessionProvenance p;
    p.session = s.store_id;
    p.source_file = "fleet:" + s.vehicle;
    p.source_session = s.remote_id;
    p.source_name = s.name;
    p.vehicle = s.vehicle;
    store_->addProvenance(p);
  }
}

void SessionManager::storeKeyframe(Session& s, const KeyframeInput* k, int keyframe, const UncertainPose2* motion,
                                   double stamp_s, const std::vector<Loop>* loops, std::vector<StoredLoop>* stored) {
  if (!store_) return;
  if (localising_ && !s.memory_only) {
    s.memory_only = true;
    say("localisation mode: session " + std::to_string(idOfBackend(s.backend)) + " '" + s.name + "': keyframes from " +
        std::to_string(keyframe) + " on are kept in memory only (" + std::to_string(s.stored) + " stored)");
  }
  if (s.memory_only) return;
  if (s.store_cut || keyframe != s.stored) {  // after a failed write: not stored, counted
    ++stats_.store_failures;
    return;
  }
  const bool ok = storeWrite("writing a keyframe", [&] {
    if (s.store_id < 0) {
      addStoreRow(s, stamp_s);  // the camera is known before a placeholder origin too
    } else if (keyframe == 0) {
      // A row made before the session's first keyframe (saveMaps after start_session) has no
      // camera yet (0x0): it gets the one the origin (or the placeholder origin) brought.
      store_->setSessionCamera(s.store_id, s.camera);
    }
    // The loops in store ids only now: a new session's row is made with its first keyframe, and
    // the loops that keyframe closed name it (they were stored with session -1 and lost at the
    // next restart when converted before the row existed).
    if (loops && stored) {
      stored->clear();
      for (const Loop& l : *loops) stored->push_back(toStored(l));
    }
    StoredKeyframe sk;
    sk.session = s.store_id;
    sk.keyframe = keyframe;
    sk.stamp_s = stamp_s;
    sk.hash = Eigen::VectorXf::Zero(HalocProjections::kHashSize);
    if (k) {  // else a keyframe that never arrived: no features
      sk.frame_index = k->frame_index;
      sk.altitude_m = k->altitude_m;
      sk.image_size =
          k->features.image_size.area() > 0 ? k->features.image_size : cv::Size(k->camera.width, k->camera.height);
      for (const cv::KeyPoint& p : k->features.keypoints) sk.points.push_back(p.pt);
      sk.descriptors = k->features.descriptors;
      if (k->hash.size() == HalocProjections::kHashSize) sk.hash = k->hash;
      sk.thumbnail = k->thumbnail;
      sk.motion_source = k->motion_source;
    }
    store_->addKeyframe(sk, motion, stored);
  });
  if (ok) {
    ++s.stored;
    return;
  }
  s.store_cut = true;
  say("session store " + options_.store_path + ": session '" + s.name + "': keyframes from " +
      std::to_string(keyframe) + " on are not stored (each counted a store failure); the " + std::to_string(s.stored) +
      " stored before stay restorable");
}

Status SessionManager::addKeyframe(const KeyframeInput& input, const std::vector<Loop>& loops) {
  if (!validSessionId(input.session)) {
    ++stats_.keyframes_refused;
    return badSessionId("keyframe " + std::to_string(input.keyframe), input.session);
  }
  if (input.keyframe < 0) {
    ++stats_.keyframes_refused;
    return {StatusCode::kInvalidArgument, "keyframe id " + std::to_string(input.keyframe) + " is negative"};
  }
  // The store keeps the session's camera (and refuses an unusable one): refused here, before it
  // could make the session's row, and with it every later save of the maps, fail.
  if (const std::string bad = unusableCamera(input.camera); !bad.empty()) {
    ++stats_.keyframes_refused;
    return {StatusCode::kInvalidArgument, "keyframe " + std::to_string(input.keyframe) + " of session " +
                                              std::to_string(input.session) + ": camera: " + bad};
  }
  KeyframeInput k = input;
  if (k.hash.size() != HalocProjections::kHashSize && !k.features.descriptors.empty())
    k.hash = hasher_.hash(k.features.descriptors);  // the one place a keyframe is hashed when nobody upstream did
  auto it = sessions_.find(k.session);
  if (it == sessions_.end()) {
    if (k.session < nextId()) {
      ++stats_.keyframes_stale;
      return {StatusCode::kFailedPrecondition, "keyframe of old session " + std::to_string(k.session) +
                                                   " skipped (session " + std::to_string(active_) + " is recording)"};
    }
    if (k.keyframe > options_.max_keyframe_gap) {
      ++stats_.keyframes_refused;
      return {StatusCode::kInvalidArgument, "keyframe " + std::to_string(k.keyframe) + " starts session " +
                                                std::to_string(k.session) + ": more than max_keyframe_gap (" +
                                                std::to_string(options_.max_keyframe_gap) + ") keyframes missing"};
    }
    open(k.session, "", k.stamp_s);
    it = sessions_.find(k.session);
  }
  const int id = k.session;
  if (id != active_) {
    ++stats_.keyframes_stale;
    return {StatusCode::kFailedPrecondition, "keyframe of finished session " + std::to_string(id) + " skipped"};
  }
  return appendKeyframe(std::move(k), loops);
}

Status SessionManager::appendKeyframe(KeyframeInput k, const std::vector<Loop>& loops) {
  const int id = k.session;
  Session& s = at(id);
  const int expected = static_cast<int>(s.stamps.size());
  if (k.keyframe > expected && k.keyframe - expected > options_.max_keyframe_gap) {
    ++stats_.keyframes_refused;
    return {StatusCode::kInvalidArgument, "keyframe " + std::to_string(k.keyframe) + " of session " +
                                              std::to_string(id) + ": " + std::to_string(k.keyframe - expected) +
                                              " keyframes missing, more than max_keyframe_gap (" +
                                              std::to_string(options_.max_keyframe_gap) + ")"};
  }
  UncertainPose2 motion = k.motion;
  const UncertainPose2* stored_motion = &motion;
  if (!s.origin_received && k.keyframe == 0) {
    // The origin: the session's first keyframe, or fills in start_session's placeholder origin.
    s.origin_received = true;
    s.camera = k.camera;
    s.stamps[0] = k.stamp_s;
    s.frames[0] = k.frame_index;
    stored_motion = nullptr;
  } else {
    if (!s.origin_received) {  // keyframe 0 never arrived: a placeholder origin
      s.origin_received = true;
      s.camera = k.camera;
      s.phantoms.insert(0);
      storeKeyframe(s, nullptr, 0, nullptr, k.stamp_s, nullptr, nullptr);
    }
    if (k.keyframe < expected) {
      ++stats_.keyframes_stale;
      return {StatusCode::kFailedPrecondition, "keyframe " + std::to_string(k.keyframe) + " of session " +
                                                   std::to_string(id) + " received twice or out of order, skipped"};
    }
    if (k.keyframe > expected) {
      // Keyframes lost on the way (a queue overflow): they stay where the last received one is
      // (phantoms: no loop may use them) and this one gets the odometry's motion across the gap.
      ++stats_.keyframe_gaps;
      say("session " + std::to_string(id) + " keyframes " + std::to_string(expected) + ".." +
          std::to_string(k.keyframe - 1) + " never arrived, bridged by the odometry");
      const Pose2 last = s.odometry.back();
      for (int g = expected; g < k.keyframe; ++g) {
        const UncertainPose2 still(Pose2(), Eigen::Matrix3d::Identity() * 1e-8);
        backend_->addMotion(s.backend, still);
        s.phantoms.insert(g);
        s.stamps.push_back(k.stamp_s);
        s.odometry.push_back(last);
        s.frames.push_back(k.frame_index);
        s.sources.push_back(MotionSource::kVisual);
        storeKeyframe(s, nullptr, g, &still, k.stamp_s, nullptr, nullptr);
      }
      motion = UncertainPose2(between(last, k.odometry_pose),
                              k.motion.covariance * static_cast<double>(k.keyframe - expected + 1));
    }
    backend_->addMotion(s.backend, motion);
    s.stamps.push_back(k.stamp_s);
    s.odometry.push_back(k.odometry_pose);
    s.frames.push_back(k.frame_index);
    s.sources.push_back(k.motion_source);
  }
  ++stats_.keyframes;
  // The loops it closed go into the store with it (one transaction), then into the back-end.
  // Only loops whose keyframes are (or are being) stored: a stored loop on a keyframe the store
  // lacks would make it unrestorable.
  std::vector<Loop> to_store;
  std::vector<int> stored_at(loops.size(), -1);
  for (std::size_t i = 0; i < loops.size(); ++i) {
    const Loop& l = loops[i];
    if (!keyframeStored(l.session_a, l.keyframe_a, id, k.keyframe) ||
        !keyframeStored(l.session_b, l.keyframe_b, id, k.keyframe))
      continue;
    stored_at[i] = static_cast<int>(to_store.size());
    to_store.push_back(l);
  }
  std::vector<StoredLoop> stored;  // to_store in store ids, their ids set when written
  const int stored_before = s.stored;
  storeKeyframe(s, &k, k.keyframe, stored_motion, k.stamp_s, &to_store, store_ ? &stored : nullptr);
  if (s.stored == stored_before) stored_at.assign(loops.size(), -1);  // the keyframe, and its loops, not written
  emit(SessionEvent::Kind::kKeyframeAdded, id, -1, mapOf(id), "");
  for (std::size_t i = 0; i < loops.size(); ++i) {
    ++stats_.loops;
    try {
      acceptLoop(loops[i]);
      store_loops_.push_back(store_ && stored_at[i] >= 0 ? stored[static_cast<std::size_t>(stored_at[i])].id : -1);
    } catch (const std::invalid_argument& e) {
      ++stats_.loops_refused;
      emit(SessionEvent::Kind::kLoopRefused, loops[i].session_b, loops[i].session_a, -1, e.what());
    }
  }
  afterBackendChange();
  return Status::Ok();
}

// --- Another vehicle's sessions (the hash exchange) -----------------------------------------

bool validVehicleName(const std::string& v) {
  if (v.empty() || v.size() > 64) return false;
  for (char c : v)
    if (!std::isalnum(static_cast<unsigned char>(c)) && c != '_' && c != '-') return false;
  return true;
}

int SessionManager::foreignSession(const std::string& vehicle, int remote_session) const {
  const auto it = foreign_ids_.find({vehicle, remote_session});
  return it == foreign_ids_.end() ? -1 : it->second;
}

Status SessionManager::addForeignKeyframe(const std::string& vehicle, const KeyframeInput& input, int* local_id) {
  if (!validVehicleName(vehicle)) {
    ++stats_.keyframes_refused;
    return {StatusCode::kInvalidArgument,
            "vehicle name '" + vehicle.substr(0, 64) + "': 1 to 64 characters of A-Z a-z 0-9 _ -"};
  }
  if (!validSessionId(input.session) || input.keyframe < 0) {
    ++stats_.keyframes_refused;
    return badSessionId("vehicle " + vehicle + "'s keyframe " + std::to_string(input.keyframe), input.session);
  }
  int id = foreignSession(vehicle, input.session);
  const auto ended = ended_foreign_.find({vehicle, input.session});
  // The vehicle started over (a restart on a new store numbers its sessions from 0 again): a
  // keyframe 0 of one of its sessions that records here or has ended, with another stamp, is the
  // origin of a new session (the same stamp: the origin sent twice, stale).
  const int known = id >= 0 ? id : ended != ended_foreign_.end() ? ended->second : -1;
  const bool again = known >= 0 && input.keyframe == 0 && at(known).stamps.front() != input.stamp_s;
  if (again && id >= 0) {
    say("vehicle " + vehicle + "'s session " + std::to_string(input.session) +
        " starts again from keyframe 0 (the vehicle restarted): session " + std::to_string(id) +
        " ends, a new one begins");
    const Status st = endForeignSession(vehicle, input.session, at(id).stamps.back());
    if (!st.ok()) return st;
    id = -1;
  }
  if (id < 0) {
    if (known >= 0 && !again) {
      ++stats_.keyframes_stale;
      return {StatusCode::kFailedPrecondition, "vehicle " + vehicle + "'s session " + std::to_string(input.session) +
                                                   " has ended: keyframe " + std::to_string(input.keyframe) +
                                                   " skipped"};
    }
    if (input.keyframe > options_.max_keyframe_gap) {
      ++stats_.keyframes_refused;
      return {StatusCode::kInvalidArgument, "keyframe " + std::to_string(input.keyframe) + " starts vehicle " +
                                                vehicle + "'s session " + std::to_string(input.session) +
                                                ": more than max_keyframe_gap keyframes missing"};
    }
    if (nextId() > kMaxSessionId)
      return {StatusCode::kResourceExhausted,
              "no session id left for vehicle " + vehicle + "'s session " + std::to_string(input.session)};
    // A name taken (this vehicle's session of an earlier run, or one it started over): _2, _3, ...
    const std::string base = vehicle + "_session_" + std::to_string(input.session);
    std::string name = base;
    for (int n = 2; idOfName(name) >= 0; ++n) name = base + "_" + std::to_string(n);
    id = nextId();
    ended_foreign_.erase({vehicle, input.session});
    open(id, name, input.stamp_s, vehicle, input.session);
  }
  if (local_id) *local_id = id;
  KeyframeInput k = input;
  k.session = id;
  // Only what crossed the link is kept: no features (asked of the vehicle when needed), no image.
  k.features = FrameFeatures();
  k.thumbnail.clear();
  return appendKeyframe(std::move(k), {});
}

Status SessionManager::endForeignSession(const std::string& vehicle, int remote_session, double stamp_s) {
  const int id = foreignSession(vehicle, remote_session);
  if (id < 0)
    return {StatusCode::kNotFound,
            "vehicle " + vehicle + " has no session " + std::to_string(remote_session) + " recording here"};
  Session& s = at(id);
  backend_->endSession(s.backend);  // first: a throw leaves it recording here, as it was
  foreign_ids_.erase({vehicle, remote_session});
  ended_foreign_[{vehicle, remote_session}] = id;
  storeWrite("ending a session", [&] {
    if (s.store_id >= 0) store_->endSession(s.store_id, stamp_s);
  });
  emit(SessionEvent::Kind::kSessionEnded, id, -1, mapOf(id),
       "session " + std::to_string(id) + " (vehicle " + vehicle + "'s session " + std::to_string(remote_session) +
           ") ended with " + std::to_string(s.stamps.size()) + " keyframes");
  afterBackendChange();
  saveMaps();
  return Status::Ok();
}

// --- Loops ------------------------------------------------------------------------------------

StoredLoop SessionManager::toStored(const Loop& l) const {
  StoredLoop sl;
  const auto a = sessions_.find(l.session_a), b = sessions_.find(l.session_b);
  sl.session_a = a == sessions_.end() ? -1 : a->second.store_id;
  sl.session_b = b == sessions_.end() ? -1 : b->second.store_id;
  sl.keyframe_a = l.keyframe_a;
  sl.keyframe_b = l.keyframe_b;
  sl.global = l.kind == Loop::Kind::kGlobal;
  sl.inliers = l.inliers;
  sl.z = l.z;
  return sl;
}

bool SessionManager::loopRefused(std::size_t i) const {
  return i < loops_.size() && backend_->loopRecord(static_cast<int>(i)).refused;
}

void SessionManager::acceptLoop(const Loop& l) {
  const Session& a = at(l.session_a);
  const Session& b = at(l.session_b);
  if (a.phantoms.count(l.keyframe_a) || b.phantoms.count(l.keyframe_b))
    throw std::invalid_argument("loop on a keyframe that never arrived");
  backend_->addLoop({a.backend, l.keyframe_a, b.backend, l.keyframe_b, l.z, l.inliers});
  Loop named = l;
  if (l.keyframe_a < static_cast<int>(a.frames.size())) named.frame_a = a.frames[l.keyframe_a];
  if (l.keyframe_b < static_cast<int>(b.frames.size())) named.frame_b = b.frames[l.keyframe_b];
  loops_.push_back(named);
  ++at(l.session_a).loops;
  if (l.session_b != l.session_a) ++at(l.session_b).loops;
  emit(SessionEvent::Kind::kLoopAccepted, l.session_b, l.session_a, mapOf(l.session_b), "");
}

Status SessionManager::addLoop(const Loop& l, bool* waiting) {
  if (waiting) *waiting = false;
  if (!validSessionId(l.session_a) || !validSessionId(l.session_b) || l.keyframe_a < 0 || l.keyframe_b < 0) {
    ++stats_.loops_refused;
    return validSessionId(l.session_a) && validSessionId(l.session_b)
               ? Status{StatusCode::kInvalidArgument, "a loop names a negative keyframe id"}
               : badSessionId("a loop", validSessionId(l.session_a) ? l.session_b : l.session_a);
  }
  for (int s : {l.session_a, l.session_b}) {
    if (deleted_.count(s)) {  // deleted: nothing will arrive for it
      ++stats_.loops_refused;
      return {StatusCode::kNotFound, "a loop names session " + std::to_string(s) + ", which was deleted"};
    }
  }
  const auto a = sessions_.find(l.session_a), b = sessions_.find(l.session_b);
  if (a == sessions_.end() || b == sessions_.end() || l.keyframe_a >= static_cast<int>(a->second.stamps.size()) ||
      l.keyframe_b >= static_cast<int>(b->second.stamps.size())) {
    if (waiting) *waiting = true;
    return {StatusCode::kFailedPrecondition, "a keyframe of the loop has not arrived yet"};
  }
  ++stats_.loops;
  try {
    acceptLoop(l);
  } catch (const std::invalid_argument& e) {
    ++stats_.loops_refused;
    emit(SessionEvent::Kind::kLoopRefused, l.session_b, l.session_a, -1, e.what());
    return {StatusCode::kFailedPrecondition, std::string("loop refused: ") + e.what()};
  }
  std::int64_t stored_id = -1;
  auto memoryOnly = [&](int s, int k) { return !keyframeStored(s, k) && at(s).memory_only; };
  if (!store_ || localising_ || memoryOnly(l.session_a, l.keyframe_a) || memoryOnly(l.session_b, l.keyframe_b)) {
    // nothing written: no store, or localisation mode (not a failure)
  } else if (!keyframeStored(l.session_a, l.keyframe_a) || !keyframeStored(l.session_b, l.keyframe_b)) {
    ++stats_.store_failures;  // on a keyframe the store lacks (a failed write): kept in memory only
  } else {
    storeWrite("writing a loop", [&] {
      std::vector<StoredLoop> one{toStored(l)};
      store_->addLoops(&one);
      stored_id = one[0].id;
    });
  }
  store_loops_.push_back(stored_id);
  afterBackendChange();
  return Status::Ok();
}

Status SessionManager::checkLinkEnds(const Loop& l) const {
  for (int s : {l.session_a, l.session_b}) {
    if (!validSessionId(s)) return badSessionId("add_link", s);
    if (!has(s)) return notFound(s);
  }
  for (const auto& [s, k] : {std::pair<int, int>{l.session_a, l.keyframe_a}, {l.session_b, l.keyframe_b}}) {
    const int n = static_cast<int>(at(s).stamps.size());
    if (k < 0) return {StatusCode::kInvalidArgument, "add_link: keyframe ids are >= 0"};
    if (k >= n)
      return {StatusCode::kNotFound, "add_link: session " + std::to_string(s) + " has no keyframe " +
                                         std::to_string(k) + " (it has " + std::to_string(n) + ")"};
    if (at(s).phantoms.count(k))
      return {StatusCode::kFailedPrecondition, "add_link: keyframe " + std::to_string(k) + " of session " +
                                                   std::to_string(s) + " never arrived (bridged)"};
  }
  if (l.session_a == l.session_b && l.keyframe_a == l.keyframe_b)
    return {StatusCode::kInvalidArgument, "add_link: a keyframe cannot be linked to itself"};
  return Status::Ok();
}

Status SessionManager::storedMapsMayChange(const std::string& what) const {
  if (!localising_) return Status::Ok();
  return {StatusCode::kFailedPrecondition,
          what + " is refused in localisation mode (no stored map changes): set_mode mapping first"};
}

Status SessionManager::checkLink(const Loop& l) const {
  if (const Status ends = checkLinkEnds(l); !ends.ok()) return ends;
  if (const std::string bad = checkUncertainPose(l.z, true); !bad.empty())
    return {StatusCode::kInvalidArgument,
            "add_link: the pose: " + bad + " (x, y, yaw; m, rad; covariance m^2, rad^2, row-major)"};
  if (l.inliers < 0) return {StatusCode::kInvalidArgument, "add_link: inliers must be >= 0"};
  return storedMapsMayChange("add_link");
}

Status SessionManager::addLink(Loop l) {
  if (const Status checked = checkLink(l); !checked.ok()) return checked;
  l.kind = l.session_a == l.session_b ? Loop::Kind::kLocal : Loop::Kind::kGlobal;
  l.frame_a = at(l.session_a).frames.at(l.keyframe_a);
  l.frame_b = at(l.session_b).frames.at(l.keyframe_b);
  l.hash_l1 = 0.0f;
  Status st;
  {
    // The link goes into the audit trail before a join it brings about (also when addLoop throws).
    struct Hold {
      bool* flag;
      ~Hold() { *flag = false; }
    } hold{&hold_changes_};
    hold_changes_ = true;
    st = addLoop(l);
  }
  if (st.ok()) {
    const std::string link = loopText(l);
    const char* kind = l.kind == Loop::Kind::kLocal ? "local" : "global";
    say("add_link " + link + " (" + kind + ")");
    char pose[200];
    std::snprintf(pose, sizeof pose, "pose (%.4f m, %.4f m, %.4f rad), sigma (%.4g m, %.4g m, %.4g rad), %d inliers",
                  l.z.mean.x(), l.z.mean.y(), l.z.mean.yaw(), std::sqrt(l.z.covariance(0, 0)),
                  std::sqrt(l.z.covariance(1, 1)), std::sqrt(l.z.covariance(2, 2)), l.inliers);
    record("link",
           l.session_a == l.session_b ? std::to_string(l.session_a)
                                      : std::to_string(l.session_a) + "," + std::to_string(l.session_b),
           link, std::string(kind) + " link " + link + ": " + pose, options_.requester.c_str());
  }
  recordMapChanges();
  return st;
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
           "localisation mode from " + localising_since_ + " to " + utcTimestamp() + " (" + std::to_string(memory_only) +
               " keyframes kept in memory only), mapping again",
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

// --- Maps -------------------------------------------------------------------------------------

std::string SessionManager::chainText(const std::vector<int>& backend_sessions) const {
  std::string t;
  for (int b : backend_sessions) t += (t.empty() ? "" : ",") + std::to_string(idOfBackend(b));
  return t;
}

std::string SessionManager::loopsText(const std::vector<int>& backend_loops) const {
  std::string t;
  for (int i : backend_loops)  // loops_[i] is the back-end's loop i
    t += (t.empty() ? "" : " ") + loopText(loops_.at(static_cast<std::size_t>(i)));
  return t;
}

HistoryEntry SessionManager::nextEntry(const std::string& kind, const std::string& sessions, const std::string& loops,
                                       const std::string& message, const char* cause) const {
  return {history_.empty() ? 1 : history_.back().id + 1, utcTimestamp(), kind, cause ? cause : cause_, sessions, loops,
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
    // Only among this run's entries: a restart numbers the stored sessions 0..k-1 again, so an
    // earlier run's ids may name other sessions now.
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

StoredKeyframe SessionManager::storedFeatures(int session, int keyframe) const {
  if (!store_) throw StoreError("no session store: no stored features");
  const auto it = sessions_.find(session);
  if (it == sessions_.end() || it->second.store_id < 0 || !keyframeStored(session, keyframe))
    throw StoreError("session store " + options_.store_path + ": keyframe " + std::to_string(keyframe) +
                     " of session " + std::to_string(session) + " is not stored");
  StoredKeyframe k = store_->keyframeFeatures(it->second.store_id, keyframe);
  k.session = session;
  return k;
}

std::vector<StoredKeyframe> SessionManager::storedHashes(int session) const {
  if (!store_) throw StoreError("no session store: no stored hashes");
  const auto it = sessions_.find(session);
  if (it == sessions_.end() || it->second.store_id < 0 || session >= restored_sessions_)
    throw StoreError("session store " + options_.store_path + ": session " + std::to_string(session) +
                     " is not a stored session");
  std::vector<StoredKeyframe> out = store_->keyframes(it->second.store_id, SessionStore::KeyframeColumns::kHash);
  for (StoredKeyframe& k : out) k.session = session;
  return out;
}

Status SessionManager::reload(const std::string& name_or_id, ReloadedSession* out, ReloadRead read) {
  if (!store_) return {StatusCode::kFailedPrecondition, "no session store: nothing to reload"};
  const int id = findSession(name_or_id);
  if (id < 0 || at(id).store_id < 0 || id >= restored_sessions_)
    return {StatusCode::kNotFound, "no stored session named '" + name_or_id + "' in " + storeName() +
                                       " (list_sessions shows the stored ones as UNLOADED)"};
  Session& s = at(id);
  if (!s.unloaded) {
    out->id = id;
    return {StatusCode::kAlreadyExists, "session " + std::to_string(id) + " ('" + s.name + "') is already loaded"};
  }
  ReloadedSession r;
  try {
    if (read != ReloadRead::kNothing)
      r.keyframes = store_->keyframes(s.store_id, read == ReloadRead::kFeatures ? SessionStore::KeyframeColumns::kAll
                                                                                : SessionStore::KeyframeColumns::kHash);
  } catch (const std::exception& e) {
    say("reload_session '" + name_or_id + "': reading " + options_.store_path + " failed: " + e.what());
    // The reply names the file only: the store's errors carry its full path.
    std::string why = e.what();
    const std::string& path = options_.store_path;
    const std::string name = storeName();
    for (std::size_t at = why.find(path); at != std::string::npos; at = why.find(path, at + name.size()))
      why.replace(at, path.size(), name);
    return {StatusCode::kDataLoss, "reading " + storeName() + ": " + why};
  }
  r.id = id;
  r.camera = s.camera;
  s.unloaded = false;
  // Older stores kept a 0x0 camera for some sessions with keyframes: their features cannot be put
  // in metres, so no loop to them verifies (the loop detector refuses such keyframes).
  if (s.camera.unknown() && !s.stamps.empty())
    say("session " + std::to_string(id) + " '" + s.name + "' has no stored camera (0x0, written by an older " +
        "version): no loop to its " + std::to_string(s.stamps.size()) + " keyframes can be verified");
  *out = std::move(r);
  return Status::Ok();
}

Status SessionManager::unload(const std::string& name_or_id, int* id_out) {
  if (id_out) *id_out = -1;
  if (!store_) return {StatusCode::kFailedPrecondition, "no session store: nothing was reloaded, nothing to unload"};
  const int id = findSession(name_or_id);
  if (id < 0)
    return {StatusCode::kNotFound, "no session named or numbered '" + name_or_id + "' (list_sessions shows them)"};
  if (id_out) *id_out = id;
  Session& s = at(id);
  if (id >= restored_sessions_)
    return {StatusCode::kFailedPrecondition,
            "session " + std::to_string(id) + " ('" + s.name +
                "') was recorded in this run: only sessions restored from the store can be unloaded "
                "(reload_session brings them back)"};
  if (s.unloaded)
    return {StatusCode::kFailedPrecondition, "session " + std::to_string(id) + " ('" + s.name + "') is not loaded"};
  s.unloaded = true;
  say("unload_session '" + name_or_id + "': session " + std::to_string(id) + " UNLOADED (its " +
      std::to_string(s.stamps.size()) + " keyframes stay in the store and in map " + std::to_string(mapOf(id)) + ")");
  return Status::Ok();
}

Status SessionManager::deleteSession(const std::string& name_or_id, bool confirm, int* id_out) {
  if (id_out) *id_out = -1;
  if (!store_) return {StatusCode::kFailedPrecondition, "no session store: nothing to delete from"};
  if (const Status mode = storedMapsMayChange("delete_session"); !mode.ok()) return mode;
  const int id = findSession(name_or_id);
  if (id < 0)
    return {StatusCode::kNotFound, "no session named or numbered '" + name_or_id + "' (list_sessions shows them)"};
  if (id_out) *id_out = id;
  const Session& s = at(id);
  const std::string what = "session " + std::to_string(id) + " ('" + s.name + "')";
  if (id == active_ || backend_->session(s.backend).recording)
    return {StatusCode::kFailedPrecondition, what + " is recording: finish_session first"};
  const std::vector<int> chain = backend_->chain(backend_->mapOf(s.backend));
  if (chain.size() != 1)
    return {StatusCode::kFailedPrecondition, what + " shares map " + std::to_string(mapOf(id)) + " with " +
                                                 std::to_string(chain.size() - 1) +
                                                 " other sessions: split_session it off first"};
  const std::string lost = std::to_string(s.stamps.size()) + " keyframes, " + std::to_string(s.loops) + " loops";
  if (!confirm)
    return {StatusCode::kFailedPrecondition, "delete_session removes " + what + " (" + lost +
                                                 ") from the store for good: call again with confirm true"};
  recordMapChanges();  // none is pending; were one, it would go in before the deletion
  const std::string name = s.name;
  const HistoryEntry entry = nextEntry("delete", std::to_string(id), "",
                                       "session " + std::to_string(id) + " '" + name + "' deleted (" + lost + ")",
                                       options_.requester.c_str());
  if (s.store_id >= 0) {
    try {
      store_->deleteSessions({s.store_id}, &entry);  // one transaction with its history entry: all or nothing
    } catch (const std::exception& e) {
      say("delete_session '" + name_or_id + "': " + e.what());
      return {StatusCode::kDataLoss, "the store could not be changed, nothing deleted: " + std::string(e.what())};
    }
  }
  // Memory: the back-end's indexes after it move down one; the manager's loops follow its order.
  const int b = s.backend;
  const Status removed = backend_->removeSession(b);
  if (!removed.ok()) throw std::logic_error("session manager: " + removed.message);  // checked above
  std::vector<Loop> loops;
  std::vector<std::int64_t> store_loops;
  for (std::size_t i = 0; i < loops_.size(); ++i) {
    const Loop& l = loops_[i];
    if (l.session_a == id || l.session_b == id) {
      const int other = l.session_a == id ? l.session_b : l.session_a;
      if (other != id) --at(other).loops;
      continue;
    }
    loops.push_back(l);
    store_loops.push_back(store_loops_[i]);
  }
  loops_ = std::move(loops);
  store_loops_ = std::move(store_loops);
  id_of_backend_.erase(id_of_backend_.begin() + b);
  for (auto& [sid, t] : sessions_)
    if (t.backend > b) --t.backend;
  const bool in_store = s.store_id >= 0;
  next_id_floor_ = std::max(next_id_floor_, nextId());
  sessions_.erase(id);  // `s` is gone from here on
  deleted_.insert(id);
  if (!in_store) storeWrite("writing the history", [&] { store_->addHistory(entry); });  // never stored itself
  history_.push_back(entry);
  say("delete_session '" + name_or_id + "': session " + std::to_string(id) + " '" + name + "' deleted (" + lost +
      ") from " + storeName() + " and from memory");
  return Status::Ok();
}

// --- Queries ----------------------------------------------------------------------------------

int SessionManager::findSession(const std::string& name_or_id) const {
  // A session's name first (names are unique), then its id: a session named "3" is not session 3.
  for (const auto& [sid, s] : sessions_)
    if (s.name == name_or_id) return sid;
  for (const auto& [sid, s] : sessions_)
    if (std::to_string(sid) == name_or_id) return sid;
  return -1;
}

std::vector<int> SessionManager::storedSessionsOf(const std::vector<FrameRecord>& frames) const {
  std::vector<int> ids;
  for (const auto& [id, s] : sessions_)
    if (id < restored_sessions_ && keyframesAreFramesOf(s.frames, s.stamps, frames)) ids.push_back(id);
  return ids;
}

int SessionManager::idOfName(const std::string& name) const {
  for (const auto& [id, s] : sessions_)
    if (s.name == name) return id;
  return -1;
}

std::vector<int> SessionManager::sessionIds() const {
  std::vector<int> ids;
  for (const auto& [id, s] : sessions_) ids.push_back(id);
  return ids;
}

int SessionManager::mapOf(int session) const { return idOfBackend(backend_->mapOf(at(session).backend)); }

std::vector<int> SessionManager::mapIds() const {
  std::vector<int> ids;
  for (int m : backend_->mapIds()) ids.push_back(idOfBackend(m));
  return ids;
}

std::vector<Pose2> SessionManager::poses(int session) const { return backend_->sessionPoses(at(session).backend); }

std::vector<Pose2> SessionManager::posesInSessionFrame(int session) const {
  std::vector<Pose2> p = poses(session);
  const Pose2 origin_inv = invert(p.front());
  for (Pose2& x : p) x = compose(origin_inv, x);
  return p;
}

UncertainPose2 SessionManager::lastKeyframeInMap(int session) const {
  const Session& s = at(session);
  return backend_->keyframeInMap(s.backend, static_cast<int>(s.stamps.size()) - 1);
}

Pose2 SessionManager::correction(int session) const {
  const Session& s = at(session);
  return compose(backend_->sessionPoses(s.backend).back(), invert(s.odometry.back()));
}

std::optional<SessionManager::Relocalisation> SessionManager::relocalise(int session) const {
  if (!has(session) || !at(session).origin_received) return std::nullopt;
  const Session& s = at(session);
  const auto r = backend_->relocalise(s.backend, [this](int map) {
    for (int b : backend_->chain(map))
      if (idOfBackend(b) < restored_sessions_) return true;
    return false;
  });
  if (!r) return std::nullopt;
  Relocalisation out;
  out.map = idOfBackend(r->map);
  out.loops = r->loops;
  out.inliers = r->inliers;
  out.keyframe = r->keyframe;
  out.pose = r->pose;
  out.correction = compose(r->origin.mean, correction(session));
  return out;
}

std::vector<SessionLink> SessionManager::links() const {
  std::vector<SessionLink> out;
  for (int m : backend_->mapIds())
    for (const LinkInfo& l : backend_->links(m))
      out.push_back({idOfBackend(m), idOfBackend(l.previous), idOfBackend(l.current), l.loops, l.measured, l.estimate});
  return out;
}

std::vector<SessionSummary> SessionManager::list() const {
  std::vector<SessionSummary> out;
  for (const auto& [id, s] : sessions_) {
    SessionSummary x;
    x.id = id;
    x.name = s.name;
    const bool foreign_recording = !s.vehicle.empty() && foreignSession(s.vehicle, s.remote_id) == id;
    x.state = id == active_ || foreign_recording ? SessionState::kActive
              : s.unloaded                       ? SessionState::kUnloaded
                                                 : SessionState::kFinished;
    x.vehicle = s.vehicle;
    x.map = mapOf(id);
    x.keyframes = static_cast<int>(s.stamps.size());
    x.loops = s.loops;
    x.first_stamp_s = s.stamps.front();
    x.last_stamp_s = s.stamps.back();
    out.push_back(x);
  }
  return out;
}

}  // namespace core
}  // namespace uw_multislam
