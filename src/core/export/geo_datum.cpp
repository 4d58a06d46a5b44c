#include "uw_multislam/core/export/geo_datum.h"

#include <GeographicLib/Geocentric.hpp>
#include <GeographicLib/LocalCartesian.hpp>
#include <GeographicLib/UTMUPS.hpp>

#include <cmath>
#include <stdexcept>
#include <vector>

namespace uw_multislam {
namespace core {

namespace {
// map's x axis has compass heading h (clockwise from north): (sin h, cos h) in (east, north);
// its y axis, 90 degrees anticlockwise with z up, is (-cos h, sin h) (as eastNorth()).
Eigen::Matrix2d enuFromMap2(double heading_deg) {
  const double h = heading_deg * M_PI / 180.0;
  Eigen::Matrix2d r;
  r << std::sin(h), -std::cos(h), std::cos(h), std::sin(h);
  return r;
}
}  // namespace

Eigen::Isometry3d earthFromMap(const GeoOrigin& o) {
  double x = 0.0, y = 0.0, z = 0.0;
  std::vector<double> m(9);  // row-major: ECEF components of the local east, north, up axes as columns
  GeographicLib::Geocentric::WGS84().Forward(o.lat_deg, o.lon_deg, 0.0, x, y, z, m);
  Eigen::Matrix3d ecef_from_enu;
  ecef_from_enu << m[0], m[1], m[2], m[3], m[4], m[5], m[6], m[7], m[8];
  Eigen::Matrix3d enu_from_map = Eigen::Matrix3d::Identity();
  enu_from_map.topLeftCorner<2, 2>() = enuFromMap2(o.heading_deg);
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  t.linear() = ecef_from_enu * enu_from_map;
  t.translation() = Eigen::Vector3d(x, y, z);
  return t;
}

GeoFix fixFromMap(const GeoOrigin& o, const UncertainPose2& pose) {
  GeoFix f;
  const GeographicLib::LocalCartesian plane(o.lat_deg, o.lon_deg, 0.0);
  const Eigen::Vector2d en = eastNorth(o, pose.mean.x(), pose.mean.y());
  plane.Reverse(en.x(), en.y(), 0.0, f.lat_deg, f.lon_deg, f.alt_m);
  // The covariance of a linear map of the position: R P R^T. NavSatFix takes it in the tangent
  // plane at the reported point; the plane at the origin differs by d / R radians (5e-5 at 320 m).
  const Eigen::Matrix2d r = enuFromMap2(o.heading_deg);
  const Eigen::Matrix2d c = r * pose.covariance.topLeftCorner<2, 2>() * r.transpose();
  f.enu_covariance = {c(0, 0), c(0, 1), 0.0, c(1, 0), c(1, 1), 0.0, 0.0, 0.0, 0.0};
  return f;
}

std::string UtmDatum::zoneName() const { return std::to_string(zone) + (north ? "N" : "S"); }

UtmDatum utmFromMap(const GeoOrigin& o) {
  UtmDatum u;
  double easting = 0.0, northing = 0.0;
  try {
    GeographicLib::UTMUPS::Forward(o.lat_deg, o.lon_deg, u.zone, u.north, easting, northing, u.convergence_deg,
                                   u.scale);
  } catch (const GeographicLib::GeographicErr& e) {
    throw std::invalid_argument(std::string("datum: no UTM zone: ") + e.what());
  }
  if (u.zone == GeographicLib::UTMUPS::UPS)
    throw std::invalid_argument("datum: latitude " + std::to_string(o.lat_deg) +
                                " is outside UTM's [-80, 84] degrees (a polar UPS frame, not published)");
  // Grid bearing = true bearing - convergence; map's x axis then points (sin b, cos b) in
  // (easting, northing): a turn about up of 90 degrees - b from the easting axis.
  const double b = (o.heading_deg - u.convergence_deg) * M_PI / 180.0;
  u.utm_from_map.linear() = Eigen::AngleAxisd(M_PI / 2.0 - b, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  u.utm_from_map.translation() = Eigen::Vector3d(easting, northing, 0.0);
  return u;
}

}  // namespace core
}  // namespace uw_multislam
