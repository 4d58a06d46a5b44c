#include "uw_multislam/core/geometry/map_frame.h"

#include <cmath>

namespace uw_multislam {
namespace core {

namespace {
// The covariance of R p for an exact turn R about z: J P J^T with J = diag(R(theta), 1).
Eigen::Matrix3d turned(const Eigen::Matrix3d& p, double theta) {
  Eigen::Matrix3d j = Eigen::Matrix3d::Identity();
  j.topLeftCorner<2, 2>() = Pose2(0.0, 0.0, theta).rotation();
  return j * p * j.transpose();
}
}  // namespace

MapFrame MapFrame::enuAtHeading(double heading_deg) {
  // The first keyframe's x axis at compass heading h points at angle 90 deg - h from east,
  // anticlockwise (z up): the turn that takes it onto east's x.
  return MapFrame((90.0 - heading_deg) * M_PI / 180.0);
}

UncertainPose2 MapFrame::toPublished(const UncertainPose2& p) const {
  return UncertainPose2(toPublished(p.mean), turned(p.covariance, theta()));
}

Pose2 MapFrame::fromPublished(const Pose2& p) const { return compose(invert(published_from_core_), p); }

UncertainPose2 MapFrame::fromPublished(const UncertainPose2& p) const {
  return UncertainPose2(fromPublished(p.mean), turned(p.covariance, -theta()));
}

}  // namespace core
}  // namespace uw_multislam
