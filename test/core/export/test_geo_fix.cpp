// Fixes as position priors (core/export/geo_fix.h): mapFromFix against fixFromMap and against an
// independently written small-offset formula (meridional and prime-vertical radii of WGS84); the
// matcher's keyframe choice, its waiting list and every refusal counted; a fix given to the
// session manager pulling its keyframe toward it.
#include <gtest/gtest.h>

#include <Eigen/Dense>

#include <cmath>
#include <limits>

#include "../../common/fixtures.h"
#include "uw_multislam/core/export/geo_fix.h"

namespace uw_multislam {
namespace core {
namespace {

constexpr double kA = 6378137.0, kF = 1.0 / 298.257223563;

GeoOrigin datum(double heading_deg = 30.0, double alt_m = 0.0) {
  GeoOrigin o;
  o.lat_deg = 43.0951;
  o.lon_deg = 5.9307;
  o.heading_deg = heading_deg;
  o.alt_m = alt_m;
  return o;
}

TEST(GeoFix, MapFromFixUndoesFixFromMapToTheMillimetre) {
  const Eigen::Matrix2d cov = (Eigen::Matrix2d() << 0.04, 0.012, 0.012, 0.09).finished();
  for (const GeoOrigin& o : {datum(30.0), datum(90.0), datum(-120.0, 35.0), datum(200.0, -4.0)}) {
    for (const Eigen::Vector2d& xy : {Eigen::Vector2d(0.0, 0.0), Eigen::Vector2d(12.5, -3.0),
                                      Eigen::Vector2d(-340.0, 610.0), Eigen::Vector2d(1800.0, 900.0)}) {
      UncertainPose2 pose(Pose2(xy.x(), xy.y(), 0.3), Eigen::Matrix3d::Identity());
      pose.covariance.topLeftCorner<2, 2>() = cov;
      const GeoFix f = fixFromMap(o, pose);
      const Eigen::Matrix2d en_cov =
          (Eigen::Matrix2d() << f.enu_covariance[0], f.enu_covariance[1], f.enu_covariance[3], f.enu_covariance[4])
              .finished();
      const MapPoint p = mapFromFix(o, f.lat_deg, f.lon_deg, en_cov);
      EXPECT_LT((p.xy - xy).norm(), 1e-3)
          << "heading " << o.heading_deg << ": " << p.xy.transpose() << " vs " << xy.transpose();
      EXPECT_LT((p.covariance - cov).norm(), 1e-12) << p.covariance;
    }
  }
}

TEST(GeoFix, MapFromFixAgreesWithTheSmallOffsetFormulaToTheCentimetre) {
  // Written here: east = dlon N cos(lat0), north = dlat M, with WGS84's prime-vertical radius N and
  // meridional radius M at the origin (good to d^2 / R: 2 mm at 150 m); then map's x axis at
  // compass heading h: x = e sin h + n cos h, y = -e cos h + n sin h.
  const double e2 = kF * (2.0 - kF);
  for (const double heading : {30.0, 90.0, -75.0}) {
    const GeoOrigin o = datum(heading);
    const double phi = o.lat_deg * M_PI / 180.0, w = 1.0 - e2 * std::sin(phi) * std::sin(phi);
    const double n_radius = kA / std::sqrt(w), m_radius = kA * (1.0 - e2) / std::pow(w, 1.5);
    for (const Eigen::Vector2d& d_deg :
         {Eigen::Vector2d(0.0009, 0.0), Eigen::Vector2d(-0.0004, 0.0011), Eigen::Vector2d(0.0007, -0.0013)}) {
      const double east = d_deg.y() * M_PI / 180.0 * n_radius * std::cos(phi);
      const double north = d_deg.x() * M_PI / 180.0 * m_radius;
      const double h = heading * M_PI / 180.0;
      const Eigen::Vector2d want(east * std::sin(h) + north * std::cos(h), -east * std::cos(h) + north * std::sin(h));
      const MapPoint p = mapFromFix(o, o.lat_deg + d_deg.x(), o.lon_deg + d_deg.y(), Eigen::Matrix2d::Identity());
      EXPECT_GT(want.norm(), 40.0);
      EXPECT_LT((p.xy - want).norm(), 0.01)
          << "heading " << heading << ": " << p.xy.transpose() << " vs " << want.transpose();
    }
  }
  // Heading 90 is ENU: an east/north covariance stays as it is; heading 0 swaps and signs it.
  const Eigen::Matrix2d en = (Eigen::Matrix2d() << 4.0, 1.0, 1.0, 9.0).finished();
  EXPECT_LT((mapFromFix(datum(90.0), 43.0951, 5.9307, en).covariance - en).norm(), 1e-12);
  const Eigen::Matrix2d north_up = mapFromFix(datum(0.0), 43.0951, 5.9307, en).covariance;  // x north, y west
  EXPECT_LT((north_up - (Eigen::Matrix2d() << 9.0, -1.0, -1.0, 4.0).finished()).norm(), 1e-12) << north_up;
}

// --- The matcher, on a session manager's keyframes. Session 0: keyframes 0..4 at stamps 0..4 s,
// camera poses (k, 0, 0) in image axes; the camera at base_link (no mount).

SessionManagerOptions managerOptions() {
  SessionManagerOptions o;
  o.backend.join_min_loops = 0;
  return o;
}

void addKeyframes(SessionManager* m, int session, int from, int to) {
  for (int k = from; k < to; ++k) {
    const Status st = m->addKeyframe(testing_util::keyframeInput(
        session, k, Pose2(k, 0, 0),
        UncertainPose2(k == 0 ? Pose2() : Pose2(1, 0, 0), Eigen::Vector3d(1e-3, 1e-3, 1e-5).asDiagonal())));
    ASSERT_TRUE(st.ok()) << st.message;
  }
}

// A fix of the z-up map point (x, y) with this east/north... covariance made from a z-up one.
NavFix fixAt(const GeoOrigin& o, double stamp, double x, double y, const Eigen::Matrix2d& zup_cov) {
  UncertainPose2 pose(Pose2(x, y, 0.0), Eigen::Matrix3d::Identity());
  pose.covariance.topLeftCorner<2, 2>() = zup_cov;
  const GeoFix g = fixFromMap(o, pose);
  NavFix f;
  f.stamp_s = stamp;
  f.status = 0;
  f.lat_deg = g.lat_deg;
  f.lon_deg = g.lon_deg;
  f.covariance_type = NavFix::kCovarianceKnown;
  f.covariance = g.enu_covariance;
  f.covariance[8] = 1.0;
  return f;
}

TEST(FixMatcher, AFixIsPlacedOnTheNearestKeyframeInTheCoresFrame) {
  const GeoOrigin o = datum();
  SessionManager m(managerOptions());
  addKeyframes(&m, 0, 0, 5);
  FixOptions opt;
  opt.max_dt_s = 0.3;
  FixMatcher matcher(opt);
  const Eigen::Matrix2d zup = (Eigen::Matrix2d() << 0.04, 0.01, 0.01, 0.09).finished();
  EXPECT_EQ(matcher.add(fixAt(o, 3.2, 3.5, -0.4, zup), true), std::nullopt);
  const std::vector<FixPrior> priors = matcher.match(m.view(), o, 0, CameraMount());
  ASSERT_EQ(priors.size(), 1u);
  EXPECT_EQ(priors[0].session, 0);
  EXPECT_EQ(priors[0].keyframe, 3);
  EXPECT_NEAR(priors[0].dt_s, 0.2, 1e-9);
  // z-up (3.5, -0.4) is (3.5, 0.4) in image axes; the covariance's off-diagonal changes sign.
  EXPECT_LT((priors[0].position - Eigen::Vector2d(3.5, 0.4)).norm(), 1e-3) << priors[0].position.transpose();
  EXPECT_LT((priors[0].covariance - (Eigen::Matrix2d() << 0.04, -0.01, -0.01, 0.09).finished()).norm(), 1e-9)
      << priors[0].covariance;
  EXPECT_EQ(matcher.waiting(), 0u);
}

TEST(FixMatcher, TheFixIsBaseLinksPositionAndThePriorTheCameras) {
  // The camera 0.5 m ahead of base_link, its image columns along base_link's x: a keyframe at
  // camera (2, 0, 0) has base_link at (1.5, 0); a fix putting base_link at (1.5, 1) puts the camera
  // at (2, 1) z-up, (2, -1) in image axes.
  const GeoOrigin o = datum();
  SessionManager m(managerOptions());
  addKeyframes(&m, 0, 0, 4);
  CameraMount mount;
  mount.base_from_camera = Pose2(0.5, 0.0, 0.0);
  FixMatcher matcher{FixOptions()};
  ASSERT_EQ(matcher.add(fixAt(o, 2.0, 1.5, 1.0, Eigen::Matrix2d::Identity()), true), std::nullopt);
  const std::vector<FixPrior> priors = matcher.match(m.view(), o, 0, mount);
  ASSERT_EQ(priors.size(), 1u);
  EXPECT_EQ(priors[0].keyframe, 2);
  EXPECT_LT((priors[0].position - Eigen::Vector2d(2.0, -1.0)).norm(), 1e-3) << priors[0].position.transpose();
}

TEST(FixMatcher, AFixNewerThanEveryKeyframeWaitsForTheNextOneInABoundedList) {
  const GeoOrigin o = datum();
  SessionManager m(managerOptions());
  addKeyframes(&m, 0, 0, 5);
  FixOptions opt;
  opt.max_dt_s = 0.3;
  opt.max_waiting = 2;
  FixMatcher matcher(opt);
  ASSERT_EQ(matcher.add(fixAt(o, 4.8, 5.0, 0.0, Eigen::Matrix2d::Identity()), true), std::nullopt);
  EXPECT_TRUE(matcher.match(m.view(), o, 0, CameraMount()).empty());
  EXPECT_EQ(matcher.waiting(), 1u);
  addKeyframes(&m, 0, 5, 6);  // stamp 5: 0.2 s after the fix, nearer than keyframe 4
  std::vector<FixPrior> priors = matcher.match(m.view(), o, 0, CameraMount());
  ASSERT_EQ(priors.size(), 1u);
  EXPECT_EQ(priors[0].keyframe, 5);
  EXPECT_NEAR(priors[0].dt_s, -0.2, 1e-9);
  // Three fixes with no keyframe after them: the oldest is dropped, counted no_keyframe.
  for (double t : {7.0, 8.0, 9.0})
    EXPECT_EQ(matcher.add(fixAt(o, t, 5.0, 0.0, Eigen::Matrix2d::Identity()), true), std::nullopt);
  EXPECT_EQ(matcher.waiting(), 2u);
  EXPECT_EQ(matcher.refused(FixRefusal::kNoKeyframe), 1);
}

TEST(FixMatcher, EveryRefusalIsCountedByItsReason) {
  const GeoOrigin o = datum();
  SessionManager m(managerOptions());
  addKeyframes(&m, 0, 0, 5);
  FixOptions opt;
  opt.max_dt_s = 0.3;
  FixMatcher matcher(opt);
  const NavFix good = fixAt(o, 3.1, 3.0, 0.0, Eigen::Matrix2d::Identity() * 0.25);
  NavFix f = good;
  f.status = NavFix::kStatusNoFix;
  EXPECT_EQ(matcher.add(f, true), FixRefusal::kNoFix);
  f = good;
  f.lat_deg = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(matcher.add(f, true), FixRefusal::kNotFinite);
  f = good;
  f.lon_deg = std::numeric_limits<double>::infinity();
  EXPECT_EQ(matcher.add(f, true), FixRefusal::kNotFinite);
  f = good;
  f.covariance_type = NavFix::kCovarianceUnknown;
  EXPECT_EQ(matcher.add(f, true), FixRefusal::kUnknownCovariance);
  for (double bad : {0.0, -1.0, std::numeric_limits<double>::quiet_NaN()}) {
    f = good;
    f.covariance[4] = bad;
    EXPECT_EQ(matcher.add(f, true), FixRefusal::kBadVariance) << bad;
  }
  f = good;
  f.covariance[1] = f.covariance[3] = 1.0;  // |correlation| > 1
  EXPECT_EQ(matcher.add(f, true), FixRefusal::kBadVariance);
  EXPECT_EQ(matcher.add(good, false), FixRefusal::kNoDatum);
  EXPECT_EQ(matcher.waiting(), 0u);
  // Matched ones: no keyframe within 0.3 s, the keyframe in another map, the map's origin.
  f = good;
  f.stamp_s = 2.5;
  ASSERT_EQ(matcher.add(f, true), std::nullopt);
  f.stamp_s = 0.1;
  ASSERT_EQ(matcher.add(f, true), std::nullopt);
  std::vector<FixPrior> priors = matcher.match(m.view(), o, 0, CameraMount());
  EXPECT_EQ(matcher.refused(FixRefusal::kNoKeyframe), 1);
  ASSERT_EQ(priors.size(), 1u);  // keyframe 0: placed, then refused by the manager
  EXPECT_EQ(matcher.give(&m, priors), 0);
  EXPECT_EQ(matcher.refused(FixRefusal::kMapOrigin), 1);
  addKeyframes(&m, 1, 0, 3);  // session 1, stamps 100..102: a map of its own
  f.stamp_s = 101.0;
  ASSERT_EQ(matcher.add(f, true), std::nullopt);
  EXPECT_TRUE(matcher.match(m.view(), o, 0, CameraMount()).empty());
  EXPECT_EQ(matcher.refused(FixRefusal::kOtherMap), 1);
  EXPECT_EQ(matcher.refused(FixRefusal::kNoFix), 1);
  EXPECT_EQ(matcher.refused(FixRefusal::kNotFinite), 2);
  EXPECT_EQ(matcher.refused(FixRefusal::kUnknownCovariance), 1);
  EXPECT_EQ(matcher.refused(FixRefusal::kBadVariance), 4);
  EXPECT_EQ(matcher.refused(FixRefusal::kNoDatum), 1);
  EXPECT_EQ(matcher.used(), 0);
  // With ~fix/default_sigma_m an UNKNOWN covariance is that sigma.
  opt.default_sigma_m = 2.0;
  FixMatcher lenient(opt);
  f = good;
  f.stamp_s = 101.1;
  f.covariance_type = NavFix::kCovarianceUnknown;
  ASSERT_EQ(lenient.add(f, true), std::nullopt);
  priors = lenient.match(m.view(), o, 1, CameraMount());
  ASSERT_EQ(priors.size(), 1u);
  EXPECT_LT((priors[0].covariance - 4.0 * Eigen::Matrix2d::Identity()).norm(), 1e-12);
  EXPECT_THROW(FixMatcher(FixOptions{0.0, 0.0, 32}), std::invalid_argument);
  EXPECT_THROW(FixMatcher(FixOptions{0.5, -1.0, 32}), std::invalid_argument);
  EXPECT_THROW(FixMatcher(FixOptions{0.5, 0.0, 0}), std::invalid_argument);
}

TEST(FixMatcher, OneFixPerKeyframeTheNextIsCountedKeyframeHasFix) {
  const GeoOrigin o = datum();
  SessionManager m(managerOptions());
  addKeyframes(&m, 0, 0, 5);
  FixMatcher matcher{FixOptions()};
  for (double t : {3.0, 3.1}) {  // 0.1 s apart: one keyframe, errors shared
    ASSERT_EQ(matcher.add(fixAt(o, t, 3.0, -0.2, Eigen::Matrix2d::Identity() * 0.01), true), std::nullopt);
  }
  const std::vector<FixPrior> priors = matcher.match(m.view(), o, 0, CameraMount());
  ASSERT_EQ(priors.size(), 2u);
  EXPECT_EQ(matcher.give(&m, priors), 1);
  EXPECT_EQ(matcher.used(), 1);
  EXPECT_EQ(matcher.refused(FixRefusal::kKeyframeHasFix), 1);
  EXPECT_EQ(m.view().positionPriors().size(), 1u);
  EXPECT_STREQ(fixRefusalName(FixRefusal::kKeyframeHasFix), "keyframe_has_fix");
}

TEST(FixMatcher, AGivenFixPullsItsKeyframeTowardIt) {
  const GeoOrigin o = datum();
  SessionManager m(managerOptions());
  addKeyframes(&m, 0, 0, 5);
  FixMatcher matcher{FixOptions()};
  // z-up (4, -1) = image axes (4, 1): the odometry says (4, 0); a fix of sigma 0.03 m against
  // odometry of sigma 0.03 m per motion over 4 motions pulls keyframe 4 most of the way (4/5).
  ASSERT_EQ(matcher.add(fixAt(o, 4.0, 4.0, -1.0, Eigen::Matrix2d::Identity() * 0.001), true), std::nullopt);
  EXPECT_EQ(matcher.give(&m, matcher.match(m.view(), o, 0, CameraMount())), 1);
  EXPECT_EQ(matcher.used(), 1);
  const Pose2 after = m.view().poses(0)[4];
  EXPECT_GT(after.y(), 0.5) << after;
  EXPECT_LT((after.translation() - Eigen::Vector2d(4.0, 1.0)).norm(), 0.5) << after;
}

TEST(FixMatcher, TheFixIsTheAntennasPositionAndBaseLinkIsItMinusTheTurnedLeverArm) {
  const GeoOrigin o = datum();
  SessionManager m(managerOptions());
  // Keyframes 1 m apart turning 0.2 rad each (image axes): keyframe 3 heads 0.6 rad off the map's x.
  for (int k = 0; k < 5; ++k) {
    const Status st = m.addKeyframe(testing_util::keyframeInput(
        0, k, Pose2(k, 0, 0.2 * k),
        UncertainPose2(k == 0 ? Pose2() : Pose2(1, 0, 0.2), Eigen::Vector3d(1e-3, 1e-3, 1e-5).asDiagonal())));
    ASSERT_TRUE(st.ok()) << st.message;
  }
  const Pose2 camera = m.view().poses(0)[3];
  ASSERT_NEAR(camera.yaw(), 0.6, 1e-9);
  const double psi = -camera.yaw();  // the vehicle's z-up heading (camera at base_link, columns along x)
  // The antenna 1.2 m forward and 0.4 m to the left of base_link, at z-up (5, -2).
  NavFix f = fixAt(o, 3.0, 5.0, -2.0, Eigen::Matrix2d::Identity() * 0.01);
  f.antenna = Eigen::Vector2d(1.2, 0.4);
  FixOptions opt;
  opt.gate_chi2 = 0.0;  // the fix is far from the keyframe on purpose
  FixMatcher matcher(opt);
  ASSERT_EQ(matcher.add(f, true), std::nullopt);
  const std::vector<FixPrior> priors = matcher.match(m.view(), o, 0, CameraMount());
  ASSERT_EQ(priors.size(), 1u);
  // base_link = antenna - R(psi) (1.2, 0.4), written out; the camera is there, in image axes (x, -y).
  const double bx = 5.0 - (std::cos(psi) * 1.2 - std::sin(psi) * 0.4);
  const double by = -2.0 - (std::sin(psi) * 1.2 + std::cos(psi) * 0.4);
  EXPECT_LT((priors[0].position - Eigen::Vector2d(bx, -by)).norm(), 1e-3) << priors[0].position.transpose();
  // Without the lever arm the prior would be 1.26 m away: the test tells the two apart.
  EXPECT_GT((Eigen::Vector2d(bx, -by) - Eigen::Vector2d(5.0, 2.0)).norm(), 1.2);
  f.antenna.x() = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(matcher.add(f, true), FixRefusal::kNotFinite);
  f.antenna = Eigen::Vector2d(1.2, 0.4);
  f.antenna_known = false;  // tf has no static transform to the fix's frame (yet)
  EXPECT_EQ(matcher.add(f, true), FixRefusal::kNoLeverArm);
  EXPECT_EQ(matcher.refused(FixRefusal::kNoLeverArm), 1);
  EXPECT_STREQ(fixRefusalName(FixRefusal::kNoLeverArm), "no_lever_arm");
}

TEST(FixMatcher, LateInALongDiveTheGateIsTheLastFixDeadReckonedNotTheChainFromTheOrigin) {
  const GeoOrigin o = datum();
  // 31 keyframes 1 m apart, each motion's variances (x, y, yaw) = 1e-3: the chain from the origin
  // to keyframe 30 has a lateral variance of 0.03 + 1e-3 (1² + ... + 29²) = 8.6 m², so against it
  // (times 100) a 20 m jump is within the gate. From a fix on keyframe 28 it is two motions:
  // 2e-3 + 1e-3 = 3e-3 m², and the gate's edge is sqrt(13.8155 (0.3 + 0.01 + 0.01)) = 2.1 m.
  auto dive = [](SessionManager* m) {
    for (int k = 0; k < 31; ++k) {
      const Status st = m->addKeyframe(testing_util::keyframeInput(
          0, k, Pose2(k, 0, 0), UncertainPose2(k == 0 ? Pose2() : Pose2(1, 0, 0), Eigen::Matrix3d::Identity() * 1e-3)));
      ASSERT_TRUE(st.ok()) << st.message;
    }
  };
  const Eigen::Matrix2d r = Eigen::Matrix2d::Identity() * 0.01;
  const NavFix jump = fixAt(o, 30.0, 30.0, -20.0, r);  // image axes (30, 20): 20 m across
  {
    SessionManager m(managerOptions());
    dive(&m);
    FixMatcher alone{FixOptions()};
    ASSERT_EQ(alone.add(jump, true), std::nullopt);
    EXPECT_EQ(alone.match(m.view(), o, 0, CameraMount()).size(), 1u);  // the chain from the origin lets it in
  }
  SessionManager m(managerOptions());
  dive(&m);
  FixMatcher matcher{FixOptions()};
  // A fix on keyframe 28 says the dive is 1 m to the side of the odometry (image axes y + 1).
  ASSERT_EQ(matcher.add(fixAt(o, 28.0, 28.0, -1.0, r), true), std::nullopt);
  ASSERT_EQ(matcher.give(&m, matcher.match(m.view(), o, 0, CameraMount())), 1);
  ASSERT_EQ(matcher.add(jump, true), std::nullopt);
  EXPECT_TRUE(matcher.match(m.view(), o, 0, CameraMount()).empty());
  EXPECT_EQ(matcher.refused(FixRefusal::kOutlier), 1);
  EXPECT_NE(matcher.lastRefusal().find("dead-reckoned from the fix on keyframe 28"), std::string::npos)
      << matcher.lastRefusal();
  // A fix on keyframe 30 that agrees with the one on 28 (1 m to the side, 0.5 m more of drift):
  // within the gate, whether or not the map has been solved with the first one yet.
  ASSERT_EQ(matcher.add(fixAt(o, 30.0, 30.0, -1.5, r), true), std::nullopt);
  EXPECT_EQ(matcher.match(m.view(), o, 0, CameraMount()).size(), 1u);
  EXPECT_EQ(matcher.refused(FixRefusal::kOutlier), 1);
}

TEST(FixMatcher, AFixBeyondTheGateIsRefusedAsAnOutlierAndOneWithinItIsPlaced) {
  const GeoOrigin o = datum();
  SessionManager m(managerOptions());
  // Four 1 m motions along x, each with variances (x, y, yaw) = (1e-3, 1e-3, 1e-3): keyframe 4's
  // chain covariance from the origin, written out (first order): var x = 4e-3; var y = 4e-3 plus
  // each yaw error times the distance still to go, 1e-3 (3² + 2² + 1²) = 0.014.
  const double var_x = 4e-3, var_y = 4e-3 + 1e-3 * 14.0;
  for (int k = 0; k < 5; ++k) {
    const Status st = m.addKeyframe(testing_util::keyframeInput(
        0, k, Pose2(k, 0, 0), UncertainPose2(k == 0 ? Pose2() : Pose2(1, 0, 0), Eigen::Matrix3d::Identity() * 1e-3)));
    ASSERT_TRUE(st.ok()) << st.message;
  }
  EXPECT_NEAR(m.view().keyframeInMap(0, 4).covariance(0, 0), var_x, 1e-9);
  EXPECT_NEAR(m.view().keyframeInMap(0, 4).covariance(1, 1), var_y, 1e-9);
  // S = 100 var + 0.01 (the fix's); across track the gate's edge is sqrt(13.8155 S_yy) = 5.00 m,
  // along it sqrt(13.8155 S_xx) = 2.38 m.
  const double edge_y = std::sqrt(13.8155 * (100.0 * var_y + 0.01)),
               edge_x = std::sqrt(13.8155 * (100.0 * var_x + 0.01));
  const Eigen::Matrix2d r = Eigen::Matrix2d::Identity() * 0.01;
  FixMatcher matcher{FixOptions()};
  ASSERT_EQ(matcher.add(fixAt(o, 4.0, 4.0, -(edge_y - 0.2), r), true), std::nullopt);     // inside
  ASSERT_EQ(matcher.add(fixAt(o, 3.0, 3.0, -(edge_y - 0.2), r), true), std::nullopt);     // keyframe 3: beyond
  ASSERT_EQ(matcher.add(fixAt(o, 2.0, 2.0 + edge_x + 0.2, 0.0, r), true), std::nullopt);  // along: beyond
  const std::vector<FixPrior> priors = matcher.match(m.view(), o, 0, CameraMount());
  ASSERT_EQ(priors.size(), 1u);
  EXPECT_EQ(priors[0].keyframe, 4);
  EXPECT_EQ(matcher.refused(FixRefusal::kOutlier), 2);
  EXPECT_NE(matcher.lastRefusal().find("chi-square"), std::string::npos) << matcher.lastRefusal();
  EXPECT_STREQ(fixRefusalName(FixRefusal::kOutlier), "outlier");
  // Without the gate all three are placed; a bad gate is refused.
  FixOptions off;
  off.gate_chi2 = 0.0;
  FixMatcher open(off);
  for (double t : {2.0, 3.0, 4.0}) ASSERT_EQ(open.add(fixAt(o, t, t, -(edge_y + 1.0), r), true), std::nullopt);
  EXPECT_EQ(open.match(m.view(), o, 0, CameraMount()).size(), 3u);
  FixOptions bad;
  bad.gate_inflation = 0.5;
  EXPECT_THROW(FixMatcher{bad}, std::invalid_argument);
  bad = FixOptions();
  bad.gate_chi2 = -1.0;
  EXPECT_THROW(FixMatcher{bad}, std::invalid_argument);
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
