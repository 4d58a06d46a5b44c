#include "uw_multislam/core/session/session_table.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <stdexcept>
#include <utility>

#include "session_detail.h"
#include "uw_multislam/core/store/map_persistence.h"

namespace uw_multislam {
namespace core {

using namespace session_detail;  // NOLINT: the manager's own helpers

bool nameIsAnId(const std::string& name) {
  return !name.empty() && std::all_of(name.begin(), name.end(), [](unsigned char c) { return std::isdigit(c) != 0; });
}

std::string sessionNameOfFolder(const std::string& folder) { return nameIsAnId(folder) ? "./" + folder : folder; }

SessionTable::SessionTable(const SessionManagerOptions& options, SessionLog log)
    : options_(options),
      log_(std::move(log)),
      hasher_(options.hash_mode, options.num_features, options.projection_seed),
      backend_(std::make_unique<MultiSessionBackend>(checked(options), [this](const std::string& l) {
        if (log_) log_(l);
      })) {}

const SessionTable::Session& SessionTable::at(int id) const {
  const auto it = sessions_.find(id);
  if (it == sessions_.end()) throw std::invalid_argument("session manager: no session " + std::to_string(id));
  return it->second;
}

SessionTable::Session& SessionTable::at(int id) {
  return const_cast<Session&>(static_cast<const SessionTable*>(this)->at(id));
}

int SessionTable::nextId() const {
  return std::max(next_id_floor_, sessions_.empty() ? 0 : sessions_.rbegin()->first + 1);
}

int SessionTable::idOfName(const std::string& name) const {
  for (const auto& [id, s] : sessions_)
    if (s.name_ == name) return id;
  return -1;
}

int SessionTable::findSession(const std::string& name_or_id) const {
  // Digits only name an id (no name is made of them); a session of an older store may still be
  // named so: found by that name when no session has the id. Anything else is a name.
  const bool digits = nameIsAnId(name_or_id);
  if (digits)
    for (const auto& [id, s] : sessions_)
      if (std::to_string(id) == name_or_id) return id;
  const int named = idOfName(name_or_id);
  if (named >= 0 || digits) return named;
  return -1;
}

int SessionTable::foreignSession(const std::string& vehicle, int remote_session) const {
  const auto it = foreign_ids_.find({vehicle, remote_session});
  return it == foreign_ids_.end() ? -1 : it->second;
}

int SessionTable::endedForeignSession(const std::string& vehicle, int remote_session) const {
  const auto it = ended_foreign_.find({vehicle, remote_session});
  return it == ended_foreign_.end() ? -1 : it->second;
}

std::vector<std::pair<std::string, int>> SessionTable::foreignRecording() const {
  std::vector<std::pair<std::string, int>> out;
  for (const auto& [key, id] : foreign_ids_) out.push_back(key);
  return out;
}

bool SessionTable::keyframeStored(int session, int keyframe, int pending_session, int pending_keyframe) const {
  if (session == pending_session && keyframe == pending_keyframe) return true;
  const auto it = sessions_.find(session);
  return it != sessions_.end() && keyframe >= 0 && keyframe < it->second.stored;
}

int SessionTable::trailingEmptySessions() const {
  int n = 0;
  for (auto it = sessions_.rbegin(); it != sessions_.rend() && !it->second.origin_received; ++it) ++n;
  return n;
}

SessionTable::Session& SessionTable::open(int id, const std::string& name, double stamp_s, const std::string& vehicle,
                                          int remote_id) {
  if (!validSessionId(id) || id < nextId())
    throw std::logic_error("session manager: session id " + std::to_string(id) + " is not new (next " +
                           std::to_string(nextId()) + ")");
  Session s;
  s.name_ = name;
  if (name.empty()) {  // a default name a request took already: _2, _3, ...
    s.name_ = defaultSessionName(id);
    for (int n = 2; idOfName(s.name_) >= 0; ++n) s.name_ = defaultSessionName(id) + "_" + std::to_string(n);
  }
  if (idOfName(s.name_) >= 0) throw std::logic_error("session manager: the name '" + s.name_ + "' is taken");
  const bool foreign = !vehicle.empty();
  if (!foreign && active_ >= 0)
    throw std::logic_error("session manager: session " + std::to_string(active_) + " still records");
  s.vehicle_ = vehicle;
  s.remote_id_ = remote_id;
  s.backend_ = backend_->startSession(s.name_);
  if (s.backend_ != static_cast<int>(id_of_backend_.size()))
    throw std::logic_error("session manager: back-end ids drifted");
  id_of_backend_.push_back(id);
  s.stamps.push_back(stamp_s);
  s.odometry.push_back(Pose2());
  s.frames.push_back(0);
  s.altitudes.push_back(0.0);
  s.sources.push_back(MotionSource::kVisual);
  Session& added = sessions_.emplace(id, std::move(s)).first->second;
  if (foreign) {
    foreign_ids_[{vehicle, remote_id}] = id;
    ended_foreign_.erase({vehicle, remote_id});
  } else {
    active_ = id;
  }
  return added;
}

void SessionTable::endActive() {
  if (active_ < 0) return;
  backend_->endSession(at(active_).backend_);
  active_ = -1;
}

void SessionTable::endForeign(const std::string& vehicle, int remote_session) {
  const int id = foreignSession(vehicle, remote_session);
  if (id < 0) throw std::logic_error("session manager: vehicle " + vehicle + "'s session is not recording here");
  backend_->endSession(at(id).backend_);  // first: a throw leaves it recording here, as it was
  foreign_ids_.erase({vehicle, remote_session});
  ended_foreign_[{vehicle, remote_session}] = id;
}

void SessionTable::setStoreRow(int id, std::int64_t row) {
  // A session's id is its store id for life: the row takes the session's id.
  if (row != id)
    throw std::logic_error("session manager: session " + std::to_string(id) + " got store row " + std::to_string(row));
  at(id).store_row_ = row;
}

void SessionTable::remove(int id) {
  const Session& s = at(id);
  const int b = s.backend_;
  const Status removed = backend_->removeSession(b);
  if (!removed.ok()) throw std::logic_error("session manager: " + removed.message);
  // The back-end's loops after it keep their order: the table's follow.
  std::vector<Loop> loops;
  std::vector<std::int64_t> store_loops;
  for (std::size_t i = 0; i < loops_.size(); ++i) {
    const Loop& l = loops_[i];
    if (l.session_a == id || l.session_b == id) {
      const int other = l.session_a == id ? l.session_b : l.session_a;
      if (other != id) --at(other).loops_;
      continue;
    }
    loops.push_back(l);
    store_loops.push_back(store_loops_[i]);
  }
  loops_ = std::move(loops);
  store_loops_ = std::move(store_loops);
  id_of_backend_.erase(id_of_backend_.begin() + b);
  for (auto& [sid, t] : sessions_)
    if (t.backend_ > b) --t.backend_;
  next_id_floor_ = std::max(next_id_floor_, nextId());
  sessions_.erase(id);
  deleted_.insert(id);
}

void SessionTable::toPiece(int* session, int* keyframe, bool detector_loop) const {
  // The piece of the odometry's session that holds this keyframe: the one that starts last at or
  // before it (one odometry session can jump more than once; earlier pieces keep their names).
  const Piece* in = nullptr;
  for (const Piece& p : pieces_)
    if (p.from == *session && p.base <= *keyframe && (!in || p.base >= in->base) &&
        !(detector_loop && p.keyframes_only))
      in = &p;
  if (!in) return;
  *session = in->to;
  *keyframe -= in->base;
}

int SessionTable::newestOwnSession() const {
  for (auto it = sessions_.rbegin(); it != sessions_.rend(); ++it)
    if (it->second.vehicle_.empty()) return it->first;
  return -1;
}

std::size_t SessionTable::acceptLoop(const Loop& l, std::int64_t store_row) {
  Session& a = at(l.session_a);
  Session& b = at(l.session_b);
  if (a.phantoms.count(l.keyframe_a) || b.phantoms.count(l.keyframe_b))
    throw std::invalid_argument("loop on a keyframe that never arrived");
  backend_->addLoop({a.backend_, l.keyframe_a, b.backend_, l.keyframe_b, l.z, l.inliers, l.nav_placement});
  Loop named = l;
  if (l.keyframe_a < static_cast<int>(a.frames.size())) named.frame_a = a.frames[l.keyframe_a];
  if (l.keyframe_b < static_cast<int>(b.frames.size())) named.frame_b = b.frames[l.keyframe_b];
  loops_.push_back(named);
  store_loops_.push_back(store_row);
  ++a.loops_;
  if (l.session_b != l.session_a) ++b.loops_;
  return loops_.size() - 1;
}

void SessionTable::setLocalising(bool on, const std::string& since) {
  localising_ = on;
  if (on) localising_since_ = since;
}

std::vector<std::string> SessionTable::openStore() {
  if (!sessions_.empty() || store_) throw std::logic_error("session manager: the store opens on an empty table");
  const std::filesystem::path dir = std::filesystem::path(options_.store_path).parent_path();
  std::error_code ec;
  if (!dir.empty() && !std::filesystem::exists(dir, ec)) {  // a failure shows in the open below
    std::filesystem::create_directories(dir, ec);
    std::filesystem::permissions(dir, std::filesystem::perms::owner_all, ec);  // 0700: the owner's missions only
  }
  store_ = std::make_unique<SessionStore>(options_.store_path);
  if (options_.store_max_mb > 0.0) store_->setMaxBytes(static_cast<std::uint64_t>(options_.store_max_mb * 1048576.0));
  store_->checkHashSettings({options_.hash_mode, options_.projection_seed, options_.num_features,
                             hasher_.projections().toText(), options_.features});

  const RestoredStore r = restoreStore(*store_, backend_.get(), nullptr, nullptr);
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
    s.backend_ = static_cast<int>(b);
    s.store_row_ = r.session_ids[b];
    s.name_ = backend_->session(s.backend_).name;
    for (const StoredSession& st : stored)
      if (st.id == s.store_row_) s.camera = st.camera;
    for (const StoredKeyframe& k : store_->keyframes(s.store_row_, false)) {
      s.stamps.push_back(k.stamp_s);
      s.frames.push_back(k.frame_index);
      s.altitudes.push_back(k.altitude_m);
    }
    s.odometry.push_back(Pose2());
    for (const UncertainPose2& m : store_->odometry(s.store_row_))
      s.odometry.push_back(compose(s.odometry.back(), m.mean));
    s.sources.push_back(MotionSource::kVisual);
    for (const MotionSource m : store_->motionSources(s.store_row_)) s.sources.push_back(m);
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
      if (s.store_row_ == p.session && validVehicleName(p.vehicle)) {
        s.vehicle_ = p.vehicle;
        s.remote_id_ = static_cast<int>(p.source_session);
      }
  }
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
    store_loops_.push_back(r.loop_ids[i]);
    ++at(l.session_a).loops_;
    if (l.session_b != l.session_a) ++at(l.session_b).loops_;
  }
  restored_sessions_ = static_cast<int>(sessions_.size());
  // This run's sessions take their ids past every id the store holds or held. The id is the
  // store id its row gets when the session is first written, not reserved by an empty row at
  // once: the store is held by this process alone (its lock), so no other writer can take the id
  // meanwhile, and a session that never gets a keyframe leaves no row behind. nextSessionId()
  // also counts deleted sessions, so an id is never given twice.
  const std::int64_t next = store_->nextSessionId();
  next_id_floor_ = static_cast<int>(std::min<std::int64_t>(next, kMaxSessionId + 1));
  first_new_id_ = nextId();
  history_ = store_->history();
  history_restored_ = static_cast<std::ptrdiff_t>(history_.size());
  backend_->takeMapChanges();  // restoring is no join
  return r.notes;
}

}  // namespace core
}  // namespace uw_multislam
