// The map's datum: earthFromMap (ECEF pose of `map`) against GeographicLib's own inverse and the
// export's latLon (a second, independent path through LocalCartesian).
#include <gtest/gtest.h>

#include <GeographicLib/Geocentric.hpp>

#include "uw_multislam/core/session/geo_datum.h"

namespace uw_multislam {
namespace core {
namespace {

Eigen::Vector3d geodetic(const Eigen::Vector3d& ecef) {
  double lat = 0.0, lon = 0.0, h = 0.0;
  GeographicLib::Geocentric::WGS84().Reverse(ecef.x(), ecef.y(), ecef.z(), lat, lon, h);
  return {lat, lon, h};
}

TEST(GeoDatum, OnTheEquatorAtGreenwichAnEnuMapHasXEastYNorthZOut) {
  const Eigen::Isometry3d t = earthFromMap({0.0, 0.0, 90.0});
  // The origin is on the equator at Greenwich: ECEF (a, 0, 0), a = WGS84's equatorial radius.
  EXPECT_NEAR(t.translation().x(), GeographicLib::Constants::WGS84_a(), 1e-6);
  EXPECT_NEAR(t.translation().y(), 0.0, 1e-6);
  EXPECT_NEAR(t.translation().z(), 0.0, 1e-6);
  // East there is ECEF +y, north +z, up +x.
  EXPECT_TRUE(t.linear().col(0).isApprox(Eigen::Vector3d::UnitY(), 1e-12)) << t.linear();
  EXPECT_TRUE(t.linear().col(1).isApprox(Eigen::Vector3d::UnitZ(), 1e-12)) << t.linear();
  EXPECT_TRUE(t.linear().col(2).isApprox(Eigen::Vector3d::UnitX(), 1e-12)) << t.linear();
}

TEST(GeoDatum, MapPointsLandWhereLatLonPutsThem) {
  for (const GeoOrigin& o : {GeoOrigin{43.1, 5.9, 90.0}, GeoOrigin{-33.8, 151.2, 30.0}, GeoOrigin{60.0, -20.0, 0.0}}) {
    const Eigen::Isometry3d t = earthFromMap(o);
    EXPECT_TRUE(t.linear().isUnitary(1e-12));
    EXPECT_NEAR(t.linear().determinant(), 1.0, 1e-12);
    const Eigen::Vector3d at_origin = geodetic(t.translation());
    EXPECT_NEAR(at_origin.x(), o.lat_deg, 1e-9);
    EXPECT_NEAR(at_origin.y(), o.lon_deg, 1e-9);
    EXPECT_NEAR(at_origin.z(), 0.0, 1e-6);
    for (const Eigen::Vector2d& p :
         {Eigen::Vector2d(250.0, 0.0), Eigen::Vector2d(0.0, -400.0), Eigen::Vector2d(-120, 75)}) {
      const Eigen::Vector3d g = geodetic(t * Eigen::Vector3d(p.x(), p.y(), 0.0));
      const Eigen::Vector2d expected = latLon(o, p.x(), p.y());
      // 1e-9 degrees is 0.1 mm on the ground.
      EXPECT_NEAR(g.x(), expected.x(), 1e-9) << p.transpose();
      EXPECT_NEAR(g.y(), expected.y(), 1e-9) << p.transpose();
    }
  }
}

TEST(GeoDatum, HeadingTurnsTheMapAboutUp) {
  // x with heading 0 points north: 100 m along map x is 100 m north of the origin.
  const GeoOrigin north{43.1, 5.9, 0.0};
  const Eigen::Isometry3d t = earthFromMap(north);
  const Eigen::Isometry3d enu = earthFromMap({43.1, 5.9, 90.0});
  EXPECT_TRUE((t * Eigen::Vector3d(100, 0, 0)).isApprox(enu * Eigen::Vector3d(0, 100, 0), 1e-12));
  EXPECT_TRUE((t * Eigen::Vector3d(0, 100, 0)).isApprox(enu * Eigen::Vector3d(-100, 0, 0), 1e-12));
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
