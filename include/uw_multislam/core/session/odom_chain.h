// REP-105 frames from the sessions: map -> odom -> base_link (doc/frames.md).
//
// Each session's odometry starts at the identity of its own frame (session_<id>). A vehicle's
// nav stack wants one continuous odom frame instead. OdomChain places every session's frame in
// odom: the first one at odom's origin, each later one so that its first pose lands where the
// last pose of the previous session was (the vehicle assumed not to have moved across the gap:
// odom then never jumps, it drifts, as REP-105 allows). map -> odom is then the correction that
// puts the vehicle where the back-end says it is, from any frame x seen in both map and odom:
//   map <- odom = (map <- x) (+) (-)(odom <- x)
// x is the active session's frame with the visual odometry's odom, or base_link at a keyframe's
// stamp when the vehicle publishes its own odom -> base_link.
#pragma once

#include <map>
#include <optional>

#include "uw_multislam/core/geometry/se2.h"

namespace uw_multislam {
namespace core {

class OdomChain {
 public:
  /// The pose in odom of `pose` (the odometry's pose in session `session`'s frame). A session
  /// not seen before is placed as the class comment says.
  Pose2 toOdom(int session, const Pose2& pose);
  /// odom <- session frame, or nullopt for a session not seen yet.
  std::optional<Pose2> offset(int session) const;
  int sessions() const { return static_cast<int>(offsets_.size()); }

 private:
  std::map<int, Pose2> offsets_;  // odom <- session frame
  std::optional<Pose2> last_;     // the last pose given, in odom
};

/// map <- odom from a frame x seen in both: (map <- x) (+) (-)(odom <- x).
Pose2 mapFromOdom(const Pose2& map_from_x, const Pose2& odom_from_x);

}  // namespace core
}  // namespace uw_multislam
