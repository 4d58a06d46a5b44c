// The front end of one camera, for every head: the mirror of the SessionManager for frames. One
// object takes each paired frame (image, camera, the camera's altitude, its nav, its stamp) and does
// everything up to a finished keyframe, in one order for offline_slam (core::Pipeline) and the
// odometry nodelet alike:
//   1. stamps (StampGuard): duplicates and late frames skipped; a jump back, or a forward gap far
//      beyond the camera's own frame period, starts a session (stamp_guard.h);
//   2. session starts, in order of precedence (core::sessionStart, stream_control.h): the first
//      frame of a stream, the back-end's request of another id, a stamp jump, a camera change. The
//      session that was open ends there; the new one takes its id at its first keyframe;
//   3. the nav at the frame's stamp, asked only now (a head's buffer of the clock before a jump
//      back is dropped first: FrameInput::nav);
//   4. odometry and tracking loss (SegmentedOdometry: a session closed after tracking.max_fallbacks
//      unmatched frames, the next one started at the first frame with enough features), keyframe
//      choice with the lookahead, the skip rule's bookkeeping (FrameSkipRule::observe);
//   5. each released keyframe as the SessionManager's KeyframeInput, hashed once (paper (6)(7)),
//      with the nav's placement attached (NavPlacer, nav_placer.h);
//   6. counts.
// It returns what happened (FrameResult): the pose and its covariance, the keyframes, the sessions
// started and ended, what was skipped and why, lines for the log.
//
// Session ids: a head that owns them (offline, the SessionManager) gives SessionHooks; without, the
// stream numbers its sessions itself as the live odometry does: the first from `first_session`
// (or the back-end's request), each later one past the last and past the back-end's next free id
// (StreamControl::Requested::next_free).
//
// Not thread-safe: one thread feeds it (the odometry's worker, offline_slam's loop). ROS-free;
// tested in test/core/session/test_frame_stream.cpp.
#pragma once

#include <opencv2/core.hpp>

#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "uw_multislam/core/frontend/frame_skip.h"
#include "uw_multislam/core/frontend/stamp_guard.h"
#include "uw_multislam/core/frontend/stream_control.h"
#include "uw_multislam/core/frontend/tracking.h"
#include "uw_multislam/core/loops/haloc.h"
#include "uw_multislam/core/session/nav_placer.h"
#include "uw_multislam/core/session/session_queries.h"
#include "uw_multislam/core/session/slam_config.h"

namespace uw_multislam {
namespace core {

/// One paired frame.
struct FrameInput {
  cv::Mat image;  // 8-bit BGR or grey
  CameraIntrinsics camera;
  double altitude_m = 0.0;  // the camera's (not finite or <= 0: the last valid one is reused)
  double stamp_s = 0.0;
  /// The frame's index (frames.csv's); < 0: numbered by the stream from 0 at each session start.
  int index = -1;
  /// The nav at the frame's stamp, asked once the frame passed the stamp checks; its argument is
  /// true when the stamps just jumped back (a bag that loops, a clock reset): readings of the clock
  /// before must not be used. Empty: no nav.
  std::function<std::optional<NavRecord>(bool clock_jumped_back)> nav;
  /// The back-end's request since the last frame (live; offline none).
  StreamControl::Requested requested;
  /// The frame's image prepared ahead with `camera` (may be null; moved from).
  PreparedFrame* prepared = nullptr;
  /// OdometryInput::keyframe_lookahead_s: used only while the skip rule predicts (frames are then
  /// taken newest first); 0 otherwise.
  double keyframe_lookahead_s = 0.0;
};

/// Why a session starts.
enum class SessionCause {
  kFirstFrame,       // the first frame of a stream
  kRequested,        // the back-end asked for another id (start_session)
  kStampJump,        // the stamps jumped back, or forward beyond the gap rule
  kCamera,           // the camera's intrinsics changed
  kTrackingResumed,  // the first good frame after a tracking loss
};
const char* sessionCauseName(SessionCause c);

/// Why a session ends.
enum class SessionEnd {
  kTrackingLoss,  // tracking.max_fallbacks unmatched frames
  kNextSession,   // another one starts (a request, a stamp jump, a camera change)
  kStreamEnd,     // endStream()
};

/// A session the stream opens, at its first keyframe (SessionHooks::open).
struct SessionOpening {
  SessionCause cause = SessionCause::kFirstFrame;
  int proposed = 0;  // the id the stream gives without hooks
  double stamp_s = 0.0;
  int piece = 0;    // its number in the stream: 0, then 1, 2, ... (one per session started)
  std::string why;  // for the log
};

/// A session that ends (SessionHooks::close), with its odometry (valid during the call only).
struct SessionClosing {
  int session = -1;
  SessionEnd cause = SessionEnd::kNextSession;
  double stamp_s = 0.0;  // the session's last frame
  const Odometry* odometry = nullptr;
};

/// What the owner of the session ids does when the stream opens or ends a session.
struct SessionHooks {
  std::function<int(const SessionOpening&)> open;    // returns the id; empty: `proposed`
  std::function<void(const SessionClosing&)> close;  // may be empty
};

/// A released keyframe, ready to send: the SessionManager's input (no thumbnail: the head has the
/// image) and how its motion was measured.
struct StreamKeyframe {
  KeyframeInput input;  // session, ids, motion and its source, odometry pose, hash, nav placement
  MatchSummary match;   // of a matched keyframe (zeros for the first and fallbacks)
  bool fallback = false;
};

/// The keyframe `kf` of `odometry` (of session `session`) as StreamKeyframe, hashed by `hasher`
/// (null: no hash).
StreamKeyframe streamKeyframe(const Odometry& odometry, const Odometry::NewKeyframe& kf, int session,
                              const ImageHasher* hasher);

/// What happened to one frame.
struct FrameResult {
  StampClass timing = StampClass::kNext;
  double jump_s = 0.0;  // timing a jump: by how much (negative back)
  /// Skipped before the odometry: a duplicate or late stamp (`timing` says which). Nothing else
  /// happened.
  bool skipped_stamp = false;
  OdometryUpdate update;  // the odometry's (status kSkipped, with its reason, when not used)
  bool moved = false;     // the odometry took the frame: update.pose and covariance in `session`
  int session = -1;       // the session of update.pose (-1: none open, e.g. tracking lost)
  bool with_nav = false;  // the frame had a nav reading
  struct Started {
    int session;
    SessionCause cause;
    std::string why;
  };
  std::optional<Started> started;  // a session began at this frame (its first keyframe)
  struct Ended {
    int session;
    SessionEnd cause;
    std::string why;  // for the log (a tracking loss: which rule)
  };
  std::vector<Ended> ended;  // sessions that ended at this frame
  std::vector<StreamKeyframe> keyframes;
  std::vector<std::string> notes;     // for the log: the nav's placements
  std::vector<std::string> warnings;  // for the log, as warnings: a placement refused, the gap rule's
};

/// Counts since the stream object was made (every stream).
struct FrameStreamCounts {
  long frames = 0;              // fed
  long duplicates = 0;          // skipped: a stamp seen before
  long out_of_order = 0;        // skipped: a stamp up to reorder_tolerance_s back
  long jumps_back = 0;          // stamps jumped back: a new session
  long jumps_forward = 0;       // stamps jumped forward past the gap rule: a new session
  long sessions = 0;            // sessions started
  long tracking_losses = 0;     // sessions ended by tracking loss
  long keyframes = 0;           // released
  long placements = 0;          // keyframes placed by the nav
  long bridges = 0;             // pieces placed by a visual bridge (tracking.rejoin_keyframes)
  long rejoin_tries = 0;        // keyframes registered with the piece before theirs for a bridge
  long dense_tries = 0;         // dense registrations tried (the normal one failed; odometry.dense)
  long dense_matches = 0;       // ... accepted
  long restarts = 0;            // tracking losses where a frame registers only with the unmatched one before it
  long placements_refused = 0;  // placements refused: the nav's step across the gap is no vehicle's motion
};

class FrameStream {
 public:
  /// `config`: the odometry, tracking loss and hash settings; `stamps`: the stamp rules;
  /// `first_session`: the first id without hooks; `hasher`: the keyframes' (the SessionManager's,
  /// which must outlive the stream; null: one of the stream's own from `config`). Throws
  /// std::invalid_argument on bad options.
  FrameStream(const SlamConfig& config, const StampGuardOptions& stamps, SessionHooks hooks = {}, int first_session = 0,
              const ImageHasher* hasher = nullptr);
  FrameStream(const FrameStream&) = delete;
  FrameStream& operator=(const FrameStream&) = delete;

  /// A new camera stream (a dataset folder; live, once): its stamps start afresh and its first
  /// usable frame starts a session. `nav_frame`: the declared world frame its nav is in (offline:
  /// nav_frame.yaml; live: ~nav_world_fixed), where sessions are placed against each other. Ends
  /// the open session first.
  void beginStream(std::optional<NavFrame> nav_frame = std::nullopt);
  /// Ends the stream's open session (at `stamp_s`, its last frame's).
  void endStream(double stamp_s);

  /// Stamps of frames received and not processed (dropped by a queue, skipped for a newer one,
  /// paused): seen, so the gap they leave is no time gap (StampGuard::passOver).
  void passOver(const std::vector<double>& stamps_s);
  /// One frame (see the file comment).
  FrameResult process(FrameInput in);

  /// The session open now (-1: none); the last one's id while tracking is lost.
  int session() const { return open_ ? session_ : -1; }
  int lastSession() const { return session_; }
  /// The odometry of the current session (null before the first frame).
  const SegmentedOdometry* odometry() const { return segmented_.get(); }
  /// The skip rule of the current session (null before the first frame): the live worker's choice.
  const FrameSkipRule* skipRule() const { return skip_rule_ ? &*skip_rule_ : nullptr; }
  const StampGuard& stamps() const { return *stamps_; }
  const FrameStreamCounts& counts() const { return counts_; }
  /// Every odometry's timings, the finished sessions' included.
  StageTimes times() const;

 private:
  // A session begins at this frame (its odometry restarts; its id comes at its first keyframe).
  void restart(const SessionStart& start, const CameraIntrinsics& camera, FrameResult* r);
  void end(SessionEnd cause, double stamp_s, FrameResult* r, std::string why = {});
  void open(SessionCause cause, int proposed, const std::string& why, double stamp_s, FrameResult* r);
  void release(const SegmentedOdometry::Step& step, FrameResult* r);

  SlamConfig config_;
  StampGuardOptions stamp_options_;
  SessionHooks hooks_;
  std::optional<ImageHasher> own_hasher_;
  const ImageHasher* hasher_ = nullptr;
  NavPlacer placer_;
  std::unique_ptr<StampGuard> stamps_;
  std::unique_ptr<SegmentedOdometry> segmented_;
  std::optional<FrameSkipRule> skip_rule_;
  CameraIntrinsics camera_;  // the session's
  bool first_ = true;        // the next frame is its stream's first
  bool any_session_ = false;
  bool open_ = false;                           // session_ is open
  int session_ = 0;                             // the open (or last) session's id
  int previous_session_ = -1;                   // the last session that ended (a placement's anchor)
  std::optional<SessionStart> pending_;         // the cause of the session the next piece starts
  int next_free_ = 0;                           // the back-end's next free id (requests)
  int frame_index_ = 0;                         // frames since the session start (FrameInput::index < 0)
  int pieces_ = 0;                              // sessions started in this stream
  double last_stamp_ = 0.0;                     // of the last frame the odometry took
  bool warned_period_ = false;                  // the gap rule's warning given
  std::optional<NavPlacement> held_placement_;  // the odometry's placement, until a keyframe is released
  FrameStreamCounts counts_;
  StageTimes finished_;  // finished odometries' timings
  long retired_dense_tries_ = 0, retired_dense_matches_ = 0, retired_restarts_ = 0, retired_rejoin_tries_ = 0;
};

}  // namespace core
}  // namespace uw_multislam
