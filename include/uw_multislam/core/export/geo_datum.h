// The datum of the map frame: where `map`'s origin is on the earth, for the static earth -> map
// and utm -> map transforms robot_localization's navsat_transform publishes, and the geographic
// position of a keyframe. Part of uw_multislam_export (GeographicLib stays out of the core library).
#pragma once

#include <Eigen/Geometry>

#include <array>
#include <string>

#include "uw_multislam/core/export/survey_export.h"
#include "uw_multislam/core/geometry/uncertain_pose.h"

namespace uw_multislam {
namespace core {

/// The compass heading of the core map's x axis (its first keyframe's, z up) that makes it ENU
/// (REP-103: x east, y north, z up). In this file "map" is the core's map at a datum of any heading;
/// the back-end publishes `map` ENU (core/geometry/map_frame.h) and passes these functions a datum
/// of this heading for earth -> map and map -> utm.
constexpr double kEnuHeadingDeg = 90.0;
/// The largest |height| of a datum above the ellipsoid, m.
constexpr double kMaxDatumAltitudeM = 1e4;

/// Why a datum cannot be used ("latitude_deg nan is not a number", "... outside [-90, 90]"), or ""
/// when it can: every value finite, latitude in [-90, 90], longitude in [-180, 180], heading in
/// [-360, 360], altitude within kMaxDatumAltitudeM.
std::string checkDatum(const GeoOrigin& d);
/// The datum as the session store keeps it, "LAT,LON,HEADING_DEG,ALT_M" (every digit a double
/// holds), and back; false with `why` on a damaged text or a value checkDatum refuses.
std::string datumText(const GeoOrigin& d);
bool parseDatumText(const std::string& text, GeoOrigin* out, std::string* why);
/// "43.0951000, 5.9307000, 0.00 m, first keyframe's x axis heading 30.0 deg" ("... east" at
/// kEnuHeadingDeg): the heading is the core map's x axis' (z up); the back-end publishes `map` ENU.
std::string describeDatum(const GeoOrigin& d);
/// Whether two datums place `map` identically.
inline bool sameDatum(const GeoOrigin& a, const GeoOrigin& b) {
  return a.lat_deg == b.lat_deg && a.lon_deg == b.lon_deg && a.heading_deg == b.heading_deg && a.alt_m == b.alt_m;
}

/// The pose of `map` in ECEF (WGS84, metres): translation = the origin's ECEF position (at its
/// height alt_m), rotation = the local east-north-up axes at the origin turned by the heading. Exact
/// ellipsoidal maths (GeographicLib::Geocentric), consistent with latLon(): a map point p lies at
/// earthFromMap(origin) * p, whose geodetic latitude/longitude is latLon(origin, p.x, p.y) for z = 0.
Eigen::Isometry3d earthFromMap(const GeoOrigin& origin);

/// (east, north) <- map's (x, y) for a datum whose map x axis has compass heading `heading_deg`:
/// columns (sin h, cos h) and (-cos h, sin h).
Eigen::Matrix2d enuFromMap2(double heading_deg);

/// A map-frame position on WGS84, as sensor_msgs/NavSatFix carries one.
struct GeoFix {
  double lat_deg = 0.0, lon_deg = 0.0;
  /// Height above the ellipsoid of the map point (x, y, 0): map's z = 0 plane, tangent at the
  /// origin at the origin's height, rises with the distance d from it (d^2 / 2R, 8 mm at 320 m). The vehicle's
  /// depth is not part of a 2-D pose.
  double alt_m = 0.0;
  /// Row-major 3x3 covariance in east, north, up (m^2): the pose's (x, y) block turned by the
  /// heading; the up row and column are 0 (the point lies on map's plane by construction).
  std::array<double, 9> enu_covariance{};
};

/// The geographic position of a map-frame (z-up) pose: its (x, y) on map's z = 0 plane through
/// GeographicLib's LocalCartesian at the origin (the path latLon() and the exports take), and its
/// position covariance rotated into east/north/up.
GeoFix fixFromMap(const GeoOrigin& origin, const UncertainPose2& pose);

/// `map` in its datum's UTM zone, as navsat_transform's utm -> map: x = easting, y = northing
/// (metres, false easting/northing included), z up.
struct UtmDatum {
  int zone = 0;       // 1..60
  bool north = true;  // hemisphere
  /// Rigid: map's origin at the datum's (easting, northing), map's x axis turned to the heading
  /// measured from grid north (= heading - convergence). UTM's scale factor k is left out (tf
  /// transforms are rigid): a map point d metres from the origin lands within |k - 1| d of its
  /// true UTM coordinates (k in [0.9996, 1.001] inside a zone: at most 1 mm per metre).
  Eigen::Isometry3d utm_from_map = Eigen::Isometry3d::Identity();
  double convergence_deg = 0.0;  // bearing of grid north clockwise from true north, at the origin
  double scale = 1.0;            // k at the origin
  std::string zoneName() const;  // "31N", "56S"
};
/// Throws std::invalid_argument for a datum outside UTM's latitudes ([-80, 84]; UPS is not a UTM
/// zone and navsat_transform does not publish it either).
UtmDatum utmFromMap(const GeoOrigin& origin);

}  // namespace core
}  // namespace uw_multislam
