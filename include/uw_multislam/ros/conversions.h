// Conversions between core types and ROS messages, in one place. 2-D poses live in
// the plane z = 0 of their frame; yaw is the rotation about z (REP-103).
#pragma once

#include <geometry_msgs/Pose.h>
#include <geometry_msgs/Pose2D.h>
#include <geometry_msgs/PoseWithCovariance.h>
#include <geometry_msgs/PoseWithCovarianceStamped.h>
#include <geometry_msgs/Transform.h>
#include <geometry_msgs/TransformStamped.h>
#include <nav_msgs/Odometry.h>
#include <ros/time.h>

#include <string>

#include "uw_multislam/core/geometry/uncertain_pose.h"

namespace uw_multislam {
namespace ros_conversions {

/// Variance written for the 3-D components a 2-D estimate does not observe (z, roll, pitch),
/// so that consumers treating the message as 3-D do not over-trust them.
constexpr double kUnobservedVariance = 1e6;

geometry_msgs::Pose2D toPose2DMsg(const core::Pose2& p);
core::Pose2 fromMsg(const geometry_msgs::Pose2D& m);

geometry_msgs::Pose toPoseMsg(const core::Pose2& p);
/// The planar part of a 3-D pose: x, y and the yaw of the quaternion (normalised first).
/// Returns false (and leaves `out` untouched) for a non-finite pose or a zero quaternion.
bool fromMsg(const geometry_msgs::Pose& m, core::Pose2* out);

geometry_msgs::Transform toTransformMsg(const core::Pose2& p);
/// The planar part of a transform, as fromMsg(Pose) does.
bool fromMsg(const geometry_msgs::Transform& m, core::Pose2* out);
/// `child` in `parent` (the pose of child's origin in parent's frame), stamped.
geometry_msgs::TransformStamped toTransformStampedMsg(const core::Pose2& p, const std::string& parent,
                                                      const std::string& child, const ros::Time& stamp);

/// The session id of a frame named "<prefix><id>" (the odometry's pose), or -1 for another name.
int sessionOfFrame(const std::string& frame, const std::string& prefix);

/// 6x6 row-major covariance (x, y, z, roll, pitch, yaw) from the 3x3 (x, y, yaw) one.
geometry_msgs::PoseWithCovariance toPoseWithCovarianceMsg(const core::UncertainPose2& p);
geometry_msgs::PoseWithCovarianceStamped toPoseWithCovarianceStampedMsg(const core::UncertainPose2& p,
                                                                        const std::string& frame_id,
                                                                        const ros::Time& stamp);
/// The (x, y, yaw) part; false for non-finite input or an invalid covariance.
bool fromMsg(const geometry_msgs::PoseWithCovariance& m, core::UncertainPose2* out);

/// nav_msgs/Odometry: `pose` in `frame_id` with its covariance (as toPoseWithCovarianceMsg), child
/// `child_frame_id`. The twist (in the child frame) is the motion from `previous` over `dt_s`
/// (x, y, yaw rates) when previous is given and dt_s > 0, else zero; it is a finite difference,
/// not an estimate: its covariance says unknown (kUnobservedVariance on the diagonal).
nav_msgs::Odometry toOdometryMsg(const core::UncertainPose2& pose, const core::Pose2* previous, double dt_s,
                                 const std::string& frame_id, const std::string& child_frame_id,
                                 const ros::Time& stamp);

}  // namespace ros_conversions
}  // namespace uw_multislam
