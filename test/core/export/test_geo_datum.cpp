// The map's datum: earthFromMap (ECEF pose of `map`) against GeographicLib's own inverse and the
// export's latLon (a second, independent path through LocalCartesian); a keyframe's fix against
// earthFromMap's inverse; utm -> map against GeographicLib's UTM forward of map points.
#include <gtest/gtest.h>

#include <GeographicLib/Geocentric.hpp>
#include <GeographicLib/UTMUPS.hpp>

#include <cmath>
#include <string>
#include <utility>
#include <vector>

#include "uw_multislam/core/export/geo_datum.h"

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

TEST(GeoDatum, AKeyframesFixIsItsMapPointThroughEarthFromMap) {
  for (const GeoOrigin& o : {GeoOrigin{43.0951, 5.9307, 30.0}, GeoOrigin{-33.8, 151.2, 90.0}}) {
    const Eigen::Isometry3d map_from_earth = earthFromMap(o).inverse();
    for (const Eigen::Vector2d& p : {Eigen::Vector2d(0, 0), Eigen::Vector2d(300, -40), Eigen::Vector2d(-75, 510)}) {
      const GeoFix f = fixFromMap(o, UncertainPose2::exact(Pose2(p.x(), p.y(), 1.0)));
      // Back through the other path: geodetic -> ECEF (Geocentric) -> map (earthFromMap's inverse).
      double x = 0, y = 0, z = 0;
      GeographicLib::Geocentric::WGS84().Forward(f.lat_deg, f.lon_deg, f.alt_m, x, y, z);
      const Eigen::Vector3d in_map = map_from_earth * Eigen::Vector3d(x, y, z);
      EXPECT_NEAR(in_map.x(), p.x(), 1e-6) << p.transpose();
      EXPECT_NEAR(in_map.y(), p.y(), 1e-6) << p.transpose();
      EXPECT_NEAR(in_map.z(), 0.0, 1e-6) << p.transpose();  // on map's plane: the height is the plane's
      const Eigen::Vector2d ll = latLon(o, p.x(), p.y());   // where the exports put it
      EXPECT_EQ(f.lat_deg, ll.x());
      EXPECT_EQ(f.lon_deg, ll.y());
    }
  }
  // The plane rises above the ellipsoid as d^2 / 2R: 0 at the origin, 7.1 mm at 300 m (R ~ 6.37e6 m).
  EXPECT_NEAR(fixFromMap({43.0951, 5.9307, 90.0}, UncertainPose2::exact(Pose2())).alt_m, 0.0, 1e-9);
  EXPECT_NEAR(fixFromMap({43.0951, 5.9307, 90.0}, UncertainPose2::exact(Pose2(300, 0, 0))).alt_m, 0.0071, 0.0002);
}

TEST(GeoDatum, AFixsCovarianceIsThePosesTurnedIntoEastNorthUp) {
  Eigen::Matrix3d p;
  p << 4.0, 0.5, 0.1, 0.5, 1.0, 0.2, 0.1, 0.2, 0.3;  // (x, y, yaw); the yaw rows must not leak in
  const UncertainPose2 pose(Pose2(10, 20, 0.3), p);
  // Heading 90 (ENU): x east, y north: the same block.
  const GeoFix enu = fixFromMap({43.0, 5.0, 90.0}, pose);
  const std::array<double, 9> same{4.0, 0.5, 0.0, 0.5, 1.0, 0.0, 0.0, 0.0, 0.0};
  for (int i = 0; i < 9; ++i) EXPECT_NEAR(enu.enu_covariance[i], same[i], 1e-12) << i;
  // Heading 0: x north, y west: east = -y, north = x: var(e) = 1, var(n) = 4, cov(e, n) = -0.5.
  const GeoFix north = fixFromMap({43.0, 5.0, 0.0}, pose);
  const std::array<double, 9> turned{1.0, -0.5, 0.0, -0.5, 4.0, 0.0, 0.0, 0.0, 0.0};
  for (int i = 0; i < 9; ++i) EXPECT_NEAR(north.enu_covariance[i], turned[i], 1e-12) << i;
  // Heading 60 (a turn of 30 degrees, where turning one way or the other differs): east = s x - y / 2,
  // north = x / 2 + s y, s = sqrt(3) / 2, so var(e) = 3 + 1/4 - s/2, var(n) = 1 + 3/4 + s/2,
  // cov(e, n) = 4 s/2 + (s^2 - 1/4) 0.5 - s/2 = 3s/2 + 1/4.
  const double s = std::sqrt(3.0) / 2.0;
  const GeoFix sixty = fixFromMap({43.0, 5.0, 60.0}, pose);
  const std::array<double, 9> by_hand{3.25 - s / 2, 1.5 * s + 0.25, 0.0, 1.5 * s + 0.25, 1.75 + s / 2, 0.0, 0.0, 0.0,
                                      0.0};
  for (int i = 0; i < 9; ++i) EXPECT_NEAR(sixty.enu_covariance[i], by_hand[i], 1e-12) << i;
}

TEST(GeoDatum, UtmFromMapPutsMapPointsWhereTheUtmForwardDoes) {
  for (const GeoOrigin& o : {GeoOrigin{43.0951, 5.9307, 30.0}, GeoOrigin{-33.8, 151.2, 90.0},
                             GeoOrigin{60.0, -20.0, 0.0}, GeoOrigin{0.5, 8.9, 200.0}}) {
    const UtmDatum u = utmFromMap(o);
    int zone = 0;
    bool north = false;
    double e0 = 0, n0 = 0, gamma = 0, k = 0;
    GeographicLib::UTMUPS::Forward(o.lat_deg, o.lon_deg, zone, north, e0, n0, gamma, k);
    EXPECT_EQ(u.zone, zone);
    EXPECT_EQ(u.north, o.lat_deg >= 0.0);
    EXPECT_NEAR(u.utm_from_map.translation().x(), e0, 1e-9);
    EXPECT_NEAR(u.utm_from_map.translation().y(), n0, 1e-9);
    EXPECT_NEAR(u.utm_from_map.translation().z(), 0.0, 1e-12);
    EXPECT_TRUE(u.utm_from_map.linear().col(2).isApprox(Eigen::Vector3d::UnitZ(), 1e-12));
    for (const Eigen::Vector2d& p : {Eigen::Vector2d(100, 0), Eigen::Vector2d(0, -100), Eigen::Vector2d(-60, 80)}) {
      const Eigen::Vector2d ll = latLon(o, p.x(), p.y());
      double e = 0, n = 0, g = 0, kp = 0;
      GeographicLib::UTMUPS::Forward(ll.x(), ll.y(), zone, north, e, n, g, kp, u.zone);
      const Eigen::Vector2d truth(e - e0, n - n0),
          got = (u.utm_from_map * Eigen::Vector3d(p.x(), p.y(), 0)).head<2>() - u.utm_from_map.translation().head<2>();
      // Direction: exact up to the arc-to-chord correction (below 1e-6 rad at 100 m in a zone).
      const double turn = std::atan2(got.x() * truth.y() - got.y() * truth.x(), got.dot(truth));
      EXPECT_NEAR(turn, 0.0, 1e-6) << o.lat_deg << " " << p.transpose();
      // Length: UTM's scale k is left out of the rigid transform, so the UTM distance is k times it.
      EXPECT_NEAR(truth.norm() / got.norm(), k, 1e-6) << o.lat_deg << " " << p.transpose();
    }
  }
  EXPECT_EQ(utmFromMap({43.0951, 5.9307, 90.0}).zoneName(), "31N");
  EXPECT_EQ(utmFromMap({-33.8, 151.2, 90.0}).zoneName(), "56S");
}

TEST(GeoDatum, UtmFromMapRefusesPolarDatums) {
  EXPECT_THROW(utmFromMap({85.0, 10.0, 90.0}), std::invalid_argument);
  EXPECT_THROW(utmFromMap({-81.0, 10.0, 90.0}), std::invalid_argument);
}

TEST(GeoDatum, AnAltitudeLiftsTheOriginAlongTheEllipsoidsNormal) {
  // Geodetic height h puts a point at (N + h) cos(lat) cos(lon), ...: h metres along the normal
  // (map's z axis) from the point at height 0, whatever N is.
  const GeoOrigin low{43.0951, 5.9307, 30.0}, high{43.0951, 5.9307, 30.0, 12.5};
  const Eigen::Isometry3d a = earthFromMap(low), b = earthFromMap(high);
  EXPECT_TRUE(b.linear().isApprox(a.linear(), 1e-15));
  EXPECT_LT((b.translation() - (a.translation() + 12.5 * a.linear().col(2))).norm(), 1e-6);
  EXPECT_NEAR(geodetic(b.translation()).z(), 12.5, 1e-6);
  // A fix of a map point is at the datum's height (plus the plane's rise, well under 1 mm at 10 m).
  EXPECT_NEAR(fixFromMap(high, UncertainPose2::exact(Pose2(10.0, -5.0, 0.0))).alt_m, 12.5, 1e-3);
  // utm -> map lifts it as much.
  EXPECT_NEAR(utmFromMap(high).utm_from_map.translation().z(), 12.5, 0.0);
}

TEST(GeoDatum, CheckDatumRefusesEveryValueNotANumberOrOutOfRangeNamingIt) {
  const double nan = std::nan(""), inf = INFINITY;
  EXPECT_EQ(checkDatum({43.0, 5.9, 90.0, 0.0}), "");
  EXPECT_EQ(checkDatum({-90.0, 180.0, -360.0, -10000.0}), "");  // the bounds are in
  const std::vector<std::pair<GeoOrigin, std::string>> bad{
      {{nan, 5.9, 90.0, 0.0}, "latitude_deg nan is not a number"},
      {{91.0, 5.9, 90.0, 0.0}, "latitude_deg 91 is outside [-90, 90]"},
      {{43.0, -180.5, 90.0, 0.0}, "longitude_deg -180.5 is outside [-180, 180]"},
      {{43.0, inf, 90.0, 0.0}, "longitude_deg inf is not a number"},
      {{43.0, 5.9, 361.0, 0.0}, "heading_deg 361 is outside [-360, 360]"},
      {{43.0, 5.9, nan, 0.0}, "heading_deg nan is not a number"},
      {{43.0, 5.9, 90.0, 2e4}, "altitude_m 20000 is outside [-10000, 10000] m"},
      {{43.0, 5.9, 90.0, -inf}, "altitude_m -inf is not a number"}};
  for (const auto& [d, why] : bad) EXPECT_EQ(checkDatum(d), why);
}

TEST(GeoDatum, TheStoresTextGivesTheDatumBackToTheLastBitAndRefusesADamagedOne) {
  const GeoOrigin d{-33.856784123456789, 151.215297987654321, 1.0 / 3.0, -2.718281828459045};
  GeoOrigin back;
  std::string why;
  ASSERT_TRUE(parseDatumText(datumText(d), &back, &why)) << why;
  EXPECT_TRUE(sameDatum(back, d)) << datumText(back) << " vs " << datumText(d);
  for (const std::string damaged :
       {"", "43,5.9,90", "43,5.9,90,", "43,5.9,90,1,2", "a,b,c,d", "91,5.9,90,0", "43,5.9,90,nan", "43,5.9,90,1e9"}) {
    EXPECT_FALSE(parseDatumText(damaged, &back, &why)) << damaged;
    EXPECT_NE(why.find("datum '" + damaged + "'"), std::string::npos) << why;
  }
  EXPECT_EQ(describeDatum({43.0951, 5.9307, 90.0, 0.0}), "43.0951000, 5.9307000, 0.00 m, first keyframe's x axis east");
  EXPECT_EQ(describeDatum({43.0951, 5.9307, 30.0, 1.5}),
            "43.0951000, 5.9307000, 1.50 m, first keyframe's x axis heading 30.0 deg");
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
