#include "uw_multislam/core/geometry/vehicle_frame.h"

#include <cmath>
#include <cstdio>

namespace uw_multislam {
namespace core {

Pose2 zUp(const Pose2& p) { return Pose2(p.x(), -p.y(), -p.yaw()); }

UncertainPose2 zUp(const UncertainPose2& p) {
  const Eigen::Matrix3d f = Eigen::Vector3d(1.0, -1.0, -1.0).asDiagonal();
  return UncertainPose2(zUp(p.mean), f * p.covariance * f);
}

Pose2 vehicleFromCamera(const Pose2& camera, const CameraMount& mount) {
  return compose(zUp(camera), invert(mount.base_from_camera));
}

Pose2 cameraFromVehicle(const Pose2& vehicle, const CameraMount& mount) {
  return zUp(compose(vehicle, mount.base_from_camera));
}

UncertainPose2 vehicleFromCamera(const UncertainPose2& camera, const CameraMount& mount) {
  return compose(zUp(camera), UncertainPose2::exact(invert(mount.base_from_camera)));
}

bool mountMoved(const CameraMount& before, const CameraMount& after, double tolerance) {
  const Pose2 moved = between(before.base_from_camera, after.base_from_camera);
  return !(moved.translation().norm() <= tolerance && std::abs(moved.yaw()) <= tolerance &&
           std::abs(after.camera_above_altimeter_m - before.camera_above_altimeter_m) <= tolerance);
}

std::string describe(const CameraMount& mount) {
  char s[160];
  std::snprintf(s, sizeof(s), "camera at x %.3f m, y %.3f m, yaw %.1f deg in base_link, %.3f m above the altimeter",
                mount.base_from_camera.x(), mount.base_from_camera.y(),
                mount.base_from_camera.yaw() * 57.29577951308232, mount.camera_above_altimeter_m);
  return s;
}

}  // namespace core
}  // namespace uw_multislam
