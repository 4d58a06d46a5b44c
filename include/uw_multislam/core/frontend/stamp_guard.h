// Classifies each frame's stamp against the previous accepted one, so that a live stream or a
// replayed bag with bad timing never feeds the odometry a frame out of order or twice:
//
//   stamp == last                        kDuplicate    skip (the same frame delivered twice)
//   last - reorder_tolerance_s <= stamp  kOutOfOrder   skip (a late frame; the odometry only goes forward)
//       < last
//   stamp < last - reorder_tolerance_s   kJumpBack     new session (a bag that loops, a clock reset)
//   stamp > last + session_gap_s         kJumpForward  new session (a gap in the recording; 0 = never)
//   otherwise                            kNext         process
//
// Skipped stamps do not move `last`; a jump does (the new session starts from it).
//
// Frames the node received but dropped itself (its worker queue was full) are passOver()ed: their
// stamps move `last` as processed ones do, so the gap our own drops leave between two processed
// frames is no time gap (else a burst would split a session several times), while a
// jump among them (the camera did pause, or the bag looped) is held and reported by the next
// accept(). ROS-free: the odometry nodelet uses it with header stamps in seconds. Tested in
// test/core/test_stamp_guard.cpp.
#pragma once

#include <string>

namespace uw_multislam {
namespace core {

struct StampGuardOptions {
  double reorder_tolerance_s = 1.0;  // a stamp this far back at most is a late frame, further back a jump
  double session_gap_s = 10.0;       // forward jumps longer than this start a session; 0 = never
  /// Empty when valid, else a sentence naming the bad value.
  std::string validate() const;
};

enum class StampClass { kFirst, kNext, kDuplicate, kOutOfOrder, kJumpBack, kJumpForward };
std::string stampClassName(StampClass c);

class StampGuard {
 public:
  explicit StampGuard(const StampGuardOptions& options = StampGuardOptions());
  /// Classifies `stamp_s` and, unless it is skipped (duplicate, out of order), accepts it as the
  /// new last stamp. A non-finite stamp is classified kOutOfOrder (skipped) and not accepted.
  StampClass accept(double stamp_s);
  /// A frame that was received but not processed (dropped by the node's own queue): its stamp
  /// is classified and accepted like accept()'s, but a jump is held and returned by the next
  /// accept() that is not skipped. Duplicates, late and non-finite stamps change nothing.
  void passOver(double stamp_s);
  /// How far the stamps jumped at the last jump (seconds; negative back, positive forward),
  /// measured from the stamp before it, passed over or not.
  double lastJump() const { return last_jump_s_; }
  /// True for the classes whose frame must be skipped.
  static bool skips(StampClass c) { return c == StampClass::kDuplicate || c == StampClass::kOutOfOrder; }
  /// True for the classes that start a new session.
  static bool startsSession(StampClass c) { return c == StampClass::kJumpBack || c == StampClass::kJumpForward; }
  /// The last accepted stamp (seconds); meaningless before the first.
  double last() const { return last_; }
  bool empty() const { return !have_last_; }

 private:
  StampGuardOptions options_;
  /// The class of a stamp against last_ (does not change anything).
  StampClass classify(double stamp_s) const;

  bool have_last_ = false;
  double last_ = 0.0;
  double last_jump_s_ = 0.0;
  StampClass held_ = StampClass::kNext;  // a jump among passed-over stamps, for the next accept()
};

}  // namespace core
}  // namespace uw_multislam
