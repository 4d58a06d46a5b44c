#include "uw_multislam/core/session/session_queries.h"

#include <algorithm>
#include <filesystem>
#include <stdexcept>
#include <utility>

#include "session_detail.h"
#include "uw_multislam/core/store/interrupted_run.h"

namespace uw_multislam {
namespace core {

using namespace session_detail;  // NOLINT: the manager's own helpers

SessionQueries::SessionQueries(const SessionManagerOptions& options, EventSink events, Log log)
    : options_(options),
      events_(std::move(events)),
      log_(std::move(log)),
      hasher_(options.hash_mode, options.num_features, options.projection_seed),
      backend_(std::make_unique<MultiSessionBackend>(checked(options), [this](const std::string& l) { say(l); })) {}

bool SessionQueries::keyframeStored(int session, int keyframe, int pending_session, int pending_keyframe) const {
  if (session == pending_session && keyframe == pending_keyframe) return true;
  const auto it = sessions_.find(session);
  return it != sessions_.end() && keyframe >= 0 && keyframe < it->second.stored;
}

const SessionQueries::Session& SessionQueries::at(int session) const {
  const auto it = sessions_.find(session);
  if (it == sessions_.end()) throw std::invalid_argument("session manager: no session " + std::to_string(session));
  return it->second;
}

SessionQueries::Session& SessionQueries::at(int session) {
  return const_cast<Session&>(static_cast<const SessionQueries*>(this)->at(session));
}

void SessionQueries::say(const std::string& line) const {
  if (log_) log_(line);
}

std::string SessionQueries::storeName() const { return std::filesystem::path(options_.store_path).filename().string(); }

int SessionQueries::trailingEmptySessions() const {
  int n = 0;
  for (auto it = sessions_.rbegin(); it != sessions_.rend() && !it->second.origin_received; ++it) ++n;
  return n;
}

void SessionQueries::emit(SessionEvent::Kind kind, int session, int other, int map, const std::string& message) const {
  if (!events_) return;
  const auto s = sessions_.find(session);
  events_({kind, session, other, map, message, s == sessions_.end() ? std::string() : s->second.vehicle});
}

HashSettings SessionQueries::hashSettings() const {
  return {options_.hash_mode, options_.projection_seed, options_.num_features, hasher_.projections().toText(),
          options_.features};
}

int SessionQueries::findSession(const std::string& name_or_id) const {
  // A session's name first (names are unique), then its id: a session named "3" is not session 3.
  for (const auto& [sid, s] : sessions_)
    if (s.name == name_or_id) return sid;
  for (const auto& [sid, s] : sessions_)
    if (std::to_string(sid) == name_or_id) return sid;
  return -1;
}

int SessionQueries::idOfName(const std::string& name) const {
  for (const auto& [id, s] : sessions_)
    if (s.name == name) return id;
  return -1;
}

std::vector<int> SessionQueries::sessionIds() const {
  std::vector<int> ids;
  for (const auto& [id, s] : sessions_) ids.push_back(id);
  return ids;
}

std::vector<int> SessionQueries::storedSessionsOf(const std::vector<FrameRecord>& frames) const {
  std::vector<int> ids;
  for (const auto& [id, s] : sessions_)
    if (restored(id) && keyframesAreFramesOf(s.frames, s.stamps, frames)) ids.push_back(id);
  return ids;
}

int SessionQueries::foreignSession(const std::string& vehicle, int remote_session) const {
  const auto it = foreign_ids_.find({vehicle, remote_session});
  return it == foreign_ids_.end() ? -1 : it->second;
}

int SessionQueries::mapOf(int session) const { return idOfBackend(backend_->mapOf(at(session).backend)); }

std::vector<int> SessionQueries::mapIds() const {
  std::vector<int> ids;
  for (int m : backend_->mapIds()) ids.push_back(idOfBackend(m));
  return ids;
}

std::vector<Pose2> SessionQueries::poses(int session) const { return backend_->sessionPoses(at(session).backend); }

std::vector<Pose2> SessionQueries::posesInSessionFrame(int session) const {
  std::vector<Pose2> p = poses(session);
  const Pose2 origin_inv = invert(p.front());
  for (Pose2& x : p) x = compose(origin_inv, x);
  return p;
}

UncertainPose2 SessionQueries::lastKeyframeInMap(int session) const {
  const Session& s = at(session);
  return backend_->keyframeInMap(s.backend, static_cast<int>(s.stamps.size()) - 1);
}

Pose2 SessionQueries::correction(int session) const {
  const Session& s = at(session);
  return compose(backend_->sessionPoses(s.backend).back(), invert(s.odometry.back()));
}

std::optional<SessionQueries::Relocalisation> SessionQueries::relocalise(int session) const {
  if (!has(session) || !at(session).origin_received) return std::nullopt;
  const Session& s = at(session);
  const auto r = backend_->relocalise(s.backend, [this](int map) {
    for (int b : backend_->chain(map))
      if (restored(idOfBackend(b))) return true;
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

std::vector<SessionLink> SessionQueries::links() const {
  std::vector<SessionLink> out;
  for (int m : backend_->mapIds())
    for (const LinkInfo& l : backend_->links(m))
      out.push_back({idOfBackend(m), idOfBackend(l.previous), idOfBackend(l.current), l.loops, l.measured, l.estimate});
  return out;
}

std::vector<SessionSummary> SessionQueries::list() const {
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

bool SessionQueries::loopRefused(std::size_t i) const {
  return i < loops_.size() && backend_->loopRecord(static_cast<int>(i)).refused;
}

Status SessionQueries::checkLinkEnds(const Loop& l) const {
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

Status SessionQueries::storedMapsMayChange(const std::string& what) const {
  if (!localising_) return Status::Ok();
  return {StatusCode::kFailedPrecondition,
          what + " is refused in localisation mode (no stored map changes): set_mode mapping first"};
}

Status SessionQueries::checkLink(const Loop& l) const {
  if (const Status ends = checkLinkEnds(l); !ends.ok()) return ends;
  if (const std::string bad = checkUncertainPose(l.z, true); !bad.empty())
    return {StatusCode::kInvalidArgument,
            "add_link: the pose: " + bad + " (x, y, yaw; m, rad; covariance m^2, rad^2, row-major)"};
  if (l.inliers < 0) return {StatusCode::kInvalidArgument, "add_link: inliers must be >= 0"};
  // Inliers are matched features of both keyframes: no more than either keyframe has. Their stored
  // feature counts when both are in the store with features, else the extractor's cap
  // (num_features), which no keyframe of this configuration exceeds.
  int most = options_.num_features;
  std::string bound = "num_features, the most features a keyframe has";
  if (l.inliers > 0 && l.inliers <= most && inStore(l.session_a, l.keyframe_a) && inStore(l.session_b, l.keyframe_b)) {
    try {
      const StoredKeyframe a = storedFeatures(l.session_a, l.keyframe_a);
      const StoredKeyframe b = storedFeatures(l.session_b, l.keyframe_b);
      // A keyframe stored without features (a sender that gives only poses) bounds nothing more.
      if (!a.points.empty() && !b.points.empty()) {
        most = static_cast<int>(std::min(a.points.size(), b.points.size()));
        bound = "the fewer features of the two keyframes";
      }
    } catch (const StoreError&) {  // unreadable: the cap still bounds it
    }
  }
  if (l.inliers > most)
    return {StatusCode::kInvalidArgument, "add_link: " + std::to_string(l.inliers) + " inliers is more than " +
                                              std::to_string(most) + " (" + bound + ")"};
  return storedMapsMayChange("add_link");
}

std::string SessionQueries::chainText(const std::vector<int>& backend_sessions) const {
  std::string t;
  for (int b : backend_sessions) t += (t.empty() ? "" : ",") + std::to_string(idOfBackend(b));
  return t;
}

std::string SessionQueries::loopsText(const std::vector<int>& backend_loops) const {
  std::string t;
  for (int i : backend_loops)  // loops_[i] is the back-end's loop i
    t += (t.empty() ? "" : " ") + loopText(loops_.at(static_cast<std::size_t>(i)));
  return t;
}

StoredKeyframe SessionQueries::storedFeatures(int session, int keyframe) const {
  if (!store_) throw StoreError("no session store: no stored features");
  const auto it = sessions_.find(session);
  if (it == sessions_.end() || it->second.store_id < 0 || !keyframeStored(session, keyframe))
    throw StoreError("session store " + options_.store_path + ": keyframe " + std::to_string(keyframe) +
                     " of session " + std::to_string(session) + " is not stored");
  StoredKeyframe k = store_->keyframeFeatures(it->second.store_id, keyframe);
  k.session = session;
  return k;
}

std::vector<StoredKeyframe> SessionQueries::storedHashes(int session) const {
  if (!store_) throw StoreError("no session store: no stored hashes");
  const auto it = sessions_.find(session);
  if (it == sessions_.end() || it->second.store_id < 0 || !restored(session))
    throw StoreError("session store " + options_.store_path + ": session " + std::to_string(session) +
                     " is not a stored session");
  std::vector<StoredKeyframe> out = store_->keyframes(it->second.store_id, SessionStore::KeyframeColumns::kHash);
  for (StoredKeyframe& k : out) k.session = session;
  return out;
}

}  // namespace core
}  // namespace uw_multislam
