// What the operator and the back-end ask of the live odometry, between their callbacks and the
// odometry's worker:
//   - pause / resume (operator services): while paused the worker drops every frame (counted, its
//     stamp passed over like a queue drop, so the pause is no time gap and the session goes on).
//     A second pause, or resume while running, is refused and changes nothing.
//   - the session to record (the back-end's active_session): a new id starts a session at the
//     next frame. A message that only says another vehicle's session took an id (next_session_only)
//     asks nothing once a request was taken; its next free id is kept, for the sessions the
//     odometry starts by itself. A FINISHED session pauses the stream until the next request or
//     resume.
// Thread-safe (a mutex of its own; paused() is lock-free for the worker). ROS-free: the odometry
// nodelet's handlers lock nothing else and delegate here. Tested in test/core/test_stream_control.cpp.
#pragma once

#include <atomic>
#include <string>

#include "uw_multislam/core/common/thread_annotations.h"
#include "uw_multislam/core/frontend/stamp_guard.h"

namespace uw_multislam {
namespace core {

class StreamControl {
 public:
  /// pause (true) / resume (false); false, with nothing changed, when already in that state.
  bool setPaused(bool paused);
  bool paused() const { return paused_; }

  /// What a request did to the pause.
  enum class Effect { kNone, kPausedByFinish, kResumedAfterFinish };
  /// The back-end's request: record `session` (FINISHED: `finished`); `next_free`: the next id no
  /// session holds; `next_session_only`: only that id moved.
  Effect request(int session, int next_free, bool next_session_only, bool finished);

  /// The worker, once per frame: the session requested since the last call (-1: none) and the next free id.
  struct Requested {
    int session = -1;
    int next_free = 0;
  };
  Requested take();

  /// The worker: a frame dropped while paused; returns the count so far.
  long countDropped() { return ++dropped_paused_; }
  long droppedWhilePaused() const { return dropped_paused_; }

 private:
  Mutex mutex_;
  std::atomic<bool> paused_{false};                   // written under mutex_ (read without it)
  bool paused_by_finish_ GUARDED_BY(mutex_) = false;  // a request after finish resumes
  int requested_ GUARDED_BY(mutex_) = -1;             // -1: none
  int next_free_ GUARDED_BY(mutex_) = 0;
  bool had_request_ GUARDED_BY(mutex_) = false;  // a request was taken
  std::atomic<long> dropped_paused_{0};
};

/// Whether a frame starts a session and which, in order of precedence: the first frame (the
/// requested id, else `current`), the back-end's request of another id, a jump of the stamps
/// (`timing`), a change of camera. A session the odometry starts by itself takes the next id past
/// those other vehicles' sessions took in the back-end (requested.next_free).
struct SessionStart {
  enum class Cause { kNone, kFirstFrame, kRequested, kStampJump, kCamera };
  Cause cause = Cause::kNone;  // kNone: no session starts
  int id = 0;
  std::string why;  // for the log
  bool starts() const { return cause != Cause::kNone; }
};
SessionStart sessionStart(bool first_frame, int current, const StreamControl::Requested& requested, StampClass timing,
                          double jump_s, bool camera_changed);

}  // namespace core
}  // namespace uw_multislam
