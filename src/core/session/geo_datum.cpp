#include "uw_multislam/core/session/geo_datum.h"

#include <GeographicLib/Geocentric.hpp>
#include <cmath>
#include <vector>

namespace uw_multislam {
namespace core {

Eigen::Isometry3d earthFromMap(const GeoOrigin& o) {
  double x = 0.0, y = 0.0, z = 0.0;
  std::vector<double> m(9);  // row-major: ECEF components of the local east, north, up axes as columns
  GeographicLib::Geocentric::WGS84().Forward(o.lat_deg, o.lon_deg, 0.0, x, y, z, m);
  Eigen::Matrix3d ecef_from_enu;
  ecef_from_enu << m[0], m[1], m[2], m[3], m[4], m[5], m[6], m[7], m[8];
  // map's x axis has compass heading h (clockwise from north): (sin h, cos h) in (east, north);
  // its y axis, 90 degrees anticlockwise with z up, is (-cos h, sin h) (as eastNorth()).
  const double h = o.heading_deg * M_PI / 180.0;
  Eigen::Matrix3d enu_from_map;
  enu_from_map << std::sin(h), -std::cos(h), 0.0, std::cos(h), std::sin(h), 0.0, 0.0, 0.0, 1.0;
  Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
  t.linear() = ecef_from_enu * enu_from_map;
  t.translation() = Eigen::Vector3d(x, y, z);
  return t;
}

}  // namespace core
}  // namespace uw_multislam
