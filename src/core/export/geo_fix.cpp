#include "uw_multislam/core/export/geo_fix.h"

#include <GeographicLib/LocalCartesian.hpp>

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <stdexcept>

namespace uw_multislam {
namespace core {

MapPoint mapFromFix(const GeoOrigin& o, double lat_deg, double lon_deg, const Eigen::Matrix2d& en_covariance) {
  const GeographicLib::LocalCartesian plane(o.lat_deg, o.lon_deg, o.alt_m);
  // fixFromMap puts (e, n, 0) of the tangent plane on the ellipsoid at the height that point has;
  // find that height (the plane rises d^2 / 2R above the ellipsoid: two steps reach it to the um).
  double e = 0.0, n = 0.0, u = 0.0, h = o.alt_m;
  for (int it = 0; it < 4; ++it) {
    plane.Forward(lat_deg, lon_deg, h, e, n, u);
    h -= u;
  }
  plane.Forward(lat_deg, lon_deg, h, e, n, u);
  const Eigen::Matrix2d r = enuFromMap2(o.heading_deg);  // a rotation: its inverse is its transpose
  MapPoint p;
  p.xy = r.transpose() * Eigen::Vector2d(e, n);
  p.covariance = r.transpose() * en_covariance * r;
  return p;
}

const char* fixRefusalName(FixRefusal r) {
  switch (r) {
    case FixRefusal::kNoFix:
      return "no_fix";
    case FixRefusal::kNotFinite:
      return "not_finite";
    case FixRefusal::kUnknownCovariance:
      return "unknown_covariance";
    case FixRefusal::kBadVariance:
      return "bad_variance";
    case FixRefusal::kNoDatum:
      return "no_datum";
    case FixRefusal::kNoKeyframe:
      return "no_keyframe";
    case FixRefusal::kOtherMap:
      return "other_map";
    case FixRefusal::kMapOrigin:
      return "map_origin";
    case FixRefusal::kKeyframeHasFix:
      return "keyframe_has_fix";
    case FixRefusal::kOutlier:
      return "outlier";
    case FixRefusal::kNoLeverArm:
      return "no_lever_arm";
    case FixRefusal::kCount:
      break;
  }
  return "?";
}

std::string FixOptions::validate() const {
  if (!(max_dt_s > 0.0) || !std::isfinite(max_dt_s)) return "fix/max_dt_s must be > 0 (seconds)";
  if (!(default_sigma_m >= 0.0) || !std::isfinite(default_sigma_m))
    return "fix/default_sigma_m must be >= 0 (0: a fix of unknown covariance is refused)";
  if (max_waiting < 1) return "fix/max_waiting must be >= 1";
  if (!(gate_chi2 >= 0.0) || !std::isfinite(gate_chi2)) return "fix/gate_chi2 must be >= 0 (0: no gate)";
  if (!(gate_inflation >= 1.0) || !std::isfinite(gate_inflation)) return "fix/gate_inflation must be >= 1";
  return "";
}

FixMatcher::FixMatcher(const FixOptions& options) : options_(options) {
  if (const std::string bad = options.validate(); !bad.empty()) throw std::invalid_argument(bad);
}

void FixMatcher::refuse(FixRefusal r, const std::string& why) {
  ++refused_[static_cast<int>(r)];
  last_refusal_ = std::string("fix refused (") + fixRefusalName(r) + "): " + why;
}

std::optional<FixRefusal> FixMatcher::add(const NavFix& f, bool have_datum) {
  char at[64];
  std::snprintf(at, sizeof at, "stamp %.3f", f.stamp_s);
  if (f.status <= NavFix::kStatusNoFix) {
    refuse(FixRefusal::kNoFix, std::string(at) + ": status NO_FIX");
    return FixRefusal::kNoFix;
  }
  if (!std::isfinite(f.lat_deg) || !std::isfinite(f.lon_deg) || std::abs(f.lat_deg) > 90.0 ||
      std::abs(f.lon_deg) > 180.0) {
    refuse(FixRefusal::kNotFinite,
           std::string(at) + ": latitude/longitude " + std::to_string(f.lat_deg) + ", " + std::to_string(f.lon_deg));
    return FixRefusal::kNotFinite;
  }
  if (!f.antenna.allFinite()) {
    refuse(FixRefusal::kNotFinite, std::string(at) + ": its lever arm from base_link is not finite");
    return FixRefusal::kNotFinite;
  }
  // Taken as base_link's position instead, it would be off by the arm for good (stored, and the
  // keyframe's one fix spent): refused until the arm is known.
  if (!f.antenna_known) {
    refuse(FixRefusal::kNoLeverArm, std::string(at) + ": where its frame sits on the vehicle is not known");
    return FixRefusal::kNoLeverArm;
  }
  Eigen::Matrix2d c;
  if (f.covariance_type == NavFix::kCovarianceUnknown) {
    if (options_.default_sigma_m <= 0.0) {
      refuse(FixRefusal::kUnknownCovariance,
             std::string(at) + ": covariance type UNKNOWN and ~fix/default_sigma_m is not set (> 0)");
      return FixRefusal::kUnknownCovariance;
    }
    c = Eigen::Matrix2d::Identity() * options_.default_sigma_m * options_.default_sigma_m;
  } else if (f.covariance_type == NavFix::kCovarianceDiagonalKnown) {
    c << f.covariance[0], 0.0, 0.0, f.covariance[4];
  } else {
    c << f.covariance[0], f.covariance[1], f.covariance[3], f.covariance[4];
  }
  if (!c.allFinite() || !(c(0, 0) > 0.0) || !(c(1, 1) > 0.0) || std::abs(c(0, 1) - c(1, 0)) > 1e-9 * c.norm() ||
      !(c.determinant() > 0.0)) {
    refuse(FixRefusal::kBadVariance, std::string(at) + ": east/north covariance [" + std::to_string(c(0, 0)) + ", " +
                                         std::to_string(c(0, 1)) + "; " + std::to_string(c(1, 0)) + ", " +
                                         std::to_string(c(1, 1)) + "] is not positive definite");
    return FixRefusal::kBadVariance;
  }
  if (!have_datum) {
    refuse(FixRefusal::kNoDatum, std::string(at) + ": no datum yet (~datum/* or set_datum)");
    return FixRefusal::kNoDatum;
  }
  if (static_cast<int>(waiting_.size()) >= options_.max_waiting) {
    char why[160];
    std::snprintf(why, sizeof why, "stamp %.3f: no keyframe came after it while %d newer fixes waited",
                  waiting_.front().fix.stamp_s, options_.max_waiting);
    refuse(FixRefusal::kNoKeyframe, why);
    waiting_.pop_front();
  }
  waiting_.push_back({f, c});
  return std::nullopt;
}

std::optional<std::string> FixMatcher::outOfGate(const SessionQueries& m, const std::vector<PriorRecord>& held,
                                                 int session, int keyframe, const std::vector<Pose2>& poses,
                                                 const FixPrior& prior) const {
  // The prediction: dead-reckoned from the nearest earlier keyframe of the session that has a prior
  // (that prior's position plus the estimate's displacement since; the chain's covariance between
  // the two, turned into the map, plus the prior's), else the keyframe's estimate with the chain
  // from its map's origin. Anchored, the gate stays as tight over a long dive as between two fixes
  // (the chain from the origin grows with the cube of the distance through yaw), and it does not
  // wait for the map to be solved with the earlier prior.
  const PriorRecord* anchor = nullptr;
  for (const PriorRecord& r : held)
    if (r.session == session && r.keyframe < keyframe && (anchor == nullptr || r.keyframe > anchor->keyframe))
      anchor = &r;
  Eigen::Vector2d predicted = poses[keyframe].translation();
  Eigen::Matrix2d spread;
  if (anchor != nullptr) {
    const Pose2& from = poses[anchor->keyframe];
    predicted = anchor->position + (predicted - from.translation());
    const Eigen::Matrix2d turn = Eigen::Rotation2Dd(from.yaw()).toRotationMatrix();
    const Eigen::Matrix2d chain = m.keyframeChain(session, anchor->keyframe, keyframe).covariance.topLeftCorner<2, 2>();
    spread = options_.gate_inflation * turn * chain * turn.transpose() + anchor->covariance;
  } else {
    spread = options_.gate_inflation * m.keyframeInMap(session, keyframe).covariance.topLeftCorner<2, 2>();
    if (spread.isZero(0.0)) return std::nullopt;  // its map's origin: the manager refuses it as such
  }
  const Eigen::Vector2d nu = prior.position - predicted;
  const double d2 = nu.dot((spread + prior.covariance).ldlt().solve(nu));
  if (d2 <= options_.gate_chi2) return std::nullopt;
  char why[200];
  std::snprintf(why, sizeof why, "%.2f m from keyframe %d of session %d as %s, chi-square %.1f > ~fix/gate_chi2 %.1f",
                nu.norm(), keyframe, session,
                anchor != nullptr
                    ? ("dead-reckoned from the fix on keyframe " + std::to_string(anchor->keyframe)).c_str()
                    : "the map places it",
                d2, options_.gate_chi2);
  return std::string(why);
}

std::vector<FixPrior> FixMatcher::match(const SessionQueries& m, const std::optional<GeoOrigin>& datum, int datum_map,
                                        const CameraMount& mount) {
  std::vector<FixPrior> out;
  if (waiting_.empty()) return out;
  double newest = -std::numeric_limits<double>::infinity();
  for (int id : m.sessionIds())
    if (m.has(id) && m.hasKeyframe(id) && !m.stamps(id).empty()) newest = std::max(newest, m.stamps(id).back());
  const std::vector<PriorRecord> held = options_.gate_chi2 > 0.0 ? m.positionPriors() : std::vector<PriorRecord>();
  std::deque<Waiting> still;
  for (const Waiting& w : waiting_) {
    const NavFix& f = w.fix;
    if (!(f.stamp_s <= newest)) {  // newer than every keyframe: the next one may be nearer
      still.push_back(w);
      continue;
    }
    char at[64];
    std::snprintf(at, sizeof at, "stamp %.3f", f.stamp_s);
    if (!datum) {
      refuse(FixRefusal::kNoDatum, std::string(at) + ": no datum");
      continue;
    }
    int best_session = -1, best_keyframe = -1;
    double best = std::numeric_limits<double>::infinity();
    for (int id : m.sessionIds()) {
      if (!m.has(id) || !m.hasKeyframe(id)) continue;
      // A session's stamps increase: the nearest is one of the two around the fix's.
      const std::vector<double>& stamps = m.stamps(id);
      const auto after = std::lower_bound(stamps.begin(), stamps.end(), f.stamp_s);
      for (auto it = after == stamps.begin() ? after : after - 1; it != stamps.end() && it <= after; ++it) {
        const double dt = f.stamp_s - *it;
        if (std::abs(dt) < std::abs(best)) {
          best = dt;
          best_session = id;
          best_keyframe = static_cast<int>(it - stamps.begin());
        }
      }
    }
    if (best_session < 0 || !(std::abs(best) <= options_.max_dt_s)) {
      char why[160];
      std::snprintf(why, sizeof why, "%s: the nearest keyframe is %.3f s away (~fix/max_dt_s %.3f)", at, std::abs(best),
                    options_.max_dt_s);
      refuse(FixRefusal::kNoKeyframe, why);
      continue;
    }
    const int map = m.mapOf(best_session);
    if (map != datum_map) {
      refuse(FixRefusal::kOtherMap, std::string(at) + ": its keyframe " + std::to_string(best_keyframe) +
                                        " of session " + std::to_string(best_session) + " is in map " +
                                        std::to_string(map) + ", the datum places map " + std::to_string(datum_map));
      continue;
    }
    // The fix is the antenna's position in the z-up map; the keyframe is the camera's pose in image
    // axes. The vehicle keeps the keyframe's current heading, moved so that its antenna is at the
    // fix; the camera follows it.
    const MapPoint p = mapFromFix(*datum, f.lat_deg, f.lon_deg, w.covariance);
    const std::vector<Pose2> poses = m.poses(best_session);
    const Pose2 camera = poses[best_keyframe];
    const Pose2 vehicle = vehicleFromCamera(camera, mount);
    const Eigen::Vector2d base = p.xy - Eigen::Rotation2Dd(vehicle.yaw()) * f.antenna;
    const Pose2 moved = cameraFromVehicle(Pose2(base.x(), base.y(), vehicle.yaw()), mount);
    FixPrior prior;
    prior.session = best_session;
    prior.keyframe = best_keyframe;
    prior.dt_s = best;
    prior.position = moved.translation();
    // z-up -> image axes is (x, y) -> (x, -y): the covariance's off-diagonal changes sign.
    const Eigen::Matrix2d flip = Eigen::Vector2d(1.0, -1.0).asDiagonal();
    prior.covariance = flip * p.covariance * flip;
    if (options_.gate_chi2 > 0.0) {
      const std::optional<std::string> far = outOfGate(m, held, best_session, best_keyframe, poses, prior);
      if (far) {
        refuse(FixRefusal::kOutlier, std::string(at) + ": " + *far);
        continue;
      }
    }
    out.push_back(prior);
  }
  waiting_ = std::move(still);
  return out;
}

int FixMatcher::give(SessionManager* m, const std::vector<FixPrior>& priors) {
  int taken = 0;
  for (const FixPrior& p : priors) {
    const Status st = m->addPositionPrior(p.session, p.keyframe, p.position, p.covariance);
    if (st.ok()) {
      ++used_;
      ++taken;
    } else {
      const FixRefusal why = st.code == StatusCode::kFailedPrecondition ? FixRefusal::kMapOrigin
                             : st.code == StatusCode::kAlreadyExists    ? FixRefusal::kKeyframeHasFix
                                                                        : FixRefusal::kNoKeyframe;
      refuse(why, st.message);
    }
  }
  return taken;
}

}  // namespace core
}  // namespace uw_multislam
