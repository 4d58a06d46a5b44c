#include "uw_multislam/core/session/nav_session_placer.h"

#include <cmath>
#include <cstdio>

namespace uw_multislam {
namespace core {

NavPlacementInput placeAgainst(const NavAnchor& anchor, const NavRecord& first, const NavPriorOptions& options) {
  NavPlacementInput p;
  p.session = anchor.session;
  p.keyframe = anchor.keyframe;
  p.z = navPlacement(anchor.nav, first, options, false);  // two dead reckonings: independent errors
  return p;
}

std::string describePlacement(const NavPlacementInput& p) {
  char line[200];
  std::snprintf(line, sizeof line, "against session %d keyframe %d: (%.3f m, %.3f m, %.3f rad), sigma %.3f m, %.4f rad",
                p.session, p.keyframe, p.z.mean.x(), p.z.mean.y(), p.z.mean.yaw(), std::sqrt(p.z.covariance(0, 0)),
                std::sqrt(p.z.covariance(2, 2)));
  return line;
}

NavSessionPlacer::NavSessionPlacer(const NavPriorOptions& nav, bool world_fixed)
    : nav_(nav), world_fixed_(world_fixed) {}

NavSessionPlacer::Sent NavSessionPlacer::step(const SegmentedOdometry::Step& step, const SegmentedOdometry& odometry,
                                              int session) {
  Sent sent;
  if (step.session_started && odometry.odometry()) sent.placement = place(step, odometry, session, &sent.said);
  // Released keyframes are sent and kept (a close drops only the held ones): the latest with a
  // reading is where the next piece or session is placed from.
  if (const Odometry* odo = odometry.odometry()) {
    const std::vector<Odometry::NewKeyframe>& released = odometry.newKeyframes();
    for (auto kf = released.rbegin(); kf != released.rend(); ++kf) {
      const std::optional<NavRecord>& nav = odo->keyframes().at(static_cast<std::size_t>(kf->id)).nav;
      if (nav) {
        anchor_ = NavAnchor{session, kf->id, *nav};
        break;
      }
    }
  }
  return sent;
}

std::optional<NavPlacementInput> NavSessionPlacer::place(const SegmentedOdometry::Step& step,
                                                         const SegmentedOdometry& odometry, int session,
                                                         std::string* said) {
  if (!nav_.enabled || !nav_.place_pieces) return std::nullopt;
  const std::string who = "session " + std::to_string(session);
  if (odometry.sessions() > 1) {
    // A piece after a tracking loss: the odometry's placement (one dead reckoning) against the
    // closed piece's last keyframe with a reading, which is the anchor this placer kept of it.
    if (!step.placement || !anchor_ || anchor_->keyframe != step.placement->keyframe) return std::nullopt;
    const NavPlacementInput p{anchor_->session, step.placement->keyframe, step.placement->z};
    *said = who + " placed by the nav after the tracking loss " + describePlacement(p);
    return p;
  }
  // The first piece of a new odometry (a new session): only a world-fixed nav relates it to the
  // sessions before it.
  if (!world_fixed_) return std::nullopt;
  if (!anchor_) {
    if (!said_unknown_)
      *said = who +
              " is not placed by the nav: no earlier keyframe with a nav reading is known (none since the odometry "
              "started); later sessions are placed against this one's";
    said_unknown_ = true;
    return std::nullopt;
  }
  const std::optional<NavRecord>& here = odometry.odometry()->keyframes().front().nav;
  if (!here || anchor_->session == session) {
    *said = who + " is not placed by the nav: " +
            (here ? "its anchor is of the same session" : "its first keyframe has no accepted nav reading");
    return std::nullopt;
  }
  const NavPlacementInput p = placeAgainst(*anchor_, *here, nav_);
  *said = who + " placed by the nav in its world-fixed frame " + describePlacement(p);
  return p;
}

}  // namespace core
}  // namespace uw_multislam
