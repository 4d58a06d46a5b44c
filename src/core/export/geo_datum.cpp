#include "uw_multislam/core/export/geo_datum.h"

#include <GeographicLib/Geocentric.hpp>
#include <GeographicLib/LocalCartesian.hpp>
#include <GeographicLib/UTMUPS.hpp>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <stdexcept>
#include <vector>

namespace uw_multislam {
namespace core {

// map's x axis has compass heading h (clockwise from north): (sin h, cos h) in (east, north);
// its y axis, 90 degrees anticlockwise with z up, is (-cos h, sin h) (as eastNorth()).
Eigen::Matrix2d enuFromMap2(double heading_deg) {
  const double h = heading_deg * M_PI / 180.0;
  Eigen::Matrix2d r;
  r << std::sin(h), -std::cos(h), std::cos(h), std::sin(h);
  return r;
}

namespace {
std::string outside(const char* name, double v, const char* range) {
  char line[160];
  std::snprintf(line, sizeof line, "%s %.10g is %s", name, v, std::isfinite(v) ? range : "not a number");
  return line;
}
}  // namespace

std::string checkDatum(const GeoOrigin& d) {
  if (!(std::abs(d.lat_deg) <= 90.0)) return outside("latitude_deg", d.lat_deg, "outside [-90, 90]");
  if (!(std::abs(d.lon_deg) <= 180.0)) return outside("longitude_deg", d.lon_deg, "outside [-180, 180]");
  if (!(std::abs(d.heading_deg) <= 360.0)) return outside("heading_deg", d.heading_deg, "outside [-360, 360]");
  if (!(std::abs(d.alt_m) <= kMaxDatumAltitudeM)) return outside("altitude_m", d.alt_m, "outside [-10000, 10000] m");
  return "";
}

std::string datumText(const GeoOrigin& d) {
  char text[160];
  std::snprintf(text, sizeof text, "%.17g,%.17g,%.17g,%.17g", d.lat_deg, d.lon_deg, d.heading_deg, d.alt_m);
  return text;
}

bool parseDatumText(const std::string& text, GeoOrigin* out, std::string* why) {
  const std::size_t comma = text.rfind(',');
  GeoOrigin d;
  if (comma == std::string::npos || !parseGeoOrigin(text.substr(0, comma), &d, why)) {
    *why = "datum '" + text + "' is not LAT,LON,HEADING_DEG,ALT_M";
    return false;
  }
  const char* alt = text.c_str() + comma + 1;
  char* end = nullptr;
  d.alt_m = std::strtod(alt, &end);
  if (end == alt || *end != '\0') {
    *why = "datum '" + text + "' is not LAT,LON,HEADING_DEG,ALT_M";
    return false;
  }
  if (const std::string bad = checkDatum(d); !bad.empty()) {
    *why = "datum '" + text + "': " + bad;
    return false;
  }
  *out = d;
  return true;
}

std::string describeDatum(const GeoOrigin& d) {
  char line[200];
  if (d.heading_deg == kEnuHeadingDeg)
    std::snprintf(line, sizeof line, "%.7f, %.7f, %.2f m, first keyframe's x axis east", d.lat_deg, d.lon_deg, d.alt_m);
  else
    std::snprintf(line, sizeof line, "%.7f, %.7f, %.2f m, first keyframe's x axis heading %.1f deg", d.lat_deg,
                  d.lon_deg, d.alt_m, d.heading_deg);
  return line;
}

Eigen::Isometry3d earthFromMap(const GeoOrigin& o) {
  double x = 0.0, y = 0.0, z = 0.0;
  std::vector<double> m(9);  // row-major: ECEF components of the local east, north, up axes as columns
  GeographicLib::Geocentric::WGS84().Forward(o.lat_deg, o.lon_deg, o.alt_m, x, y, z, m);
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
  const GeographicLib::LocalCartesian plane(o.lat_deg, o.lon_deg, o.alt_m);
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
  u.utm_from_map.translation() = Eigen::Vector3d(easting, northing, o.alt_m);
  return u;
}

}  // namespace core
}  // namespace uw_multislam
