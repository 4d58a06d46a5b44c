#include "uw_multislam/core/session/nav_placer.h"

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

bool sameWorldFrame(const NavFrame& a, const NavFrame& b) {
  return a.name == b.name &&
         (!a.has_origin || !b.has_origin || (a.latitude_deg == b.latitude_deg && a.longitude_deg == b.longitude_deg));
}

NavPlacer::NavPlacer(const NavPriorOptions& nav) : nav_(nav) {}

void NavPlacer::beginStream(std::optional<NavFrame> frame) {
  frame_ = std::move(frame);
  ++stream_;
  piece_.clear();
  previous_piece_.clear();
}

void NavPlacer::pieceEnded() {
  previous_piece_ = std::move(piece_);
  piece_.clear();
}

void NavPlacer::released(int session, int keyframe, const std::optional<NavRecord>& nav) {
  if (!nav) return;
  piece_[keyframe] = *nav;
  if (frame_) anchor_ = NavAnchor{session, keyframe, *nav, *frame_, stream_};
}

std::string NavPlacer::implausible(const NavRecord& from, const NavRecord& to) const {
  return navStepImplausible(from, to, nav_);
}

NavPlacer::Placed NavPlacer::afterLoss(const NavPlacement& p, int previous, int session, int keyframe,
                                       const std::optional<NavRecord>& here) {
  Placed out;
  if (!nav_.enabled || !nav_.place_pieces || previous < 0) return out;
  const std::string who = "session " + std::to_string(session) + " keyframe " + std::to_string(keyframe);
  const auto from = previous_piece_.find(p.keyframe);
  std::string bad;
  if (from == previous_piece_.end()) {
    bad = "keyframe " + std::to_string(p.keyframe) + " of session " + std::to_string(previous) +
          " has no accepted nav reading";
  } else if (!here) {
    bad = "it has no accepted nav reading";
  } else {
    bad = implausible(from->second, *here);
  }
  if (!bad.empty()) {
    out.refused = true;
    out.said = who + " is not placed by the nav after the tracking loss: " + bad +
               " (a reading refused never places a piece; loops may join it)";
    return out;
  }
  out.placement = NavPlacementInput{previous, p.keyframe, p.z};
  out.said = who + " placed by the nav after the tracking loss " + describePlacement(*out.placement);
  return out;
}

NavPlacer::Placed NavPlacer::bridged(const NavPlacement& p, int previous, int session, int keyframe) {
  Placed out;
  if (previous < 0) return out;
  out.placement = NavPlacementInput{previous, p.keyframe, p.z, true};
  out.said = "session " + std::to_string(session) + " keyframe " + std::to_string(keyframe) +
             " registers with the piece before it: placed by that visual bridge " + describePlacement(*out.placement);
  return out;
}

NavPlacer::Placed NavPlacer::newSession(int session, const std::optional<NavRecord>& here) {
  Placed out;
  if (!nav_.enabled || !nav_.place_pieces || !frame_) return out;
  const std::string who = "session " + std::to_string(session);
  if (!anchor_ || !sameWorldFrame(anchor_->frame, *frame_)) {
    if (!said_unknown_)
      out.said = who + " is not placed by the nav: no earlier keyframe with an accepted nav reading in the world " +
                 "frame " + frame_->name + " is known; later sessions are placed against this one's";
    said_unknown_ = true;
    return out;
  }
  if (!here || anchor_->session == session) {
    out.said = who + " is not placed by the nav: " +
               (here ? "its anchor is of the same session" : "its first keyframe has no accepted nav reading");
    return out;
  }
  // One clock (the same stream, forward in time): the step from the anchor must be the vehicle's.
  if (anchor_->stream == stream_ && here->stamp_s > anchor_->nav.stamp_s) {
    const std::string bad = implausible(anchor_->nav, *here);
    if (!bad.empty()) {
      out.refused = true;
      out.said = who + " is not placed by the nav in the nav's world frame " + frame_->name + " against session " +
                 std::to_string(anchor_->session) + ": " + bad + " (a reading refused never places a session)";
      return out;
    }
  }
  out.placement = placeAgainst(*anchor_, *here, nav_);
  out.said =
      who + " placed by the nav in the nav's world frame " + frame_->name + " " + describePlacement(*out.placement);
  return out;
}

}  // namespace core
}  // namespace uw_multislam
