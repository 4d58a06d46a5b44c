// Classifies each frame's stamp against the previous accepted one, so that a live stream or a
// replayed bag with bad timing never feeds the odometry a frame out of order or twice:
//
//   stamp == last                        kDuplicate    skip (the same frame delivered twice)
//   last - reorder_tolerance_s <= stamp  kOutOfOrder   skip (a late frame; the odometry only goes forward)
//       < last
//   stamp < last - reorder_tolerance_s   kJumpBack     new session (a bag that loops, a clock reset)
//   stamp > last + gapThreshold()        kJumpForward  new session (a gap in the recording)
//   otherwise                            kNext         process
//
// Skipped stamps do not move `last`; a jump does (the new session starts from it).
//
// A forward gap is measured against the camera's own rhythm: gapThreshold() is the larger of
// session_gap_s and gap_periods times the camera's frame period (the median of its last stamp
// intervals, passed-over frames included, jumps not). A stills camera shooting every 13-20 s, as
// survey ROVs' do, thus goes on in one session however its period compares with session_gap_s,
// while a pause of many of its periods (the vehicle surfaced, the recording stopped) still starts
// one; at video rates the rule is session_gap_s alone. Before the period is known (fewer than
// kMinIntervals intervals since the stream began) a gap must exceed gap_periods times
// session_gap_s, so that a 0.05 Hz camera is not cut at its second frame. session_gap_s 0: never.
//
// Frames the node received but dropped itself (its worker queue was full) are passOver()ed: their
// stamps move `last` as processed ones do, so the gap our own drops leave between two processed
// frames is no time gap (else a burst would split a session several times), while a
// jump among them (the camera did pause, or the bag looped) is held and reported by the next
// accept(). ROS-free: the odometry nodelet uses it with header stamps in seconds. Tested in
// test/core/test_stamp_guard.cpp.
#pragma once

#include <deque>
#include <optional>
#include <string>

namespace uw_multislam {
namespace core {

struct StampGuardOptions {
  double reorder_tolerance_s = 1.0;  // a stamp this far back at most is a late frame, further back a jump
  double session_gap_s = 10.0;       // forward jumps shorter than this never start a session; 0 = never
  /// A forward jump starts a session only beyond this many of the camera's frame periods as well
  /// (with too few intervals to know the period: beyond this many session_gap_s). >= 1.
  double gap_periods = 10.0;
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

  /// The stamp intervals the camera's period is the median of, and how many are needed to know it.
  static constexpr std::size_t kPeriodWindow = 15, kMinIntervals = 3;
  /// The camera's frame period: the median of its last kPeriodWindow stamp intervals (frames
  /// passed over included, jumps excluded); nullopt with fewer than kMinIntervals of them.
  std::optional<double> period() const;
  /// How far forward the next stamp may be from last() before it starts a session (infinite with
  /// session_gap_s 0): max(session_gap_s, gap_periods x period()), or gap_periods x session_gap_s
  /// while the period is not known.
  double gapThreshold() const;

 private:
  StampGuardOptions options_;
  /// The class of a stamp against last_ (does not change anything).
  StampClass classify(double stamp_s) const;

  bool have_last_ = false;
  double last_ = 0.0;
  double last_jump_s_ = 0.0;
  StampClass held_ = StampClass::kNext;  // a jump among passed-over stamps, for the next accept()
  std::deque<double> intervals_;         // the last stamp intervals, oldest first (period())
  // `stamp_s` (classified `c` against last_) becomes the last stamp; its interval is remembered.
  void advance(double stamp_s, StampClass c);
};

}  // namespace core
}  // namespace uw_multislam
