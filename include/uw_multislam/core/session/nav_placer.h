// The nav's placement of each new piece and session of a camera stream (core::FrameStream's, for
// offline_slam and the odometry nodelet alike), so that it is in its predecessor's map from its
// first keyframe instead of a map of its own until visual loops come:
//   - a piece after a tracking loss: the odometry's placement (SegmentedOdometry::Step::placement,
//     one dead reckoning) against a keyframe of the piece before it;
//   - a new session (a new stream, start_session, a stamp jump, a camera change) whose nav is in a
//     declared world frame (offline: nav_frame.yaml; live: ~nav_world_fixed): against the last
//     keyframe with an accepted nav reading in the same world frame (navPlacement, the two dead
//     reckonings' errors independent).
// Only accepted readings place anything: both ends are readings the odometry accepted at released
// keyframes, and the step between them across the gap must be one the vehicle could make
// (navStepImplausible, the test the odometry applies to each reading; across two streams, whose
// clocks need not be one, it is not applied). A nav that jumped while vision was lost is refused
// (counted, said) rather than placing the piece where the jump puts it. Nothing is invented:
// without an anchor a session is not placed.
#pragma once

#include <map>
#include <optional>
#include <string>

#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/frontend/nav_prior.h"
#include "uw_multislam/core/frontend/tracking.h"
#include "uw_multislam/core/session/session_queries.h"

namespace uw_multislam {
namespace core {

/// A keyframe with an accepted nav reading: where a later session is placed from.
struct NavAnchor {
  int session = -1, keyframe = -1;
  NavRecord nav;
  NavFrame frame;   // the declared world frame of its nav
  int stream = -1;  // the stream it came from (FrameStream::beginStream's count)
};

/// The nav's placement of a new session's keyframe, whose accepted reading is `first`, against
/// `anchor` (a keyframe of an earlier session whose nav is in the same world frame): `first`'s nav
/// pose in `anchor`'s, the two sessions' dead-reckoning errors taken as independent
/// (navPlacement, not one track).
NavPlacementInput placeAgainst(const NavAnchor& anchor, const NavRecord& first, const NavPriorOptions& options);

/// "against session S keyframe K: (x m, y m, yaw rad), sigma s m, s rad", for the log.
std::string describePlacement(const NavPlacementInput& p);

/// Two nav_frame.yaml declare one world frame when they name it alike: the convention is only how
/// nav.csv's rows are written (both are read into the same ENU frame), and an origin given in one
/// file but not the other is the same frame; two different origins under one name are not.
bool sameWorldFrame(const NavFrame& a, const NavFrame& b);

class NavPlacer {
 public:
  explicit NavPlacer(const NavPriorOptions& nav = {});

  /// A new stream, its nav in `frame` (none: its sessions are not placed against other sessions).
  void beginStream(std::optional<NavFrame> frame);
  /// The current piece ended: its readings are where the next piece is placed from.
  void pieceEnded();
  /// A released keyframe of `session` with its reading (the odometry's accepted one, if any).
  void released(int session, int keyframe, const std::optional<NavRecord>& nav);

  struct Placed {
    std::optional<NavPlacementInput> placement;
    bool refused = false;  // a placement the nav gave was refused (the step across the gap)
    std::string said;      // not empty: a line for the log
  };
  /// After a tracking loss: the odometry's placement `p` of keyframe `keyframe` of `session`, whose
  /// reading is `here`, against keyframe p.keyframe of `previous` (the piece before).
  Placed afterLoss(const NavPlacement& p, int previous, int session, int keyframe,
                   const std::optional<NavRecord>& here);
  /// After a tracking loss: keyframe `keyframe` of `session` registered with keyframe p.keyframe of
  /// `previous` (p.visual, SegmentedOdometry's rejoin): placed by that registration, no nav needed.
  static Placed bridged(const NavPlacement& p, int previous, int session, int keyframe);
  /// Keyframe 0 of a new session (not a piece after a tracking loss), whose reading is `here`.
  Placed newSession(int session, const std::optional<NavRecord>& here);

  /// The last keyframe with an accepted reading in a declared world frame (the next session's).
  const std::optional<NavAnchor>& anchor() const { return anchor_; }

 private:
  // Empty when the nav's step from `from` to `to` could be the vehicle's; else why not.
  std::string implausible(const NavRecord& from, const NavRecord& to) const;

  NavPriorOptions nav_;
  std::optional<NavFrame> frame_;  // the current stream's
  int stream_ = -1;
  std::map<int, NavRecord> piece_, previous_piece_;  // keyframe -> accepted reading, current and last piece
  std::optional<NavAnchor> anchor_;
  bool said_unknown_ = false;  // "nothing known to place it against" said already
};

}  // namespace core
}  // namespace uw_multislam
