// Other vehicles' sessions (the hash exchange between vehicles): FleetSessions.
#include "uw_multislam/core/session/session_manager.h"

#include <cctype>
#include <string>
#include <utility>

#include "session_detail.h"

namespace uw_multislam {
namespace core {

using namespace session_detail;  // NOLINT: the manager's own helpers

bool validVehicleName(const std::string& v) {
  if (v.empty() || v.size() > 64) return false;
  for (char c : v)
    if (!std::isalnum(static_cast<unsigned char>(c)) && c != '_' && c != '-') return false;
  return true;
}

Status FleetSessions::addKeyframe(const std::string& vehicle, const KeyframeInput& input, int* local_id) {
  SessionManager& m = *manager_;
  SessionTable& t = m.table_;
  SessionManagerStats& stats = t.stats();
  if (!validVehicleName(vehicle)) {
    ++stats.keyframes_refused;
    return {StatusCode::kInvalidArgument,
            "vehicle name '" + vehicle.substr(0, 64) + "': 1 to 64 characters of A-Z a-z 0-9 _ -"};
  }
  if (!validSessionId(input.session) || input.keyframe < 0) {
    ++stats.keyframes_refused;
    return badSessionId("vehicle " + vehicle + "'s keyframe " + std::to_string(input.keyframe), input.session);
  }
  int id = t.foreignSession(vehicle, input.session);
  // The vehicle started over (a restart on a new store numbers its sessions from 0 again): a
  // keyframe 0 of one of its sessions that records here or has ended, with another stamp, is the
  // origin of a new session (the same stamp: the origin sent twice, stale).
  const int known = id >= 0 ? id : t.endedForeignSession(vehicle, input.session);
  const bool again = known >= 0 && input.keyframe == 0 && t.at(known).stamps.front() != input.stamp_s;
  if (again && id >= 0) {
    m.say("vehicle " + vehicle + "'s session " + std::to_string(input.session) +
          " starts again from keyframe 0 (the vehicle restarted): session " + std::to_string(id) +
          " ends, a new one begins");
    const Status st = endSession(vehicle, input.session, t.at(id).stamps.back());
    if (!st.ok()) return st;
    id = -1;
  }
  if (id < 0) {
    if (known >= 0 && !again) {
      ++stats.keyframes_stale;
      return {StatusCode::kFailedPrecondition, "vehicle " + vehicle + "'s session " + std::to_string(input.session) +
                                                   " has ended: keyframe " + std::to_string(input.keyframe) +
                                                   " skipped"};
    }
    if (input.keyframe > t.options().max_keyframe_gap) {
      ++stats.keyframes_refused;
      return {StatusCode::kInvalidArgument, "keyframe " + std::to_string(input.keyframe) + " starts vehicle " +
                                                vehicle + "'s session " + std::to_string(input.session) +
                                                ": more than max_keyframe_gap keyframes missing"};
    }
    if (t.nextId() > kMaxSessionId)
      return {StatusCode::kResourceExhausted,
              "no session id left for vehicle " + vehicle + "'s session " + std::to_string(input.session)};
    // A name taken (this vehicle's session of an earlier run, or one it started over): _2, _3, ...
    const std::string base = vehicle + "_session_" + std::to_string(input.session);
    std::string name = base;
    for (int n = 2; t.idOfName(name) >= 0; ++n) name = base + "_" + std::to_string(n);
    id = t.nextId();
    m.open(id, name, input.stamp_s, vehicle, input.session);
  }
  if (local_id) *local_id = id;
  KeyframeInput k = input;
  k.session = id;
  // Only what crossed the link is kept: no features (asked of the vehicle when needed), no image.
  k.features = FrameFeatures();
  k.thumbnail.clear();
  return m.appendKeyframe(std::move(k), {});
}

Status FleetSessions::endSession(const std::string& vehicle, int remote_session, double stamp_s) {
  SessionManager& m = *manager_;
  SessionTable& t = m.table_;
  const int id = t.foreignSession(vehicle, remote_session);
  if (id < 0)
    return {StatusCode::kNotFound,
            "vehicle " + vehicle + " has no session " + std::to_string(remote_session) + " recording here"};
  t.endForeign(vehicle, remote_session);
  const SessionTable::Session& s = t.at(id);
  m.storeWrite("ending a session", [&] {
    if (s.storeRow() >= 0) t.store()->endSession(s.storeRow(), stamp_s);
  });
  m.emit(SessionEvent::Kind::kSessionEnded, id, -1, m.view_.mapOf(id),
         "session " + std::to_string(id) + " (vehicle " + vehicle + "'s session " + std::to_string(remote_session) +
             ") ended with " + std::to_string(s.stamps.size()) + " keyframes");
  m.afterBackendChange();
  m.saveMaps();
  return Status::Ok();
}

int FleetSessions::finishAll() {
  const SessionTable& t = manager_->table_;
  const std::vector<std::pair<std::string, int>> recording = t.foreignRecording();
  int ended = 0;
  for (const auto& [vehicle, remote] : recording)
    ended += endSession(vehicle, remote, t.at(t.foreignSession(vehicle, remote)).stamps.back()).ok() ? 1 : 0;
  return ended;
}

}  // namespace core
}  // namespace uw_multislam
