#include "uw_multislam/core/frontend/stream_control.h"

#include <algorithm>
#include <utility>

namespace uw_multislam {
namespace core {

bool StreamControl::setPaused(bool paused) {
  MutexLock lock(&mutex_);
  if (paused_ == paused) return false;
  paused_ = paused;
  paused_by_finish_ = false;
  return true;
}

StreamControl::Effect StreamControl::request(int session, int next_free, bool next_session_only, bool finished) {
  MutexLock lock(&mutex_);
  next_free_ = next_free;
  // Another vehicle's session took an id: nothing is asked of us (a subscriber that comes now, a
  // respawned odometry, takes the request it repeats).
  if (next_session_only && had_request_) return Effect::kNone;
  had_request_ = true;
  requested_ = session;
  if (finished) {  // no session records: frames are dropped until the next request or resume
    paused_ = true;
    paused_by_finish_ = true;
    return Effect::kPausedByFinish;
  }
  if (paused_by_finish_) {
    paused_ = false;
    paused_by_finish_ = false;
    return Effect::kResumedAfterFinish;
  }
  return Effect::kNone;
}

StreamControl::Requested StreamControl::take() {
  MutexLock lock(&mutex_);
  Requested r;
  std::swap(r.session, requested_);
  r.next_free = next_free_;
  return r;
}

SessionStart sessionStart(bool first_frame, int current, const StreamControl::Requested& requested, StampClass timing,
                          double jump_s, bool camera_changed) {
  using C = SessionStart::Cause;
  const int next_own = std::max(current + 1, requested.next_free);
  if (first_frame) return {C::kFirstFrame, requested.session >= 0 ? requested.session : current, "first frame"};
  if (requested.session >= 0 && requested.session != current)
    return {C::kRequested, requested.session, "requested on active_session"};
  if (StampGuard::startsSession(timing))
    return {C::kStampJump, next_own, "image stamps jumped by " + std::to_string(jump_s) + " s"};
  if (camera_changed) return {C::kCamera, next_own, "camera intrinsics changed"};
  return {};
}

}  // namespace core
}  // namespace uw_multislam
