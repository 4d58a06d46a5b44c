// The published `map` frame from the core's (doc/frames.md "What map is").
//
// The core keeps each map in its first keyframe's frame; the ROS side draws it z-up
// (vehicle_frame.h: x along that keyframe's image columns). With a datum, what the back-end
// publishes in `map` is ENU at the datum instead (REP-103: x east, y north, z up): the z-up frame
// turned about z by theta = 90 deg - heading, where the heading is the compass heading (degrees
// clockwise from north) of the first keyframe's z-up x axis. Without a datum theta is 0 and the
// two frames are one. Origins coincide: only the axes turn, so distances, covariances' sizes and
// the datum's place stay as they are.
#pragma once

#include "uw_multislam/core/geometry/se2.h"
#include "uw_multislam/core/geometry/uncertain_pose.h"

namespace uw_multislam {
namespace core {

class MapFrame {
 public:
  /// No datum: the published map is the z-up core map.
  MapFrame() = default;
  /// ENU at a datum whose first keyframe's x axis has compass heading `heading_deg`.
  static MapFrame enuAtHeading(double heading_deg);

  /// The turn about z from the z-up core map to the published map, radians in (-pi, pi].
  double theta() const { return published_from_core_.yaw(); }
  bool isIdentity() const { return theta() == 0.0; }

  /// A z-up pose in the core map as published (published <- core (+) pose); its covariance turned
  /// with it (x, y rotated by theta, yaw's variance unchanged).
  Pose2 toPublished(const Pose2& in_core_map) const { return compose(published_from_core_, in_core_map); }
  UncertainPose2 toPublished(const UncertainPose2& in_core_map) const;
  /// Back: a pose given in the published map (an input expressed in `map`) in the z-up core map.
  Pose2 fromPublished(const Pose2& in_published_map) const;
  UncertainPose2 fromPublished(const UncertainPose2& in_published_map) const;

  /// The published map <- z-up core map, as a transform (origin fixed, yaw theta).
  const Pose2& publishedFromCore() const { return published_from_core_; }

 private:
  explicit MapFrame(double theta_rad) : published_from_core_(0.0, 0.0, theta_rad) {}
  Pose2 published_from_core_;
};

}  // namespace core
}  // namespace uw_multislam
