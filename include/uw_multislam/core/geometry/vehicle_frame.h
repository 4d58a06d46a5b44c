// From the camera's poses to the vehicle's, in REP-103 frames (doc/frames.md).
//
// The core's poses are the camera's: a session's frame is its first keyframe's image axes in
// metres (x along the image columns, y along the rows, z into the seabed: the camera's optical
// frame, DESIGN.md "Conventions"). ROS frames are z-up (REP-103). The two are related by a
// rotation of pi about x, (x, y, z) -> (x, -y, -z), which maps a planar pose (x, y, yaw) to
// (x, -y, -yaw): a proper rotation in 3-D, not a mirror, so tf chains stay consistent.
//
// The camera sits on the vehicle where tf's base_link -> camera_optical says: its "level frame"
// (optical frame turned by pi about x: x along the image columns, y against the rows, z up) is
// `base_from_camera` in base_link's plane. The vehicle's pose is then
//   map <- base_link = zUp(map <- camera) (+) (-)base_from_camera,
// and the camera's height above the seabed is the altimeter's range plus how far the camera sits
// above the altimeter. The default mount (the launch files' static transforms) is a camera at
// base_link's origin looking straight down with the image columns along base_link's x.
#pragma once

#include <string>

#include "uw_multislam/core/geometry/se2.h"
#include "uw_multislam/core/geometry/uncertain_pose.h"

namespace uw_multislam {
namespace core {

struct CameraMount {
  Pose2 base_from_camera;                 // the camera's level frame in base_link's plane
  double camera_above_altimeter_m = 0.0;  // camera height minus altimeter height (base_link z)
};

/// (x, y, yaw) -> (x, -y, -yaw): an image-axes (z-down) pose in the z-up frame, and back (its own inverse).
Pose2 zUp(const Pose2& p);
/// The same for a Gaussian pose: P -> F P F with F = diag(1, -1, -1).
UncertainPose2 zUp(const UncertainPose2& p);

/// The vehicle's pose (z-up, base_link) from the camera's (image axes), and back.
Pose2 vehicleFromCamera(const Pose2& camera, const CameraMount& mount);
Pose2 cameraFromVehicle(const Pose2& vehicle, const CameraMount& mount);
/// The same for a Gaussian pose (the mount is exact: first-order propagation through (+)).
UncertainPose2 vehicleFromCamera(const UncertainPose2& camera, const CameraMount& mount);

/// The camera's height above the seabed from the altimeter's range (level vehicle).
inline double cameraAltitude(double altimeter_range_m, const CameraMount& mount) {
  return altimeter_range_m + mount.camera_above_altimeter_m;
}

/// True when `after` places the sensors elsewhere than `before` (a second mount publisher, a changed
/// URDF): beyond `tolerance` in metres (x, y, the camera's height above the altimeter) or radians
/// (yaw, on the circle). The same transform published again, with a float's rounding, is no move.
bool mountMoved(const CameraMount& before, const CameraMount& after, double tolerance = 1e-6);

/// "x y yaw, camera above altimeter" for logs.
std::string describe(const CameraMount& mount);

}  // namespace core
}  // namespace uw_multislam
