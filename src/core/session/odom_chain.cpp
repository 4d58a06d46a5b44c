#include "uw_multislam/core/session/odom_chain.h"

namespace uw_multislam {
namespace core {

Pose2 OdomChain::toOdom(int session, const Pose2& pose) {
  auto it = offsets_.find(session);
  if (it == offsets_.end()) {
    // The new session's origin (its odometry's identity) is where the vehicle was last seen; the
    // first pose given need not be the origin (a frame may have been skipped), so the offset is
    // chosen to put `pose` there: odom <- session = last (+) (-)pose.
    const Pose2 offset = last_ ? compose(*last_, invert(pose)) : Pose2();
    it = offsets_.emplace(session, offset).first;
  }
  const Pose2 in_odom = compose(it->second, pose);
  last_ = in_odom;
  return in_odom;
}

std::optional<Pose2> OdomChain::offset(int session) const {
  const auto it = offsets_.find(session);
  if (it == offsets_.end()) return std::nullopt;
  return it->second;
}

Pose2 mapFromOdom(const Pose2& map_from_x, const Pose2& odom_from_x) {
  return compose(map_from_x, invert(odom_from_x));
}

}  // namespace core
}  // namespace uw_multislam
