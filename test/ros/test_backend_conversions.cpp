// The session manager's answers and state as ROS messages (ros/backend_conversions.h).
#include <gtest/gtest.h>

#include "uw_multislam/ros/backend_conversions.h"

namespace uw_multislam {
namespace ros_conversions {
namespace {

TEST(BackendConversions, EveryCoreStatusCodeIsTheStatusMsgCodeOfTheSameName) {
  using C = core::StatusCode;
  const std::vector<std::pair<C, std::uint8_t>> pairs = {
      {C::kOk, uw_multislam::Status::OK},
      {C::kInvalidArgument, uw_multislam::Status::INVALID_ARGUMENT},
      {C::kNotFound, uw_multislam::Status::NOT_FOUND},
      {C::kAlreadyExists, uw_multislam::Status::ALREADY_EXISTS},
      {C::kFailedPrecondition, uw_multislam::Status::FAILED_PRECONDITION},
      {C::kInternal, uw_multislam::Status::INTERNAL},
      {C::kDataLoss, uw_multislam::Status::DATA_LOSS}};
  for (const auto& [core_code, msg_code] : pairs) {
    const uw_multislam::Status s = toStatusMsg({core_code, "why"});
    EXPECT_EQ(s.code, msg_code) << core::statusCodeName(core_code);
    EXPECT_EQ(s.message, core_code == C::kOk ? "" : "why");
  }
}

TEST(BackendConversions, SessionSummaryAsSessionState) {
  core::SessionSummary s;
  s.id = 4;
  s.name = "dive";
  s.state = core::SessionState::kUnloaded;
  s.map = 2;
  s.keyframes = 17;
  s.loops = 3;
  s.first_stamp_s = 10.5;
  s.last_stamp_s = 20.25;
  const uw_multislam::SessionState m = toSessionStateMsg(s);
  EXPECT_EQ(m.session, 4);
  EXPECT_EQ(m.name, "dive");
  EXPECT_EQ(m.state, uw_multislam::SessionState::UNLOADED);
  EXPECT_EQ(m.map, 2);
  EXPECT_EQ(m.num_keyframes, 17);
  EXPECT_EQ(m.num_loops, 3);
  EXPECT_DOUBLE_EQ(m.first_stamp.toSec(), 10.5);
  EXPECT_DOUBLE_EQ(m.last_stamp.toSec(), 20.25);
  s.state = core::SessionState::kActive;
  EXPECT_EQ(toSessionStateMsg(s).state, uw_multislam::SessionState::ACTIVE);
  s.state = core::SessionState::kFinished;
  EXPECT_EQ(toSessionStateMsg(s).state, uw_multislam::SessionState::FINISHED);
}

TEST(BackendConversions, KeyframeDataAsManagerInput) {
  KeyframeData k;
  k.session = 3;
  k.keyframe = 7;
  k.frame_index = 21;
  k.altitude_m = 1.9;
  k.camera.width = 320;
  k.motion = core::UncertainPose2(core::Pose2(0.1, 0.2, 0.3), Eigen::Matrix3d::Identity() * 2e-4);
  k.odometry_pose = core::Pose2(1, 2, 0.5);
  k.hash = Eigen::VectorXf::LinSpaced(384, 0.0f, 1.0f);
  const core::KeyframeInput in = toKeyframeInput(k, 123.5);
  EXPECT_EQ(in.session, 3);
  EXPECT_EQ(in.keyframe, 7);
  EXPECT_EQ(in.frame_index, 21);
  EXPECT_DOUBLE_EQ(in.stamp_s, 123.5);
  EXPECT_DOUBLE_EQ(in.altitude_m, 1.9);
  EXPECT_EQ(in.camera.width, 320);
  EXPECT_DOUBLE_EQ(in.motion.mean.yaw(), 0.3);
  EXPECT_DOUBLE_EQ(in.motion.covariance(1, 1), 2e-4);
  EXPECT_DOUBLE_EQ(in.odometry_pose.y(), 2.0);
  ASSERT_EQ(in.hash.size(), 384);
  EXPECT_FLOAT_EQ(in.hash(383), 1.0f);
}

}  // namespace
}  // namespace ros_conversions
}  // namespace uw_multislam
