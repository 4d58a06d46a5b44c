// The datum of the map frame: where `map`'s origin is on the earth, for a static earth -> map
// transform as robot_localization's navsat_transform publishes one. Part of uw_multislam_export
// (GeographicLib stays out of the core library).
#pragma once

#include <Eigen/Geometry>

#include "uw_multislam/core/session/survey_export.h"

namespace uw_multislam {
namespace core {

/// The pose of `map` in ECEF (WGS84, metres): translation = the origin's ECEF position (height
/// 0), rotation = the local east-north-up axes at the origin turned by the heading. Exact
/// ellipsoidal maths (GeographicLib::Geocentric), consistent with latLon(): a map point p lies at
/// earthFromMap(origin) * p, whose geodetic latitude/longitude is latLon(origin, p.x, p.y) for z = 0.
Eigen::Isometry3d earthFromMap(const GeoOrigin& origin);

}  // namespace core
}  // namespace uw_multislam
