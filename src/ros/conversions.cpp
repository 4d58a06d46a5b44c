#include "uw_multislam/ros/conversions.h"

#include <charconv>

#include <tf2/LinearMath/Matrix3x3.h>
#include <tf2/LinearMath/Quaternion.h>

#include <cmath>

namespace uw_multislam {
namespace ros_conversions {

namespace {
// Index of the planar components in the 6x6 (x, y, z, roll, pitch, yaw) covariance.
constexpr int kPlanar[3] = {0, 1, 5};

geometry_msgs::Quaternion yawQuaternion(double yaw) {
  geometry_msgs::Quaternion q;
  q.x = 0.0;
  q.y = 0.0;
  q.z = std::sin(yaw / 2.0);
  q.w = std::cos(yaw / 2.0);
  return q;
}
}  // namespace

geometry_msgs::Pose2D toPose2DMsg(const core::Pose2& p) {
  geometry_msgs::Pose2D m;
  m.x = p.x();
  m.y = p.y();
  m.theta = p.yaw();
  return m;
}

core::Pose2 fromMsg(const geometry_msgs::Pose2D& m) { return core::Pose2(m.x, m.y, m.theta); }

geometry_msgs::Pose toPoseMsg(const core::Pose2& p) {
  geometry_msgs::Pose m;
  m.position.x = p.x();
  m.position.y = p.y();
  m.position.z = 0.0;
  m.orientation = yawQuaternion(p.yaw());
  return m;
}

bool fromMsg(const geometry_msgs::Pose& m, core::Pose2* out) {
  const auto& o = m.orientation;
  const double norm = std::sqrt(o.x * o.x + o.y * o.y + o.z * o.z + o.w * o.w);
  if (!std::isfinite(m.position.x) || !std::isfinite(m.position.y) || !std::isfinite(norm) || norm < 1e-9) {
    return false;
  }
  tf2::Quaternion q(o.x / norm, o.y / norm, o.z / norm, o.w / norm);
  double roll = 0.0, pitch = 0.0, yaw = 0.0;
  tf2::Matrix3x3(q).getRPY(roll, pitch, yaw);
  *out = core::Pose2(m.position.x, m.position.y, yaw);
  return true;
}

bool fromMsg(const geometry_msgs::Transform& m, core::Pose2* out) {
  geometry_msgs::Pose p;
  p.position.x = m.translation.x;
  p.position.y = m.translation.y;
  p.position.z = m.translation.z;
  p.orientation = m.rotation;
  return fromMsg(p, out);
}

geometry_msgs::Transform toTransformMsg(const core::Pose2& p) {
  geometry_msgs::Transform t;
  t.translation.x = p.x();
  t.translation.y = p.y();
  t.translation.z = 0.0;
  t.rotation = yawQuaternion(p.yaw());
  return t;
}

geometry_msgs::TransformStamped toTransformStampedMsg(const core::Pose2& p, const std::string& parent,
                                                      const std::string& child, const ros::Time& stamp) {
  geometry_msgs::TransformStamped t;
  t.header.stamp = stamp;
  t.header.frame_id = parent;
  t.child_frame_id = child;
  t.transform = toTransformMsg(p);
  return t;
}

int sessionOfFrame(const std::string& frame, const std::string& prefix) {
  if (frame.size() <= prefix.size() || frame.compare(0, prefix.size(), prefix) != 0) return -1;
  int id = -1;
  const char* end = frame.data() + frame.size();
  const auto [ptr, ec] = std::from_chars(frame.data() + prefix.size(), end, id);
  return ec == std::errc() && ptr == end && id >= 0 ? id : -1;
}

geometry_msgs::PoseWithCovariance toPoseWithCovarianceMsg(const core::UncertainPose2& p) {
  geometry_msgs::PoseWithCovariance m;
  m.pose = toPoseMsg(p.mean);
  m.covariance.fill(0.0);
  for (int i = 2; i <= 4; ++i) m.covariance[i * 6 + i] = kUnobservedVariance;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) m.covariance[kPlanar[r] * 6 + kPlanar[c]] = p.covariance(r, c);
  }
  return m;
}

geometry_msgs::PoseWithCovarianceStamped toPoseWithCovarianceStampedMsg(const core::UncertainPose2& p,
                                                                        const std::string& frame_id,
                                                                        const ros::Time& stamp) {
  geometry_msgs::PoseWithCovarianceStamped m;
  m.header.stamp = stamp;
  m.header.frame_id = frame_id;
  m.pose = toPoseWithCovarianceMsg(p);
  return m;
}

bool fromMsg(const geometry_msgs::PoseWithCovariance& m, core::UncertainPose2* out) {
  core::Pose2 mean;
  if (!fromMsg(m.pose, &mean)) return false;
  Eigen::Matrix3d cov;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) cov(r, c) = m.covariance[kPlanar[r] * 6 + kPlanar[c]];
  }
  if (!core::checkCovariance(cov).empty()) return false;
  *out = core::UncertainPose2(mean, cov);
  return true;
}

nav_msgs::Odometry toOdometryMsg(const core::UncertainPose2& pose, const core::Pose2* previous, double dt_s,
                                 const std::string& frame_id, const std::string& child_frame_id,
                                 const ros::Time& stamp) {
  nav_msgs::Odometry m;
  m.header.stamp = stamp;
  m.header.frame_id = frame_id;
  m.child_frame_id = child_frame_id;
  m.pose = toPoseWithCovarianceMsg(pose);
  if (previous && dt_s > 0) {
    const core::Pose2 step = core::between(*previous, pose.mean);  // in the previous base_link
    m.twist.twist.linear.x = step.x() / dt_s;
    m.twist.twist.linear.y = step.y() / dt_s;
    m.twist.twist.angular.z = step.yaw() / dt_s;
  }
  for (int k = 0; k < 6; ++k) m.twist.covariance[7 * k] = kUnobservedVariance;
  return m;
}

}  // namespace ros_conversions
}  // namespace uw_multislam
