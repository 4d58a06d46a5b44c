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
  if (!validVehicleName(vehicle)) {
    ++m.stats_.keyframes_refused;
    return {StatusCode::kInvalidArgument,
            "vehicle name '" + vehicle.substr(0, 64) + "': 1 to 64 characters of A-Z a-z 0-9 _ -"};
  }
  if (!validSessionId(input.session) || input.keyframe < 0) {
    ++m.stats_.keyframes_refused;
    return badSessionId("vehicle " + vehicle + "'s keyframe " + std::to_string(input.keyframe), input.session);
  }
  int id = m.foreignSession(vehicle, input.session);
  const auto ended = m.ended_foreign_.find({vehicle, input.session});
  // The vehicle started over (a restart on a new store numbers its sessions from 0 again): a
  // keyframe 0 of one of its sessions that records here or has ended, with another stamp, is the
  // origin of a new session (the same stamp: the origin sent twice, stale).
  const int known = id >= 0 ? id : ended != m.ended_foreign_.end() ? ended->second : -1;
  const bool again = known >= 0 && input.keyframe == 0 && m.at(known).stamps.front() != input.stamp_s;
  if (again && id >= 0) {
    m.say("vehicle " + vehicle + "'s session " + std::to_string(input.session) +
          " starts again from keyframe 0 (the vehicle restarted): session " + std::to_string(id) +
          " ends, a new one begins");
    const Status st = endSession(vehicle, input.session, m.at(id).stamps.back());
    if (!st.ok()) return st;
    id = -1;
  }
  if (id < 0) {
    if (known >= 0 && !again) {
      ++m.stats_.keyframes_stale;
      return {StatusCode::kFailedPrecondition, "vehicle " + vehicle + "'s session " + std::to_string(input.session) +
                                                   " has ended: keyframe " + std::to_string(input.keyframe) +
                                                   " skipped"};
    }
    if (input.keyframe > m.options_.max_keyframe_gap) {
      ++m.stats_.keyframes_refused;
      return {StatusCode::kInvalidArgument, "keyframe " + std::to_string(input.keyframe) + " starts vehicle " +
                                                vehicle + "'s session " + std::to_string(input.session) +
                                                ": more than max_keyframe_gap keyframes missing"};
    }
    if (m.nextId() > kMaxSessionId)
      return {StatusCode::kResourceExhausted,
              "no session id left for vehicle " + vehicle + "'s session " + std::to_string(input.session)};
    // A name taken (this vehicle's session of an earlier run, or one it started over): _2, _3, ...
    const std::string base = vehicle + "_session_" + std::to_string(input.session);
    std::string name = base;
    for (int n = 2; m.idOfName(name) >= 0; ++n) name = base + "_" + std::to_string(n);
    id = m.nextId();
    m.ended_foreign_.erase({vehicle, input.session});
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
  const int id = m.foreignSession(vehicle, remote_session);
  if (id < 0)
    return {StatusCode::kNotFound,
            "vehicle " + vehicle + " has no session " + std::to_string(remote_session) + " recording here"};
  auto& s = m.at(id);
  m.backend_->endSession(s.backend);  // first: a throw leaves it recording here, as it was
  m.foreign_ids_.erase({vehicle, remote_session});
  m.ended_foreign_[{vehicle, remote_session}] = id;
  m.storeWrite("ending a session", [&] {
    if (s.store_id >= 0) m.store_->endSession(s.store_id, stamp_s);
  });
  m.emit(SessionEvent::Kind::kSessionEnded, id, -1, m.mapOf(id),
         "session " + std::to_string(id) + " (vehicle " + vehicle + "'s session " + std::to_string(remote_session) +
             ") ended with " + std::to_string(s.stamps.size()) + " keyframes");
  m.afterBackendChange();
  m.saveMaps();
  return Status::Ok();
}

int FleetSessions::finishAll() {
  SessionManager& m = *manager_;
  std::vector<std::pair<std::string, int>> recording;
  for (const auto& [key, id] : m.foreign_ids_) recording.push_back(key);
  int ended = 0;
  for (const auto& [vehicle, remote] : recording)
    ended += endSession(vehicle, remote, m.at(m.foreignSession(vehicle, remote)).stamps.back()).ok() ? 1 : 0;
  return ended;
}

}  // namespace core
}  // namespace uw_multislam
