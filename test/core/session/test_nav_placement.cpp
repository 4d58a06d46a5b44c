// The nav's placement of a new piece or session (nav_prior.h navPlacement, tracking.h NavPlacement,
// SessionManager::addNavPlacement): its covariance against a Monte-Carlo of a dead reckoning
// simulated here on its own, the odometry's placement after a tracking loss, the manager putting
// the piece in its predecessor's map from its first keyframe, loops refining it, the store keeping
// it (and its kind) across a restart, and the back-end never taking it as visual evidence.
#include <gtest/gtest.h>

#include <Eigen/LU>

#include <cmath>
#include <functional>
#include <optional>
#include <random>
#include <vector>

#include "../../common/fixtures.h"
#include "../../common/rendered_seabed.h"
#include "../../common/scoped_temp_dir.h"
#include "../../common/sql_file.h"
#include "uw_multislam/core/backend/backend.h"
#include "uw_multislam/core/frontend/nav_prior.h"
#include "uw_multislam/core/frontend/tracking.h"
#include "uw_multislam/core/session/frame_stream.h"
#include "uw_multislam/core/session/nav_placer.h"
#include "uw_multislam/core/session/session_manager.h"
#include "uw_multislam/core/store/session_store.h"
#include "uw_multislam/core/store/store_merge.h"

namespace uw_multislam {
namespace core {
namespace {

// --- The covariance against a Monte-Carlo -------------------------------------------------------

// A DVL/INS dead reckoning written here apart from the simulator: a scale error s ~ N(0, sigma_s)
// on the body displacement, a heading bias b ~ N(0, sigma_b), a position random walk of
// `walk` m/sqrt(m); its stated sigma what a nav.csv states for that model (make_survey's):
// hypot(sigma_s, sigma_b) x distance + walk x sqrt(distance), sigma_yaw sigma_b.
struct DeadReckoning {
  double sigma_s = 0.007, sigma_b = 0.007, walk = 0.002;
  std::vector<NavRecord> fly(const std::vector<Pose2>& truth, std::mt19937_64* rng) const {
    std::normal_distribution<double> g(0.0, 1.0);
    const double s = sigma_s * g(*rng), b = sigma_b * g(*rng);
    std::vector<NavRecord> nav;
    Eigen::Vector2d p = truth.front().translation();
    double distance = 0.0;
    for (std::size_t k = 0; k < truth.size(); ++k) {
      if (k > 0) {
        const Eigen::Vector2d step = truth[k].translation() - truth[k - 1].translation();
        distance += step.norm();
        p += Pose2(0, 0, b).rotation() * ((1.0 + s) * step) +
             walk * std::sqrt(step.norm()) * Eigen::Vector2d(g(*rng), g(*rng));
      }
      nav.push_back({1.0 * k, Pose2(p.x(), p.y(), truth[k].yaw() + b),
                     std::hypot(sigma_s, sigma_b) * distance + walk * std::sqrt(distance), sigma_b});
    }
    return nav;
  }
};

// 0.4 m steps: 10 m east, a quarter turn, 10 m north (the turn inside the stretch).
std::vector<Pose2> lShapedTrack(const Pose2& start) {
  std::vector<Pose2> t;
  for (int k = 0; k <= 25; ++k) t.push_back(compose(start, Pose2(0.4 * k, 0, 0)));
  for (int k = 1; k <= 25; ++k) t.push_back(compose(start, Pose2(10, 0.4 * k, M_PI / 2)));
  return t;
}

struct Coverage {
  double inside = 0.0;          // fraction of runs with d^2 (3 dof) within the 0.99 quantile
  double sigma_over_rms = 0.0;  // the placement's sigma_xy over the runs' rms error per axis
};

template <typename Place>
Coverage monteCarlo(Place place, int runs) {
  std::mt19937_64 rng(7);
  int inside = 0;
  double sum2 = 0.0, sigma = 0.0;
  for (int r = 0; r < runs; ++r) {
    Pose2 truth_a, truth_b;
    const UncertainPose2 z = place(&rng, &truth_a, &truth_b);
    const Pose2 truth = between(truth_a, truth_b);
    const Eigen::Vector3d e(z.mean.x() - truth.x(), z.mean.y() - truth.y(), normalizeAngle(z.mean.yaw() - truth.yaw()));
    if (e.dot(z.covariance.inverse() * e) <= 11.345) ++inside;  // chi-square 3 dof, 0.99
    sum2 += 0.5 * e.head<2>().squaredNorm();
    sigma += std::sqrt(z.covariance(0, 0)) / runs;
  }
  return {static_cast<double>(inside) / runs, sigma / std::sqrt(sum2 / runs)};
}

TEST(NavPlacement, OneTracksCovarianceIsTheDriftOverTheStretchAndCoversAMonteCarlo) {
  NavPriorOptions o;
  const DeadReckoning dr;
  const std::vector<Pose2> track = lShapedTrack(Pose2(3, 2, 0.3));
  // The drift model written out: a at 4 m travelled, b at 16 m: inflation x hypot(s, b) x 12 m,
  // plus the random walk's growth.
  std::mt19937_64 rng(1);
  const std::vector<NavRecord> nav = dr.fly(track, &rng);
  const UncertainPose2 z = navPlacement(nav[10], nav[40], o, true);
  const double expected = 2.0 * (std::hypot(0.007, 0.007) * 12.0 + 0.002 * (std::sqrt(16.0) - std::sqrt(4.0)));
  EXPECT_NEAR(std::sqrt(z.covariance(0, 0)), expected, 1e-9);
  EXPECT_NEAR(std::sqrt(z.covariance(1, 1)), expected, 1e-9);
  EXPECT_NEAR(std::sqrt(z.covariance(2, 2)), o.min_sigma_rad, 1e-12) << "a constant heading bias: the floor";
  const Pose2 nav_motion = between(nav[10].pose, nav[40].pose);
  EXPECT_NEAR(z.mean.x(), nav_motion.x(), 1e-12);
  EXPECT_NEAR(z.mean.y(), nav_motion.y(), 1e-12);
  // Monte-Carlo: the nav's motion across the turn is within the placement's covariance (99 % of
  // runs at the 0.99 quantile): a true loop is never refused against it. It is conservative by
  // design, not loose without bound: nav.inflation (2) x the stated drift hypot(s, b) over the
  // scale error s alone (sqrt 2: a constant heading bias cancels within one track) x the path over
  // the displacement (12 m / 8.5 m) x sqrt 2 (the error lies along the displacement, one axis):
  // 5.66 times the rms error per axis.
  const Coverage c = monteCarlo(
      [&](std::mt19937_64* g, Pose2* ta, Pose2* tb) {
        const std::vector<NavRecord> n = dr.fly(track, g);
        *ta = track[10];
        *tb = track[40];
        return navPlacement(n[10], n[40], o, true);
      },
      4000);
  EXPECT_GE(c.inside, 0.99);
  EXPECT_NEAR(c.sigma_over_rms, 2.0 * std::sqrt(2.0) * (12.0 / std::hypot(6.0, 6.0)) * std::sqrt(2.0), 0.5);
  // A fixed small sigma (the nav prior's 5 mm floor) would be refused against by the truth.
  NavPriorOptions tiny = o;
  tiny.inflation = 1.0;
  const Coverage overconfident = monteCarlo(
      [&](std::mt19937_64* g, Pose2* ta, Pose2* tb) {
        const std::vector<NavRecord> n = dr.fly(track, g);
        *ta = track[10];
        *tb = track[40];
        UncertainPose2 p = navPlacement(n[10], n[40], tiny, true);
        p.covariance.topLeftCorner<2, 2>() = Eigen::Matrix2d::Identity() * tiny.min_sigma_m * tiny.min_sigma_m;
        return p;
      },
      1000);
  EXPECT_LT(overconfident.inside, 0.5);
}

TEST(NavPlacement, TwoSessionsErrorsAreIndependentAndTheHeadingErrorReachesAcrossTheGap) {
  NavPriorOptions o;
  const DeadReckoning dr;
  // Session a flies the L from (0, 0); session b starts 6 m west of a's end, its own dead
  // reckoning from a known start (sigma 0 there), in the same world frame.
  const std::vector<Pose2> a = lShapedTrack(Pose2());
  const std::vector<Pose2> b = lShapedTrack(Pose2(4, 10, M_PI));
  const Coverage c = monteCarlo(
      [&](std::mt19937_64* g, Pose2* ta, Pose2* tb) {
        const std::vector<NavRecord> na = dr.fly(a, g), nb = dr.fly(b, g);
        *ta = a.back();
        *tb = b.front();
        return navPlacement(na.back(), nb.front(), o, false);
      },
      4000);
  // Covered, and conservative by about the same factors as one track (the inflation, the stated
  // drift over the path against an error over the displacement).
  EXPECT_GE(c.inside, 0.99);
  EXPECT_GE(c.sigma_over_rms, 2.0);
  EXPECT_LE(c.sigma_over_rms, 6.0);
  std::mt19937_64 rng(3);
  const NavRecord end = dr.fly(a, &rng).back(), start = dr.fly(b, &rng).front();
  const UncertainPose2 z = navPlacement(end, start, o, false);
  const double reach = 0.007 * (start.pose.translation() - end.pose.translation()).norm();
  EXPECT_NEAR(std::sqrt(z.covariance(0, 0)), 2.0 * std::hypot(end.sigma_xy_m, reach), 1e-9);
  EXPECT_NEAR(std::sqrt(z.covariance(2, 2)), 2.0 * std::hypot(0.007, 0.007), 1e-9);
}

// --- The odometry's placement after a tracking loss ---------------------------------------------

// One stream through the front end (FrameStream, as both heads drive it): frame k at stamp k over the
// straight pass, 0.25 m a frame, frames [blank_from, blank_to) blank, `nav(k)` its reading. Returns
// each frame's result; `closed`: the last nav keyframe (id, frame) of the piece a tracking loss closed.
struct Flight {
  std::vector<FrameResult> steps;
  int last_nav_kf = -1, last_nav_frame = -1;
  // The placement sent with frame k's keyframes, if any.
  std::optional<NavPlacementInput> placementAt(int k) const {
    for (const StreamKeyframe& kf : steps[k].keyframes)
      if (kf.input.nav_placement) return kf.input.nav_placement;
    return std::nullopt;
  }
  bool closedAt(int k) const {
    for (const auto& e : steps[k].ended)
      if (e.cause == SessionEnd::kTrackingLoss) return true;
    return false;
  }
};

class NavPlacementTracking : public testing_util::RenderedSeabedTest {
 protected:
  Flight fly(const OdometryOptions& options, const std::function<std::optional<NavRecord>(int)>& nav, int frames = 24,
             int blank_from = 10, int blank_to = 18) const {
    SlamConfig config;
    config.odometry = options;
    FrameStream stream(config, StampGuardOptions());
    stream.beginStream();
    const cv::Mat grey(240, 320, CV_8UC3, cv::Scalar(90, 110, 60));
    Flight f;
    for (int k = 0; k < frames; ++k) {
      FrameInput in;
      in.image = (k >= blank_from && k < blank_to) ? grey : render(Pose2(2.0 + 0.25 * k, 4.0, 0.0), 2.0);
      in.camera = camera_;
      in.altitude_m = 2.0;
      in.stamp_s = 1.0 * k;
      in.index = k;
      in.nav = [&nav, k](bool) { return nav(k); };
      f.steps.push_back(stream.process(in));
      if (f.closedAt(k)) {
        const auto last = stream.odometry()->lastNavKeyframe();
        if (last) {
          f.last_nav_kf = last->first;
          f.last_nav_frame = stream.odometry()->odometry()->keyframes()[last->first].frame_index;
        }
      }
    }
    return f;
  }
};

TEST_F(NavPlacementTracking, APieceAfterATrackingLossIsPlacedByTheNavFromThePreviousPiecesLastNavKeyframe) {
  // The straight pass, 0.25 m a frame; frames 10-17 blank. The nav's heading turns 2.5 rad at
  // frame 12 (beyond nav.max_yaw_rate_rad_s: refused, the piece ends at frame 13 with one
  // bridged frame); the second piece starts at frame 18.
  const auto nav = [](int k) -> std::optional<NavRecord> {
    if (k < 12) return NavRecord{1.0 * k, Pose2(0.25 * k, 0.0, 0.0), 0.01 * 0.25 * k, 0.001};
    const double d = 0.25 * (k - 12);
    return NavRecord{1.0 * k, Pose2(3.0 + d * std::cos(2.5), d * std::sin(2.5), 2.5), 0.01 * 0.25 * k, 0.001};
  };
  OdometryOptions one_bridged;
  one_bridged.fallback.bridge_frames = 1;
  const Flight f = fly(one_bridged, nav);
  ASSERT_TRUE(f.closedAt(13));
  ASSERT_TRUE(f.steps[18].started.has_value());
  EXPECT_EQ(f.steps[18].started->cause, SessionCause::kTrackingResumed);
  ASSERT_GE(f.last_nav_kf, 0);
  EXPECT_LE(f.last_nav_frame, 11) << "a keyframe whose reading was accepted, before the refused turn";
  const std::optional<NavPlacementInput> p = f.placementAt(18);
  ASSERT_TRUE(p.has_value());
  EXPECT_EQ(p->session, 0) << "against the piece the loss closed";
  EXPECT_EQ(p->keyframe, f.last_nav_kf);
  EXPECT_EQ(f.steps[18].keyframes[0].input.keyframe, 0) << "carried by the new piece's first keyframe";
  // The nav's motion from that keyframe's reading to frame 18's, with the growth of its sigma
  // (1 % of 0.25 m a frame) times nav.inflation.
  const Pose2 nav_motion = between(nav(f.last_nav_frame)->pose, nav(18)->pose);
  EXPECT_NEAR(p->z.mean.x(), nav_motion.x(), 1e-12);
  EXPECT_NEAR(p->z.mean.y(), nav_motion.y(), 1e-12);
  EXPECT_NEAR(p->z.mean.yaw(), nav_motion.yaw(), 1e-12);
  const double sigma = 2.0 * 0.01 * 0.25 * (18 - f.last_nav_frame);
  EXPECT_NEAR(std::sqrt(p->z.covariance(0, 0)), sigma, 1e-12);
  for (int k = 0; k < 24; ++k) EXPECT_EQ(f.placementAt(k).has_value(), k == 18) << k;
  // Off: nav.place_pieces false, or no nav (then the path is the one without nav).
  OdometryOptions off = one_bridged;
  off.nav.place_pieces = false;
  const Flight not_placing = fly(off, nav);
  EXPECT_TRUE(not_placing.steps[18].started.has_value());
  for (int k = 0; k < 24; ++k) EXPECT_FALSE(not_placing.placementAt(k).has_value()) << k;
  OdometryOptions disabled = one_bridged;
  disabled.nav.enabled = false;
  const Flight no_nav = fly(disabled, nav);
  for (int k = 0; k < 24; ++k) EXPECT_FALSE(no_nav.placementAt(k).has_value()) << k;
}

TEST_F(NavPlacementTracking, ANavReadingRefusedAsAJumpNeverPlacesThePieceAfterTheTrackingLoss) {
  // The nav jumps 1 km east at frame 10, where vision goes blank, and stays there: each reading is
  // refused as no motion of the vehicle (nav_implausible), no visual keyframe takes it as a new
  // anchor, the piece ends (no visual motion and no usable nav reading past the bridged frames).
  // The next piece's first reading is the jumped one: a placement from the last accepted reading
  // would put the piece 1 km away.
  const auto nav = [](int k) -> std::optional<NavRecord> {
    return NavRecord{1.0 * k, Pose2(0.25 * k + (k >= 10 ? 1000.0 : 0.0), 0.0, 0.0), 0.01 * 0.25 * k, 0.001};
  };
  const Flight f = fly(OdometryOptions(), nav);
  int closed = -1, implausible = 0;
  for (int k = 0; k < 24; ++k) {
    if (f.closedAt(k)) closed = k;
    implausible += !f.steps[k].update.nav_note.empty();
  }
  ASSERT_GT(closed, 10) << "the blank frames end the piece";
  EXPECT_GE(implausible, 5) << "the jumped readings are refused";
  int resumed = -1;
  for (int k = closed + 1; k < 24 && resumed < 0; ++k)
    if (f.steps[k].started) resumed = k;
  ASSERT_GE(resumed, 18);
  for (int k = 0; k < 24; ++k) EXPECT_FALSE(f.placementAt(k).has_value()) << k;
  ASSERT_EQ(f.steps[resumed].warnings.size(), 1u);
  EXPECT_NE(f.steps[resumed].warnings[0].find("is not placed by the nav after the tracking loss: nav step of"),
            std::string::npos)
      << f.steps[resumed].warnings[0];
  // The same loss with a nav that did not jump: placed (the refusal is the jump's, not the loss's).
  const auto steady = [](int k) -> std::optional<NavRecord> {
    return NavRecord{1.0 * k, Pose2(0.25 * k, 0.0, 0.0), 0.01 * 0.25 * k, 0.001};
  };
  OdometryOptions new_session;
  new_session.nav.on_tracking_loss = TrackingLossPolicy::kNewSession;
  const Flight g = fly(new_session, steady);
  int placed = 0;
  for (int k = 0; k < 24; ++k) placed += g.placementAt(k).has_value();
  EXPECT_EQ(placed, 1);
}

// --- A new session live, in a world-fixed nav frame -------------------------------------------------

// One straight pass, 0.25 m a frame; the nav continuous in one world frame across the sessions
// (0.01 x distance, yaw 0.002 rad).
NavRecord worldNav(int k) { return {1.0 * k, Pose2(0.25 * k, 0.0, 0.0), 0.01 * 0.25 * k, 0.002}; }

// Sessions of one stream (start_session at frame `first` of each), as the odometry nodelet feeds them;
// each frame's placement and log lines.
struct PlacedStep {
  std::optional<NavPlacementInput> placement;
  std::string said;
};

TEST_F(NavPlacementTracking, ANewSessionInAWorldFixedNavFrameIsPlacedAgainstThePreviousSessionsLastNavKeyframe) {
  SlamConfig config;
  const auto session = [&](FrameStream* stream, int id, int first, int last, std::vector<PlacedStep>* out,
                           std::optional<std::pair<int, NavRecord>>* last_nav = nullptr) {
    for (int k = first; k < last; ++k) {
      FrameInput in;
      in.image = render(Pose2(2.0 + 0.25 * k, 4.0, 0.0), 2.0);
      in.camera = camera_;
      in.altitude_m = 2.0;
      in.stamp_s = 1.0 * k;
      in.nav = [k](bool) { return std::optional<NavRecord>(worldNav(k)); };
      if (k == first) in.requested.session = id;
      const FrameResult r = stream->process(in);
      PlacedStep p;
      for (const StreamKeyframe& kf : r.keyframes)
        if (kf.input.nav_placement) p.placement = kf.input.nav_placement;
      for (const auto& lines : {r.notes, r.warnings})
        for (const std::string& l : lines) p.said += l;
      out->push_back(p);
    }
    if (last_nav) *last_nav = stream->odometry()->lastNavKeyframe();
    EXPECT_EQ(stream->odometry()->sessions(), 1);
  };
  const auto worldFixed = [](FrameStream* s) { s->beginStream(NavFrame{"odom"}); };
  // Session 0 over frames 0-11, session 1 (after a gap: frames 12-15 never processed) from 16.
  FrameStream stream(config, StampGuardOptions());
  worldFixed(&stream);
  std::vector<PlacedStep> s0, s1;
  std::optional<std::pair<int, NavRecord>> end0;
  session(&stream, 0, 0, 12, &s0, &end0);
  ASSERT_TRUE(end0.has_value());
  // The first session since the stream started: nothing known to place it against, said once.
  EXPECT_FALSE(s0[0].placement.has_value());
  EXPECT_NE(s0[0].said.find("session 0 is not placed by the nav: no earlier keyframe"), std::string::npos)
      << s0[0].said;
  for (std::size_t k = 1; k < s0.size(); ++k) EXPECT_TRUE(s0[k].said.empty()) << k << ": " << s0[k].said;
  session(&stream, 1, 16, 20, &s1);
  ASSERT_TRUE(s1[0].placement.has_value());
  const NavPlacementInput& p = *s1[0].placement;
  EXPECT_EQ(p.session, 0);
  EXPECT_EQ(p.keyframe, end0->first) << "the last kept keyframe with a reading";
  // Frame 16's reading in that keyframe's, the two readings' errors independent (as offline).
  const int from = static_cast<int>(std::lround(end0->second.stamp_s));
  const Pose2 expected = between(worldNav(from).pose, worldNav(16).pose);
  EXPECT_NEAR(p.z.mean.x(), expected.x(), 1e-12);
  EXPECT_NEAR(p.z.mean.y(), expected.y(), 1e-12);
  EXPECT_NEAR(p.z.mean.yaw(), expected.yaw(), 1e-12);
  EXPECT_GT(p.z.mean.x(), 1.0) << "at least the four frames never processed";
  const UncertainPose2 independent = navPlacement(worldNav(from), worldNav(16), config.odometry.nav, false);
  EXPECT_EQ(p.z.covariance, independent.covariance);
  const double reach = 0.002 * (16 - from) * 0.25;
  EXPECT_NEAR(std::sqrt(p.z.covariance(0, 0)),
              config.odometry.nav.inflation * std::sqrt(std::pow(worldNav(from).sigma_xy_m, 2) +
                                                        std::pow(worldNav(16).sigma_xy_m, 2) + reach * reach),
              1e-12);
  EXPECT_NE(s1[0].said.find("session 1 placed by the nav in the nav's world frame odom against session 0"),
            std::string::npos)
      << s1[0].said;
  for (std::size_t k = 1; k < s1.size(); ++k) EXPECT_FALSE(s1[k].placement.has_value()) << k;

  // Not world-fixed (the default), or no nav prior, or nav.place_pieces false: a new session is
  // not placed, and nothing is said of it.
  SlamConfig no_nav = config;
  no_nav.odometry.nav.enabled = false;
  SlamConfig not_placing = config;
  not_placing.odometry.nav.place_pieces = false;
  for (int variant = 0; variant < 3; ++variant) {
    FrameStream off(variant == 1 ? no_nav : variant == 2 ? not_placing : config, StampGuardOptions());
    if (variant == 0) {
      off.beginStream();
    } else {
      worldFixed(&off);
    }
    std::vector<PlacedStep> a, b;
    session(&off, 0, 0, 12, &a);
    session(&off, 1, 16, 20, &b);
    for (const auto& x : {a, b})
      for (const PlacedStep& y : x) {
        EXPECT_FALSE(y.placement.has_value()) << variant;
        EXPECT_TRUE(y.said.empty()) << variant << ": " << y.said;
      }
  }
  // A restarted odometry knows nothing of the sessions before it: its first session is not placed
  // (said once, not again), the next one is placed against it.
  FrameStream restarted(config, StampGuardOptions(), {}, 5);
  worldFixed(&restarted);
  std::vector<PlacedStep> r1, r2;
  session(&restarted, 5, 16, 20, &r1);
  EXPECT_FALSE(r1[0].placement.has_value());
  EXPECT_FALSE(r1[0].said.empty());
  session(&restarted, 6, 20, 24, &r2);
  ASSERT_TRUE(r2[0].placement.has_value());
  EXPECT_EQ(r2[0].placement->session, 5);
  // The world-fixed nav jumping 1 km between two sessions of one stream: the new one is not placed.
  FrameStream jumped(config, StampGuardOptions());
  worldFixed(&jumped);
  std::vector<PlacedStep> j0;
  session(&jumped, 0, 0, 12, &j0);
  FrameInput in;
  in.image = render(Pose2(2.0 + 0.25 * 16, 4.0, 0.0), 2.0);
  in.camera = camera_;
  in.altitude_m = 2.0;
  in.stamp_s = 16.0;
  in.nav = [](bool) {
    NavRecord r = worldNav(16);
    r.pose = compose(Pose2(1000.0, 0.0, 0.0), r.pose);
    return std::optional<NavRecord>(r);
  };
  in.requested.session = 1;
  const FrameResult r = jumped.process(in);
  ASSERT_TRUE(r.started.has_value());
  ASSERT_FALSE(r.keyframes.empty());
  EXPECT_FALSE(r.keyframes[0].input.nav_placement.has_value());
  ASSERT_EQ(r.warnings.size(), 1u);
  EXPECT_NE(r.warnings[0].find("is not placed by the nav in the nav's world frame odom against session 0: nav step"),
            std::string::npos)
      << r.warnings[0];
  EXPECT_EQ(jumped.counts().placements_refused, 1);
}

// --- The session manager ---------------------------------------------------------------------------

SessionManagerOptions managerOptions(const std::string& store = "") {
  SessionManagerOptions o;
  o.store_path = store;
  o.backend.join_policy = JoinPolicy::kCount;
  o.backend.join_min_loops = 2;  // two visual loops join maps automatically
  return o;
}

KeyframeInput keyframeAt(int session, int k, const Pose2& pose, const Pose2& previous) {
  return testing_util::keyframeInput(
      session, k, pose, UncertainPose2(between(previous, pose), Eigen::Vector3d(1e-6, 1e-6, 1e-8).asDiagonal()));
}

// Session 0: 8 keyframes 1 m apart along x. Session 1 (after a tracking loss) starts at
// truthOne(0) in session 0's frame and flies along its own x.
const Pose2 kOneStart(10.0, 1.5, 0.4);
Pose2 truthOne(int k) { return compose(kOneStart, Pose2(k, 0, 0)); }

Loop placementOf(const Pose2& z, double sigma_m, double sigma_rad) {
  Loop l;
  l.session_a = 0;
  l.keyframe_a = 7;
  l.session_b = 1;
  l.keyframe_b = 0;
  l.z = UncertainPose2(z, Eigen::Vector3d(sigma_m * sigma_m, sigma_m * sigma_m, sigma_rad * sigma_rad).asDiagonal());
  return l;
}

Loop visualLoop(int ka, int kb, const Pose2& a_pose, const Pose2& b_pose) {
  Loop l;
  l.kind = Loop::Kind::kGlobal;
  l.session_a = 0;
  l.keyframe_a = ka;
  l.session_b = 1;
  l.keyframe_b = kb;
  l.z = UncertainPose2(between(a_pose, b_pose), Eigen::Vector3d(1e-6, 1e-6, 1e-6).asDiagonal());
  l.inliers = 80;
  return l;
}

TEST(NavPlacement, APlacedPieceIsInItsPredecessorsMapFromItsFirstKeyframeLoopsRefineItAndTheStoreKeepsIt) {
  testing_util::ScopedTempDir dir("nav_placement");
  const std::string db = (dir.path() / "s.db").string();
  // The nav's placement is 8 cm and 0.02 rad off the truth, its sigma 0.1 m, 0.03 rad.
  const Pose2 truth_z = between(Pose2(7, 0, 0), kOneStart);
  const Pose2 nav_z = compose(truth_z, Pose2(0.08, -0.03, 0.02));
  std::vector<Pose2> placed_poses;
  {
    std::vector<SessionEvent> events;
    SessionManager m(managerOptions(db), [&](const SessionEvent& e) { events.push_back(e); });
    for (int k = 0; k < 8; ++k)
      ASSERT_TRUE(m.addKeyframe(keyframeAt(0, k, Pose2(k, 0, 0), Pose2(std::max(0, k - 1), 0, 0))).ok());
    ASSERT_TRUE(m.addKeyframe(keyframeAt(1, 0, Pose2(), Pose2())).ok());
    ASSERT_NE(m.view().mapOf(1), m.view().mapOf(0));
    events.clear();
    const Status st = m.addNavPlacement(placementOf(nav_z, 0.1, 0.03));
    ASSERT_TRUE(st.ok()) << st.message;
    // In session 0's map from its first keyframe, where the nav puts it.
    EXPECT_EQ(m.view().mapOf(1), m.view().mapOf(0));
    const Pose2 placed = m.view().poses(1)[0];
    const Pose2 expected = compose(m.view().poses(0)[7], nav_z);
    EXPECT_NEAR(placed.x(), expected.x(), 1e-9);
    EXPECT_NEAR(placed.y(), expected.y(), 1e-9);
    EXPECT_NEAR(placed.yaw(), expected.yaw(), 1e-9);
    bool joined = false;
    for (const SessionEvent& e : events) joined |= e.kind == SessionEvent::Kind::kMapsJoined;
    EXPECT_TRUE(joined);
    EXPECT_EQ(m.view().stats().nav_placements, 1);
    ASSERT_EQ(m.view().loops().size(), 1u);
    EXPECT_TRUE(m.view().loops()[0].nav_placement);
    EXPECT_EQ(m.view().loops()[0].inliers, 0);
    // A second placement of the same pair changes nothing (already one map).
    EXPECT_TRUE(m.addNavPlacement(placementOf(nav_z, 0.1, 0.03)).ok());
    EXPECT_EQ(m.view().loops().size(), 1u);
    EXPECT_EQ(m.view().stats().nav_placements, 1);
    // Misuse: nothing changed.
    Loop same = placementOf(nav_z, 0.1, 0.03);
    same.session_a = 1;
    same.keyframe_a = 0;
    same.keyframe_b = 0;
    EXPECT_EQ(m.addNavPlacement(same).code, StatusCode::kInvalidArgument);
    Loop zero = placementOf(nav_z, 0.0, 0.0);
    EXPECT_EQ(m.addNavPlacement(zero).code, StatusCode::kInvalidArgument);
    // Session 1 flies on; its odometry is exact. Three true visual loops to session 0 (now inside
    // one map: the intra-map gate checks them against the chain through the placement's
    // covariance) are taken and the solve moves the piece onto the truth.
    for (int k = 1; k < 6; ++k) ASSERT_TRUE(m.addKeyframe(keyframeAt(1, k, Pose2(k, 0, 0), Pose2(k - 1, 0, 0))).ok());
    const long refused_before = m.view().stats().loops_refused;
    ASSERT_TRUE(m.addLoop(visualLoop(7, 0, Pose2(7, 0, 0), truthOne(0))).ok());
    ASSERT_TRUE(m.addLoop(visualLoop(6, 1, Pose2(6, 0, 0), truthOne(1))).ok());
    ASSERT_TRUE(m.addLoop(visualLoop(5, 2, Pose2(5, 0, 0), truthOne(2))).ok());
    m.flush();
    EXPECT_EQ(m.view().stats().loops_refused, refused_before) << "a true loop is not refused against the placement";
    const Pose2 refined = between(m.view().poses(0)[0], m.view().poses(1)[0]);
    EXPECT_LT((refined.translation() - kOneStart.translation()).norm(), 0.005);
    EXPECT_NEAR(normalizeAngle(refined.yaw() - kOneStart.yaw()), 0.0, 0.002);
    EXPECT_GT((between(m.view().poses(0)[0], placed).translation() - kOneStart.translation()).norm(), 0.05)
        << "the placement alone was off: the loops moved it";
    ASSERT_TRUE(m.endSession(300.0).ok());
    placed_poses = m.view().poses(1);
  }
  // The store says what the link is and a restart restores the map with it.
  {
    SessionStore store(db, StoreAccess::kReadOnly);
    int marked = 0;
    for (const StoredLoop& l : store.loops()) marked += l.nav_placement ? 1 : 0;
    EXPECT_EQ(marked, 1);
    EXPECT_EQ(store.loops().size(), 4u);
  }
  SessionManager again(managerOptions(db));
  EXPECT_EQ(again.view().mapOf(1), again.view().mapOf(0));
  ASSERT_EQ(again.view().loops().size(), 4u);
  EXPECT_TRUE(again.view().loops()[0].nav_placement);
  for (std::size_t i = 1; i < 4; ++i) EXPECT_FALSE(again.view().loops()[i].nav_placement) << i;
  const std::vector<Pose2> restored = again.view().poses(1);
  ASSERT_EQ(restored.size(), placed_poses.size());
  for (std::size_t k = 0; k < restored.size(); ++k)
    EXPECT_LT((restored[k].translation() - placed_poses[k].translation()).norm(), 1e-9) << k;
  // merge_stores copies the mark with its loop: the merged store still tells the placement from
  // the visual loops, and restores the placed session in the same map.
  {
    const std::string merged = (dir.path() / "merged.db").string();
    const MergeReport report = mergeStores(merged, {{db, "auv", ""}}, SlamConfig(), false);
    EXPECT_EQ(report.copied_loops, 4);
    {
      SessionStore out(merged, StoreAccess::kReadOnly);
      int marked = 0;
      for (const StoredLoop& l : out.loops()) marked += l.nav_placement ? 1 : 0;
      EXPECT_EQ(marked, 1);
    }
    SessionManager from_merged(managerOptions(merged));
    EXPECT_EQ(from_merged.view().mapOf(1), from_merged.view().mapOf(0));
    int placements = 0;
    for (const Loop& l : from_merged.view().loops()) placements += l.nav_placement ? 1 : 0;
    EXPECT_EQ(placements, 1);
  }
  // Split off and deleted, the placed session takes its placement's row with it.
  ASSERT_TRUE(again.split(1).ok());
  ASSERT_TRUE(again.deleteSession("1", true).ok());
  {
    SessionStore store(db, StoreAccess::kReadOnly);
    EXPECT_TRUE(store.loops().empty());
  }
  EXPECT_TRUE(testing_util::execSql(db,
                                    "CREATE TEMP TABLE left_over(n CHECK(n = 0)); "
                                    "INSERT INTO left_over SELECT COUNT(*) FROM nav_placements;"));
}

/// Session 0 (keyframes 0..7); session 1, whose first keyframe to arrive is its odometry's keyframe
/// 10, past max_keyframe_gap 5: the manager holds it, then opens session 1 with the odometry's
/// 10..30 as its 0..20; session 2's keyframe 0, a map of its own.
void feedAJumpedSession(SessionManager* m) {
  for (int k = 0; k < 8; ++k)
    ASSERT_TRUE(m->addKeyframe(keyframeAt(0, k, Pose2(k, 0, 0), Pose2(std::max(0, k - 1), 0, 0))).ok());
  EXPECT_FALSE(m->addKeyframe(keyframeAt(1, 10, Pose2(10, 0, 0), Pose2(9, 0, 0))).ok());  // held: a jump
  for (int k = 11; k <= 30; ++k)
    ASSERT_TRUE(m->addKeyframe(keyframeAt(1, k, Pose2(k, 0, 0), Pose2(k - 1, 0, 0))).ok()) << k;
  ASSERT_EQ(m->view().poses(1).size(), 21u);
  ASSERT_TRUE(m->addKeyframe(keyframeAt(2, 0, Pose2(), Pose2())).ok());
}

// A visual bridge (a piece's keyframe registered with the piece before it, tracking.h's rejoin)
// goes the placement's way but is what it is: a visual loop, joining the maps at once, counted
// and audited apart from the nav's placements.
TEST(NavPlacement, AVisualBridgeJoinsTheMapsAndIsStoredAsAVisualLoopNotANavPlacement) {
  SessionManager m(managerOptions());
  for (int k = 0; k < 8; ++k)
    ASSERT_TRUE(m.addKeyframe(keyframeAt(0, k, Pose2(k, 0, 0), Pose2(std::max(0, k - 1), 0, 0))).ok());
  ASSERT_TRUE(m.addKeyframe(keyframeAt(1, 0, Pose2(), Pose2())).ok());
  ASSERT_NE(m.view().mapOf(1), m.view().mapOf(0));
  const Pose2 z = between(Pose2(7, 0, 0), kOneStart);
  const Status st = m.addNavPlacement(placementOf(z, 0.02, 0.005), true);
  ASSERT_TRUE(st.ok()) << st.message;
  EXPECT_EQ(m.view().mapOf(1), m.view().mapOf(0));
  const Pose2 placed = between(m.view().poses(0)[7], m.view().poses(1)[0]);
  EXPECT_TRUE(approxEqual(placed, z, 1e-9, 1e-9)) << placed;
  EXPECT_EQ(m.view().stats().visual_bridges, 1);
  EXPECT_EQ(m.view().stats().nav_placements, 0);
  ASSERT_EQ(m.view().loops().size(), 1u);
  EXPECT_FALSE(m.view().loops()[0].nav_placement);
}

TEST(NavPlacement, APlacementAgainstAPieceWhoseKeyframeIdsJumpedNamesThatKeyframeOnce) {
  // Session 1's first keyframe to arrive is its odometry's keyframe 10, past max_keyframe_gap: the
  // manager opens it under its own id 1 with the ids from 10 on as 0, 1, ... The placement names
  // the odometry's (1, 30), which is the manager's (1, 20): translated once, never twice.
  SessionManagerOptions o = managerOptions();
  o.max_keyframe_gap = 5;
  SessionManager m(o);
  feedAJumpedSession(&m);
  if (HasFatalFailure()) return;
  ASSERT_NE(m.view().mapOf(2), m.view().mapOf(1));
  Loop l = placementOf(Pose2(0.5, 0.2, 0.1), 0.1, 0.03);
  l.session_a = 1;
  l.keyframe_a = 30;
  l.session_b = 2;
  const Status st = m.addNavPlacement(l);
  ASSERT_TRUE(st.ok()) << st.message;
  ASSERT_EQ(m.view().loops().size(), 1u);
  EXPECT_EQ(m.view().loops()[0].session_a, 1);
  EXPECT_EQ(m.view().loops()[0].keyframe_a, 20);
  EXPECT_EQ(m.view().mapOf(2), m.view().mapOf(1));
  const Pose2 expected = compose(m.view().poses(1)[20], Pose2(0.5, 0.2, 0.1));
  EXPECT_NEAR(m.view().poses(2)[0].x(), expected.x(), 1e-9);
  EXPECT_NEAR(m.view().poses(2)[0].y(), expected.y(), 1e-9);
}

TEST(NavPlacement, AnOperatorsLinkInAJumpedPieceNamesTheManagersKeyframe) {
  // As above, session 1 holds the odometry's keyframes 10..30 as its 0..20. The operator names
  // keyframes as list_sessions shows them: (1, 15) is the manager's 15, not the odometry's 15
  // (which would be the manager's 5).
  SessionManagerOptions o = managerOptions();
  o.max_keyframe_gap = 5;
  SessionManager m(o);
  feedAJumpedSession(&m);
  if (HasFatalFailure()) return;
  Loop l = placementOf(Pose2(0.5, 0.2, 0.1), 0.1, 0.03);
  l.session_a = 1;
  l.keyframe_a = 15;
  l.session_b = 2;
  l.inliers = 50;
  const Status st = m.addLink(l);
  ASSERT_TRUE(st.ok()) << st.message;
  ASSERT_EQ(m.view().loops().size(), 1u);
  EXPECT_EQ(m.view().loops()[0].session_a, 1);
  EXPECT_EQ(m.view().loops()[0].keyframe_a, 15);
}

TEST(NavPlacement, APlacementIsNoEvidenceForAnAutomaticJoin) {
  // Two maps with one visual loop and a placement loop between them (as after a split):
  // join_min_loops 2 joins with two loops, not with the placement standing in for one.
  for (const bool placement : {true, false}) {
    BackendOptions o;
    o.join_policy = JoinPolicy::kCount;
    o.join_min_loops = 2;
    MultiSessionBackend b(o);
    const int s0 = b.startSession("a");
    for (int k = 1; k < 5; ++k) b.addMotion(s0, UncertainPose2(Pose2(1, 0, 0), Eigen::Matrix3d::Identity() * 1e-6));
    b.endSession(s0);
    const int s1 = b.startSession("b");
    for (int k = 1; k < 5; ++k) b.addMotion(s1, UncertainPose2(Pose2(1, 0, 0), Eigen::Matrix3d::Identity() * 1e-6));
    b.endSession(s1);
    BackendLoop nav{s0, 4, s1, 0, UncertainPose2(Pose2(1, 1, 0), Eigen::Matrix3d::Identity() * 1e-2), 0, placement};
    b.addLoop(nav);
    // Consistent with the placement: keyframe 1 of b at (6, 1) in a's frame.
    b.addLoop({s0, 2, s1, 1, UncertainPose2(Pose2(4, 1, 0), Eigen::Matrix3d::Identity() * 1e-6), 80});
    EXPECT_EQ(b.mapOf(s0) == b.mapOf(s1), !placement) << placement;
    if (placement) {
      EXPECT_FALSE(b.relocalise(s1).has_value()) << "one visual loop relocalises nothing";
    }
  }
}

TEST(NavPlacement, ALinkOnlyTheNavPlacedIsGatedWithItsOwnCovarianceNotTheInflatedOne) {
  // Two sparse sessions joined by a placement of sigma 0.77 m (two sessions' dead reckonings, as
  // bench_nav's two_sessions rows state it). A visual loop 10 m off the placement is wrong: the
  // intra-map gate inflating the placement 100 times (sigma 7.7 m) took it and moved the piece by
  // it. A true loop 0.5 m off the placement (within its error) is still taken.
  for (const double off : {10.0, 0.5}) {
    BackendOptions o;
    o.optimise = false;
    MultiSessionBackend b(o);
    const Eigen::Matrix3d step = Eigen::Vector3d(1e-4, 1e-4, 1e-6).asDiagonal();
    const int s0 = b.startSession("a");
    for (int k = 1; k < 5; ++k) b.addMotion(s0, UncertainPose2(Pose2(1, 0, 0), step));
    b.endSession(s0);
    const int s1 = b.startSession("b");
    for (int k = 1; k < 5; ++k) b.addMotion(s1, UncertainPose2(Pose2(1, 0, 0), step));
    const Eigen::Matrix3d nav_cov = Eigen::Vector3d(0.77 * 0.77, 0.77 * 0.77, 1e-3).asDiagonal();
    b.addLoop({s0, 4, s1, 0, UncertainPose2(Pose2(0, 5, 0), nav_cov), 0, true});
    ASSERT_TRUE(b.join(s0, s1, 1).ok());
    ASSERT_EQ(b.mapOf(s0), b.mapOf(s1));
    const int gated = b.stats().loops_gated;
    // The pose of b's keyframe 1 in a's keyframe 2 by the placement: (3, 5); the loop says `off`
    // more in x.
    b.addLoop({s0, 2, s1, 1, UncertainPose2(Pose2(3 + off, 5, 0), Eigen::Matrix3d::Identity() * 1e-4), 80});
    EXPECT_EQ(b.stats().loops_gated, gated + (off > 1.0 ? 1 : 0)) << "a loop " << off << " m off the placement";
  }
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
