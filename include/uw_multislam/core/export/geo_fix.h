// Absolute fixes (sensor_msgs/NavSatFix from a GPS at the surface or a USBL) as position priors on
// keyframes: the fix checked, matched to the keyframe nearest in stamp, placed in the core's map
// frame through the datum (geo_datum.h), and handed to SessionManager::addPositionPrior. No ROS:
// the back-end's glue (ros/fix_input.h) converts the message and calls this. Part of
// uw_multislam_export (GeographicLib).
//
// The fix is the position of a point fixed on the vehicle (the GPS antenna, the USBL transponder:
// NavFix::antenna, base_link's origin by default); base_link's position is the fix minus that
// lever arm turned by the vehicle's heading at the keyframe, and the prior is on the camera's
// position, which the core's keyframes are, through the camera's mount at that heading.
#pragma once

#include <Eigen/Core>

#include <array>
#include <deque>
#include <optional>
#include <string>
#include <vector>

#include "uw_multislam/core/export/geo_datum.h"
#include "uw_multislam/core/geometry/vehicle_frame.h"
#include "uw_multislam/core/session/session_manager.h"

namespace uw_multislam {
namespace core {

/// A WGS84 position as a point of map's z = 0 plane (z-up axes, as fixFromMap takes it) with its
/// covariance there: the inverse of fixFromMap. The point is the one fixFromMap would give this
/// latitude and longitude for (GeographicLib's LocalCartesian at the datum, on the plane); the
/// fix's own height is not used (the 2-D pose has no depth). `en_covariance`: east/north, m^2.
struct MapPoint {
  Eigen::Vector2d xy = Eigen::Vector2d::Zero();
  Eigen::Matrix2d covariance = Eigen::Matrix2d::Zero();
};
MapPoint mapFromFix(const GeoOrigin& origin, double lat_deg, double lon_deg, const Eigen::Matrix2d& en_covariance);

/// A fix as sensor_msgs/NavSatFix carries it (its status and covariance type use that message's
/// numbers).
struct NavFix {
  static constexpr int kStatusNoFix = -1;
  static constexpr int kCovarianceUnknown = 0, kCovarianceApproximated = 1, kCovarianceDiagonalKnown = 2,
                       kCovarianceKnown = 3;
  double stamp_s = 0.0;
  int status = 0;
  double lat_deg = 0.0, lon_deg = 0.0;
  int covariance_type = kCovarianceUnknown;
  std::array<double, 9> covariance{};  // east, north, up; row-major, m^2
  /// Where the fix is on the vehicle: the antenna's or transponder's position in base_link's plane
  /// (x forward, y left, metres; tf's base_link -> the message's frame_id). Zero: base_link itself.
  Eigen::Vector2d antenna = Eigen::Vector2d::Zero();
  bool antenna_known = true;  // false: the frame's place on the vehicle is not known (refused)
};

/// Why a fix is not used; each counted (fixes_refused_<name>).
enum class FixRefusal {
  kNoFix,              // status NO_FIX
  kNotFinite,          // latitude or longitude NaN or infinite
  kUnknownCovariance,  // covariance type UNKNOWN and no default_sigma_m
  kBadVariance,        // an east/north variance not finite or not positive, or not positive definite
  kNoDatum,            // no datum yet (~datum/* or set_datum)
  kNoKeyframe,         // no keyframe within max_dt_s (or dropped from a full waiting list)
  kOtherMap,           // the keyframe's map is not the one the datum places (the active session's)
  kMapOrigin,          // the keyframe is its map's origin (the map's frame: fixed)
  kKeyframeHasFix,     // the keyframe has a fix already (one per keyframe: close fixes share their errors)
  kOutlier,            // too far from its keyframe for both covariances (the gate: a USBL's multipath, a jump)
  kNoLeverArm,         // its frame's place on the vehicle is not known (not static in tf, or not on the vehicle)
  kCount
};
/// "no_fix", "not_finite", "unknown_covariance", "bad_variance", "no_datum", "no_keyframe", "other_map",
/// "map_origin", "keyframe_has_fix", "outlier", "no_lever_arm".
const char* fixRefusalName(FixRefusal r);

struct FixOptions {
  double max_dt_s = 0.5;         // a fix is matched to the keyframe nearest in stamp within this (s, > 0)
  double default_sigma_m = 0.0;  // > 0: the east/north sigma of a fix whose covariance type is UNKNOWN
  int max_waiting = 32;          // fixes newer than every keyframe, waiting for the next one (>= 1)
  /// The gate: a fix is refused (outlier) when d² = νᵀ S⁻¹ ν exceeds gate_chi2, ν the fix minus the
  /// keyframe's predicted position, S = gate_inflation × the odometry chain's covariance behind that
  /// prediction + the covariances of the fixes in it: dead-reckoned from the session's nearest
  /// earlier keyframe with a fix (that fix plus the estimate's displacement since), else the
  /// keyframe's estimate with the chain from its map's origin. 13.8155: χ²(2) at 0.999. 0: no gate. The chain
  /// covariance is first order and over-confident over many motions (doc/benchmarks/real_survey.md), so it is inflated
  /// as the loops' gate inflates it (backend intra_gate_inflation): the gate refuses a jump of metres, not a drift the
  /// odometry made.
  double gate_chi2 = 13.8155;
  double gate_inflation = 100.0;  // >= 1
  std::string validate() const;
};

/// A fix placed on a keyframe: the prior SessionManager::addPositionPrior takes (the core's map
/// frame: the camera's position, image axes).
struct FixPrior {
  int session = -1, keyframe = -1;
  double dt_s = 0.0;  // the fix's stamp minus the keyframe's
  Eigen::Vector2d position = Eigen::Vector2d::Zero();
  Eigen::Matrix2d covariance = Eigen::Matrix2d::Identity();
};

/// Checks fixes, keeps them until a keyframe at least as new has arrived, and matches them. Not
/// thread-safe (the host holds its own lock, or the worker's).
class FixMatcher {
 public:
  /// Throws std::invalid_argument on bad options.
  explicit FixMatcher(const FixOptions& options);

  /// A fix: checked (status, latitude/longitude, covariance; `have_datum`), then waiting for
  /// match(). Returns the refusal (counted), or nullopt when it waits. A full waiting list drops
  /// its oldest fix (counted no_keyframe).
  std::optional<FixRefusal> add(const NavFix& fix, bool have_datum);
  /// The waiting fixes against `m`'s keyframes: each one that is not newer than every keyframe is
  /// matched to the keyframe nearest in stamp (refused no_keyframe beyond max_dt_s, other_map when
  /// that keyframe's map is not `datum_map`, outlier beyond the gate) and placed through `datum`
  /// and the camera's `mount` at the keyframe's current pose; the rest wait. Refusals are counted; the priors returned
  /// are not counted until given (give()).
  std::vector<FixPrior> match(const SessionQueries& m, const std::optional<GeoOrigin>& datum, int datum_map,
                              const CameraMount& mount);
  /// Gives the priors to the manager: each one it takes is counted used, a map origin refused
  /// (map_origin), a keyframe with a prior already (keyframe_has_fix); another refusal is counted
  /// no_keyframe; the message kept (lastRefusal).
  /// Returns how many were taken.
  int give(SessionManager* m, const std::vector<FixPrior>& priors);

  long used() const { return used_; }
  long refused(FixRefusal r) const { return refused_[static_cast<int>(r)]; }
  std::size_t waiting() const { return waiting_.size(); }
  /// The last refusal in words, for a throttled WARN.
  const std::string& lastRefusal() const { return last_refusal_; }
  const FixOptions& options() const { return options_; }

 private:
  void refuse(FixRefusal r, const std::string& why);
  /// Why `prior` is beyond the gate (options_.gate_chi2), or nullopt when it is within it.
  std::optional<std::string> outOfGate(const SessionQueries& m, const std::vector<PriorRecord>& held, int session,
                                       int keyframe, const std::vector<Pose2>& poses, const FixPrior& prior) const;

  FixOptions options_;
  struct Waiting {
    NavFix fix;
    Eigen::Matrix2d covariance;  // east/north, checked
  };
  std::deque<Waiting> waiting_;
  long used_ = 0;
  std::array<long, static_cast<int>(FixRefusal::kCount)> refused_{};
  std::string last_refusal_;
};

}  // namespace core
}  // namespace uw_multislam
