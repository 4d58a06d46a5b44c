// OdomChain (session/odom_chain.h): one continuous odom frame over sessions, and map -> odom.
#include <gtest/gtest.h>

#include "uw_multislam/core/session/odom_chain.h"

namespace uw_multislam {
namespace core {
namespace {

double distance(const Pose2& a, const Pose2& b) {
  return std::abs(a.x() - b.x()) + std::abs(a.y() - b.y()) + std::abs(normalizeAngle(a.yaw() - b.yaw()));
}

TEST(OdomChain, OdomDoesNotJumpWhenASessionStartsAndKeepsEachSessionRigid) {
  OdomChain chain;
  // Session 0: along x, turning; its frame is odom's.
  Pose2 last;
  for (int k = 0; k < 5; ++k) last = chain.toOdom(0, Pose2(0.5 * k, 0.1 * k, 0.2 * k));
  EXPECT_LT(distance(last, Pose2(2.0, 0.4, 0.8)), 1e-12);
  EXPECT_LT(distance(*chain.offset(0), Pose2()), 1e-12);
  // Tracking lost: session 3 starts at its own identity. Its first pose is where session 0 ended.
  const Pose2 first = chain.toOdom(3, Pose2());
  EXPECT_LT(distance(first, last), 1e-12);
  // Later poses of session 3 move with it, rigidly: odom <- session 3 is fixed.
  const Pose2 p = chain.toOdom(3, Pose2(1.0, -0.5, 0.3));
  EXPECT_LT(distance(p, compose(last, Pose2(1.0, -0.5, 0.3))), 1e-12);
  EXPECT_LT(distance(*chain.offset(3), last), 1e-12);
  // A first pose that is not the identity (a skipped first frame) also lands on the last pose.
  const Pose2 q = chain.toOdom(4, Pose2(0.7, 0.2, -0.4));
  EXPECT_LT(distance(q, p), 1e-12);
  EXPECT_FALSE(chain.offset(1).has_value());
  EXPECT_EQ(chain.sessions(), 3);
}

TEST(OdomChain, MapFromOdomPutsTheVehicleWhereTheMapSaysItIs) {
  // Whatever frame x is seen in both, map <- odom (+) odom <- base = map <- base.
  const Pose2 map_from_session(3.0, -1.0, 0.7), odom_from_session(-2.0, 4.0, -1.2);
  const Pose2 session_from_base(1.5, 0.3, 0.25);
  const Pose2 map_from_odom = mapFromOdom(map_from_session, odom_from_session);
  const Pose2 via_odom = compose(map_from_odom, compose(odom_from_session, session_from_base));
  EXPECT_LT(distance(via_odom, compose(map_from_session, session_from_base)), 1e-12);
  // With x = base_link at one stamp (the vehicle's own odometry).
  const Pose2 map_from_base(10.0, 2.0, 2.5), odom_from_base(-3.0, 1.0, -2.9);
  EXPECT_LT(distance(compose(mapFromOdom(map_from_base, odom_from_base), odom_from_base), map_from_base), 1e-12);
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
