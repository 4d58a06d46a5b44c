// The nav's placement of each new piece and session of a live odometry stream (the odometry
// nodelet's; offline, core::Pipeline places its streams' sessions with the same functions): the
// first keyframe of a piece after a tracking loss against the piece before it (one dead
// reckoning: SegmentedOdometry::Step::placement), and, when the nav is in a world-fixed frame (one
// that does not reset between sessions), the first keyframe of a new session (start_session, a
// camera change, a stamp jump) against the last keyframe with an accepted nav reading of the
// sessions before it. Nothing is invented: without such a keyframe (the first session since the
// odometry started) a session is not placed.
#pragma once

#include <optional>
#include <string>

#include "uw_multislam/core/frontend/nav_prior.h"
#include "uw_multislam/core/frontend/tracking.h"
#include "uw_multislam/core/session/session_queries.h"

namespace uw_multislam {
namespace core {

/// A keyframe with an accepted nav reading: where a later session is placed from.
struct NavAnchor {
  int session = -1, keyframe = -1;
  NavRecord nav;
};

/// The nav's placement of a new session's keyframe 0, whose accepted reading is `first`, against
/// `anchor` (a keyframe of an earlier session whose nav is in the same world frame): `first`'s nav
/// pose in `anchor`'s, the two sessions' dead-reckoning errors taken as independent
/// (navPlacement, not one track).
NavPlacementInput placeAgainst(const NavAnchor& anchor, const NavRecord& first, const NavPriorOptions& options);

/// "against session S keyframe K: (x m, y m, yaw rad), sigma s m, s rad", for the log.
std::string describePlacement(const NavPlacementInput& p);

class NavSessionPlacer {
 public:
  /// `world_fixed`: the nav's frame does not reset between sessions, so that a new session can be
  /// placed against an earlier one (the odometry's ~nav_world_fixed).
  NavSessionPlacer(const NavPriorOptions& nav = {}, bool world_fixed = false);

  struct Sent {
    std::optional<NavPlacementInput> placement;  // for the started piece's keyframe 0
    std::string said;  // not empty: a line for the log (the placement, or why a new session has none)
  };
  /// After `odometry.process()` gave `step`, whose keyframes go out as session `session`: the
  /// nav's placement of the piece or session that step started, if any; then the step's released
  /// keyframes' latest with a nav reading becomes the anchor. That nothing is known to place a new
  /// session against is said once.
  Sent step(const SegmentedOdometry::Step& step, const SegmentedOdometry& odometry, int session);

  /// The last keyframe with an accepted nav reading seen so far (the next session's anchor).
  const std::optional<NavAnchor>& anchor() const { return anchor_; }

 private:
  std::optional<NavPlacementInput> place(const SegmentedOdometry::Step& step, const SegmentedOdometry& odometry,
                                         int session, std::string* said);

  NavPriorOptions nav_;
  bool world_fixed_ = false;
  std::optional<NavAnchor> anchor_;
  bool said_unknown_ = false;  // "nothing known to place it against" said already
};

}  // namespace core
}  // namespace uw_multislam
