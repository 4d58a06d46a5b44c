// SessionChain: the keyframe chain a loop-detection stage keeps per session (loops/session_chain.h).
#include <gtest/gtest.h>

#include "uw_multislam/core/loops/session_chain.h"

namespace uw_multislam {
namespace core {
namespace {

UncertainPose2 step(double x, double yaw, double var = 1e-4) {
  return UncertainPose2(Pose2(x, 0.0, yaw), Eigen::Matrix3d::Identity() * var);
}

TEST(SessionChain, AppendsInOrderAndRefusesStaleKeyframes) {
  SessionChain c;
  EXPECT_EQ(c.append(0, UncertainPose2(), Pose2()), SessionChain::Append::kAppended);
  EXPECT_EQ(c.append(1, step(1.0, 0.1), Pose2(1.0, 0.0, 0.1)), SessionChain::Append::kAppended);
  EXPECT_EQ(c.append(1, step(5.0, 0.0), Pose2(9.0, 0.0, 0.0)), SessionChain::Append::kStale);
  EXPECT_EQ(c.numKeyframes(), 2);
  EXPECT_NEAR(c.odometry().absolutePose(1).x(), 1.0, 1e-12);
  EXPECT_FALSE(c.isPlaceholder(1));
}

TEST(SessionChain, BridgesAGapWithPlaceholdersAtTheLastPose) {
  SessionChain c;
  c.append(0, UncertainPose2(), Pose2());
  c.append(1, step(1.0, 0.0), Pose2(1.0, 0.0, 0.0));
  // Keyframes 2 and 3 lost; 4 is at odometry pose (3, 1, 0.2).
  EXPECT_EQ(c.append(4, step(0.5, 0.0, 2e-4), Pose2(3.0, 1.0, 0.2)), SessionChain::Append::kBridged);
  ASSERT_EQ(c.numKeyframes(), 5);
  EXPECT_TRUE(c.isPlaceholder(2));
  EXPECT_TRUE(c.isPlaceholder(3));
  EXPECT_FALSE(c.isPlaceholder(4));
  const Pose2 p3 = c.odometry().absolutePose(3), p4 = c.odometry().absolutePose(4);
  EXPECT_NEAR(p3.x(), 1.0, 1e-12);
  EXPECT_NEAR(p4.x(), 3.0, 1e-12);
  EXPECT_NEAR(p4.y(), 1.0, 1e-12);
  EXPECT_NEAR(p4.yaw(), 0.2, 1e-12);
  EXPECT_NEAR(c.odometry().motion(4).covariance(0, 0), 2e-4, 1e-15);  // the message's own covariance
}

TEST(SessionChain, RefusesAGapLargerThanTheLimitAndChangesNothing) {
  SessionChain c(10);
  c.append(0, UncertainPose2(), Pose2());
  EXPECT_EQ(c.append(2147483647, step(1.0, 0.0), Pose2(1.0, 0.0, 0.0)), SessionChain::Append::kTooFar);
  EXPECT_EQ(c.numKeyframes(), 1);
  EXPECT_EQ(c.append(12, step(1.0, 0.0), Pose2(1.0, 0.0, 0.0)), SessionChain::Append::kTooFar);
  EXPECT_EQ(c.append(11, step(1.0, 0.0), Pose2(1.0, 0.0, 0.0)), SessionChain::Append::kBridged);
  EXPECT_EQ(c.numKeyframes(), 12);
  SessionChain fresh(10);
  EXPECT_EQ(fresh.append(50, step(1.0, 0.0), Pose2()), SessionChain::Append::kTooFar);
  EXPECT_EQ(fresh.numKeyframes(), 0);
}

TEST(SessionChain, CandidateTrajectoryTakesOptimisedPositionsAndOdometryCovariances) {
  SessionChain c;
  c.append(0, UncertainPose2(), Pose2());
  c.append(1, step(1.0, 0.0, 1e-3), Pose2(1.0, 0.0, 0.0));
  c.append(2, step(1.0, 0.0, 2e-3), Pose2(2.0, 0.0, 0.0));
  c.append(3, step(1.0, 0.0, 3e-3), Pose2(3.0, 0.0, 0.0));
  // No optimised poses (or one): the odometry itself.
  EXPECT_NEAR(c.candidateTrajectory({}).absolutePose(3).x(), 3.0, 1e-12);
  // Optimised poses for keyframes 0..2 only: 0..2 follow them, 3 follows the odometry from 2.
  const std::vector<Pose2> opt{Pose2(), Pose2(0.9, 0.1, 0.0), Pose2(1.8, 0.2, 0.0)};
  const Trajectory t = c.candidateTrajectory(opt);
  ASSERT_EQ(t.numKeyframes(), 4u);
  EXPECT_NEAR(t.absolutePose(2).x(), 1.8, 1e-12);
  EXPECT_NEAR(t.absolutePose(2).y(), 0.2, 1e-12);
  EXPECT_NEAR(t.absolutePose(3).x(), 2.8, 1e-12);
  for (int k = 1; k <= 3; ++k) EXPECT_NEAR(t.motion(k).covariance(0, 0), 1e-3 * k, 1e-15) << k;
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
