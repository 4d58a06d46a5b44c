// The camera -> vehicle conversion against an independent 3-D computation with 4x4 matrices
// (tf's view of the same frames), its covariance against numeric differentiation.
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <random>

#include "uw_multislam/core/geometry/vehicle_frame.h"

namespace uw_multislam {
namespace core {
namespace {

using Iso = Eigen::Isometry3d;

Iso rotX(double a) { return Iso(Eigen::AngleAxisd(a, Eigen::Vector3d::UnitX())); }
Iso planar(double x, double y, double z, double yaw) {
  Iso t(Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()));
  t.translation() = Eigen::Vector3d(x, y, z);
  return t;
}

// tf's computation: the z-up map M, the core's frame S (the first camera's optical frame at the
// map's origin, z into the seabed) = M turned by pi about x; the camera's optical frame c in S from
// the core's planar pose; base_link -> camera_optical from the mount (level frame turned back by pi).
Iso mapFromBase3d(const Pose2& camera, const CameraMount& m, double camera_z_in_base) {
  const Iso map_from_s = rotX(M_PI);
  const Iso s_from_optical = planar(camera.x(), camera.y(), 0.0, camera.yaw());
  const Iso base_from_optical =
      planar(m.base_from_camera.x(), m.base_from_camera.y(), camera_z_in_base, m.base_from_camera.yaw()) * rotX(M_PI);
  return map_from_s * s_from_optical * base_from_optical.inverse();
}

TEST(VehicleFrame, MatchesTheThreeDimensionalChainOfTransforms) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-3.0, 3.0);
  for (int i = 0; i < 200; ++i) {
    const Pose2 camera(u(rng) * 10, u(rng) * 10, u(rng));
    CameraMount mount;
    mount.base_from_camera = Pose2(u(rng) * 0.5, u(rng) * 0.5, u(rng));
    const double z = u(rng) * 0.2;
    const Iso t = mapFromBase3d(camera, mount, z);
    // A bottom-looking camera on a level vehicle: base_link stays level (z axis up).
    ASSERT_NEAR((t.linear() * Eigen::Vector3d::UnitZ() - Eigen::Vector3d::UnitZ()).norm(), 0.0, 1e-12);
    const Pose2 expected(t.translation().x(), t.translation().y(), std::atan2(t.linear()(1, 0), t.linear()(0, 0)));
    const Pose2 got = vehicleFromCamera(camera, mount);
    ASSERT_TRUE(approxEqual(got, expected, 1e-9, 1e-12)) << got << " vs " << expected;
    ASSERT_TRUE(approxEqual(cameraFromVehicle(got, mount), camera, 1e-9, 1e-12));
  }
}

TEST(VehicleFrame, DefaultMountIsTheRotationByPiAboutX) {
  // Camera at base_link looking down, image columns along x: the image's rows run to starboard
  // (-y), and a camera turning towards its rows (positive yaw in image axes) turns the vehicle
  // clockwise seen from above (negative yaw about z up).
  const Pose2 v = vehicleFromCamera(Pose2(2.0, 1.0, 0.3), CameraMount());
  EXPECT_TRUE(approxEqual(v, Pose2(2.0, -1.0, -0.3)));
  EXPECT_TRUE(approxEqual(zUp(zUp(Pose2(1.0, 2.0, 3.0))), Pose2(1.0, 2.0, 3.0)));
}

TEST(VehicleFrame, ZUpIsAGroupMorphismSoCorrectionsAndPosesConvertAlike) {
  // map <- pose = (map <- session) (+) (session <- pose) holds in either convention, which is why
  // frame corrections take zUp alone while poses take zUp and the mount.
  const Pose2 a(1.0, -2.0, 0.7), b(-0.3, 4.0, -2.1);
  EXPECT_TRUE(approxEqual(zUp(compose(a, b)), compose(zUp(a), zUp(b))));
  CameraMount mount;
  mount.base_from_camera = Pose2(0.4, -0.1, 0.2);
  EXPECT_TRUE(approxEqual(vehicleFromCamera(compose(a, b), mount), compose(zUp(a), vehicleFromCamera(b, mount))));
}

TEST(VehicleFrame, CovarianceMatchesNumericDifferentiation) {
  CameraMount mount;
  mount.base_from_camera = Pose2(0.35, -0.2, 0.9);
  const Pose2 mean(3.0, -1.0, 2.5);
  Eigen::Matrix3d p;
  p << 0.04, 0.01, 0.002, 0.01, 0.09, -0.003, 0.002, -0.003, 0.01;
  Eigen::Matrix3d j;
  const double h = 1e-6;
  for (int k = 0; k < 3; ++k) {
    Eigen::Vector3d d = Eigen::Vector3d::Zero();
    d(k) = h;
    const Pose2 plus = vehicleFromCamera(Pose2(mean.x() + d(0), mean.y() + d(1), mean.yaw() + d(2)), mount);
    const Pose2 minus = vehicleFromCamera(Pose2(mean.x() - d(0), mean.y() - d(1), mean.yaw() - d(2)), mount);
    j.col(k) =
        Eigen::Vector3d(plus.x() - minus.x(), plus.y() - minus.y(), normalizeAngle(plus.yaw() - minus.yaw())) / (2 * h);
  }
  const UncertainPose2 got = vehicleFromCamera(UncertainPose2(mean, p), mount);
  EXPECT_TRUE(approxEqual(got.mean, vehicleFromCamera(mean, mount)));
  EXPECT_LT((got.covariance - j * p * j.transpose()).cwiseAbs().maxCoeff(), 1e-8) << got.covariance;
  // With a lever arm the camera's yaw uncertainty moves the vehicle: for uncorrelated x, y, yaw
  // the x/y variances grow by var(yaw) times the lever arm squared.
  const Eigen::Matrix3d d = Eigen::Vector3d(0.04, 0.09, 0.01).asDiagonal();
  const Eigen::Matrix3d q = vehicleFromCamera(UncertainPose2(mean, d), mount).covariance;
  EXPECT_NEAR(q(0, 0) + q(1, 1), 0.04 + 0.09 + 0.01 * (0.35 * 0.35 + 0.2 * 0.2), 1e-12);
}

TEST(VehicleFrame, CameraAltitudeAddsTheCameraAboveTheAltimeter) {
  // Base 2.0 m above the seabed, camera 0.15 m below base_link, altimeter 0.30 m below it.
  CameraMount mount;
  mount.camera_above_altimeter_m = -0.15 - (-0.30);
  EXPECT_DOUBLE_EQ(cameraAltitude(2.0 - 0.30, mount), 2.0 - 0.15);
}

TEST(VehicleFrame, AMountMovedByAnyOfItsFourNumbersIsAMoveTheSameOneRepublishedIsNot) {
  CameraMount before;
  before.base_from_camera = Pose2(0.35, -0.15, 0.4);
  before.camera_above_altimeter_m = 0.15;
  EXPECT_FALSE(mountMoved(before, before));
  CameraMount again = before;  // the same transform through a float32 and back
  again.base_from_camera = Pose2(0.35 + 1e-8, -0.15 - 1e-8, 0.4 + 1e-8);
  again.camera_above_altimeter_m = 0.15 + 1e-8;
  EXPECT_FALSE(mountMoved(before, again));
  CameraMount x = before, y = before, yaw = before, height = before, wrapped = before;
  x.base_from_camera = Pose2(0.45, -0.15, 0.4);  // 0.1 m forward, the rostest's and fault matrix's move
  y.base_from_camera = Pose2(0.35, -0.14, 0.4);
  yaw.base_from_camera = Pose2(0.35, -0.15, 0.41);  // turned in place: the vehicle's pose moves with it
  height.camera_above_altimeter_m = 0.25;           // every altitude 0.1 m off
  EXPECT_TRUE(mountMoved(before, x));
  EXPECT_TRUE(mountMoved(before, y));
  EXPECT_TRUE(mountMoved(before, yaw));
  EXPECT_TRUE(mountMoved(before, height));
  // Yaw on the circle: pi and -pi are one mount.
  before.base_from_camera = Pose2(0.35, -0.15, M_PI);
  wrapped.base_from_camera = Pose2(0.35, -0.15, -M_PI);
  EXPECT_FALSE(mountMoved(before, wrapped));
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
