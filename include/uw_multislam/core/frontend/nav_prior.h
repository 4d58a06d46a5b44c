// The vehicle's dead-reckoned navigation (DVL + INS) as a prior for the visual odometry:
// nav.csv rows (core/frontend/dataset.h) interpolated at image stamps, the relative
// nav motion between two frames with its covariance, and the chi-square gate that compares a
// visual motion with it.
//
// Covariance of a relative nav motion (the inflation model). nav.csv gives, per row, the standard
// deviation of the *accumulated* dead-reckoning error (sigma_xy_m, sigma_yaw_rad). A DVL/INS error
// is dominated by systematic terms (the DVL's scale error, the compass's heading bias) that grow
// the error linearly with the distance travelled, fully correlated from one interval to the next;
// the standard deviation of the motion between stamps a and b is then the growth of sigma over
// the interval, |sigma(b) - sigma(a)| (a random walk alone would give sqrt(sigma_b^2 - sigma_a^2),
// which is larger late in a mission and would make the gate below blind). That growth is
// multiplied by `inflation` (we trust the nav's own figures less than it claims: unmodelled
// currents, lever arms, time offsets) and floored by min_sigma_m / min_sigma_rad (a nav standing
// still, or a track with absolute fixes, still has an uncertain relative motion):
//   sigma_xy  = max(min_sigma_m,   inflation * |sigma_xy(b)  - sigma_xy(a)|)
//   sigma_yaw = max(min_sigma_rad, inflation * |sigma_yaw(b) - sigma_yaw(a)|)
//   covariance = diag(sigma_xy^2, sigma_xy^2, sigma_yaw^2)   (isotropic in x, y: frame-free)
//
// The gate: d^2 = e^T (C_visual + C_nav)^-1 e, e = visual motion minus nav motion (yaw wrapped),
// against the chi-square quantile of 3 degrees of freedom at gate_confidence
// (backend/loop_consistency.h's mahalanobis2 and chiSquare3Quantile).
#pragma once

#include <string>
#include <vector>

#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/geometry/uncertain_pose.h"

namespace uw_multislam {
namespace core {

/// What a session does when vision fails (frames the odometry cannot match).
enum class TrackingLossPolicy {
  kNewSession,    // close the session after tracking.max_fallbacks unmatched frames (no nav: always)
  kDeadReckoning  // with a nav input: the nav's motion carries the session across the gap
};
std::string trackingLossPolicyName(TrackingLossPolicy p);
bool parseTrackingLossPolicy(const std::string& name, TrackingLossPolicy* p);

/// Where a keyframe's motion X_k^{k-1} came from.
enum class MotionSource {
  kVisual,    // RANSAC on the images (the nav, when present, agreed within the gate)
  kNav,       // the nav's relative motion: vision failed, or its motion was refused by the gate
  kFused,     // visual and nav combined (nav.fuse)
  kFallback,  // no nav: the previous frame-to-frame motion reused (paper §5)
};
const char* motionSourceName(MotionSource s);
bool parseMotionSource(const std::string& name, MotionSource* s);

struct NavPriorOptions {
  /// Use nav.csv / the nav input when there is one (offline_slam --nav on|off overrides).
  bool enabled = true;
  /// With a nav input (the policy is always new_session without one).
  TrackingLossPolicy on_tracking_loss = TrackingLossPolicy::kDeadReckoning;
  double inflation = 2.0;        // factor on the growth of the nav's sigma over the interval
  double min_sigma_m = 0.005;    // floor of the relative motion's sigma on x and y
  double min_sigma_rad = 0.005;  // floor on yaw
  /// Chi-square gate on visual - nav (3 dof); 0 = no gate.
  double gate_confidence = 0.999;
  /// Combine a visual motion that passes the gate with the nav's (information-weighted);
  /// off: the visual motion is kept as it is (source visual).
  bool fuse = false;
  /// Gate RANSAC's hypotheses by the nav's motion (rigid_ransac.h MotionPrior) at the same confidence.
  bool gate_ransac = true;
  /// A frame carried by the nav becomes a keyframe when the nav-predicted footprint overlap with
  /// the last keyframe drops below keyframes.min_overlap, or when it has at least this many
  /// features and the last keyframe was itself not matched (so that the next frame can match it).
  int min_features_to_restart = 100;
  /// A nav step faster than this (plus three sigma of its own noise), from the last keyframe or
  /// from the previous frame, is a glitch of the nav (a bad row, a reset), not a motion: that
  /// frame is treated as having no nav (counted, OdometryStats::nav_implausible) instead of
  /// overruling the camera.
  double max_speed_m_s = 10.0;
  /// The same for the heading: a turn faster than this (plus three sigma, the nav's and a 2-degree
  /// reading noise of each heading).
  double max_yaw_rate_rad_s = 1.0;
  /// Place each new piece (after a tracking loss) and each new session whose nav is in the same
  /// declared world frame by the nav (navPlacement below), so that it is in its predecessor's map
  /// from its first keyframe instead of a map of its own until visual loops come.
  bool place_pieces = true;

  std::string validate() const;
};

/// A nav track: the rows of nav.csv, interpolated at image stamps.
class NavTrack {
 public:
  NavTrack() = default;
  /// Throws std::invalid_argument when stamps do not increase strictly or a value is not finite.
  explicit NavTrack(std::vector<NavRecord> rows);

  bool empty() const { return rows_.empty(); }
  const std::vector<NavRecord>& rows() const { return rows_; }
  /// The nav at `stamp_s`: linear between the two rows around it (x, y and sigmas), yaw along the
  /// shorter arc of the circle; a row's own stamp gives that row exactly. False outside the
  /// track's stamps (no extrapolation).
  bool at(double stamp_s, NavRecord* out) const;

  // --- A live track (the odometry nodelet's nav topic) ---
  /// Appends a row; false (nothing changed, `why` says why) when a value is not finite, a sigma
  /// is negative or its stamp is not after the last row's. A stamp more than `restart_after_s`
  /// (> 0) before the last row's is a new clock (a bag played again, a clock reset): the track
  /// starts again from this row (true, `why` says so).
  bool append(const NavRecord& row, std::string* why = nullptr, double restart_after_s = 0.0);
  /// Forgets the rows before `stamp_s`, keeping the last one before it (so at(stamp_s) still works).
  void dropBefore(double stamp_s);
  /// The images' clock jumped back to `stamp_s` (a bag that loops, a clock reset): when the newest row
  /// is more than `tolerance_s` after it, every row is of the clock before the jump (a looping bag's
  /// earlier pass covers the same stamps with readings the new session must not use) and the track is
  /// emptied: returns how many rows were dropped. A track the nav already restarted (append) keeps
  /// its rows.
  std::size_t dropClockBefore(double stamp_s, double tolerance_s);

 private:
  static std::string invalid(const NavRecord& r);  // "" for a row whose values are valid
  std::vector<NavRecord> rows_;
};

/// The nav's motion from a to b (b in a's frame) with the covariance of the model above.
UncertainPose2 navMotion(const NavRecord& a, const NavRecord& b, const NavPriorOptions& options);

/// The nav's placement of a keyframe b relative to an earlier keyframe a, across a stretch the
/// odometry did not carry (a tracking loss, or from one session to the next): b's nav pose in a's
/// nav frame. `one_track`: a and b are readings of one continuous dead reckoning (the pieces of a
/// stream), whose error is systematic: navMotion's covariance, the growth of the nav's sigma over
/// the stretch times nav.inflation (so the distance travelled in the gap sets it, never a fixed
/// sigma). Otherwise (two sessions, each dead-reckoned from its own start in one declared world
/// frame) their accumulated errors are independent: sigma_xy = inflation x sqrt(sigma_xy(a)^2 +
/// sigma_xy(b)^2 + (sigma_yaw(a) |b - a|)^2) (a's heading error turns the vector between them),
/// sigma_yaw = inflation x sqrt(sigma_yaw(a)^2 + sigma_yaw(b)^2), floored as navMotion's.
UncertainPose2 navPlacement(const NavRecord& a, const NavRecord& b, const NavPriorOptions& options, bool one_track);

/// The squared Mahalanobis distance between a visual and a nav motion (summed covariances), and
/// the gate's threshold.
double navGateDistance2(const UncertainPose2& visual, const UncertainPose2& nav);
double navGateThreshold(const NavPriorOptions& options);

/// Empty when the nav's step a -> b could be a motion of the vehicle: its distance at most
/// max_speed_m_s times the time between them plus 3 sigma (navMotion's, on the distance), its turn
/// at most max_yaw_rate_rad_s times the time plus 3 sigma; otherwise why not (for the log).
std::string navStepImplausible(const NavRecord& a, const NavRecord& b, const NavPriorOptions& options);

/// The information-weighted combination of two estimates of one motion, linearised at `visual`.
UncertainPose2 fuseMotions(const UncertainPose2& visual, const UncertainPose2& nav);

}  // namespace core
}  // namespace uw_multislam
