// The multi-session back-end (core/backend/backend.h): sessions, automatic and explicit joins, splits,
// delayed optimisation, both optimisers on the same graph.
#include <gtest/gtest.h>

#include <Eigen/Dense>

#include <algorithm>
#include <random>
#include <tuple>

#include "uw_multislam/core/backend/backend.h"
#include "uw_multislam/core/backend/iekf.h"
#include "uw_multislam/core/backend/loop_consistency.h"

namespace uw_multislam {
namespace core {
namespace {

Eigen::Matrix3d diag(double sxy, double syaw) {
  return Eigen::Vector3d(sxy * sxy, sxy * sxy, syaw * syaw).asDiagonal();
}

// Ground-truth world poses of a few sessions; odometry and loops derived from them.
struct World {
  std::vector<std::vector<Pose2>> sessions;
  std::mt19937 rng{3};
  double odo_noise = 0.0;  // std of the odometry's x, y (m) and yaw (rad) error per motion

  UncertainPose2 motion(int s, int k) {
    std::normal_distribution<double> n(0.0, 1.0);
    const Pose2 m = between(sessions[s][k - 1], sessions[s][k]);
    const double e = odo_noise;
    return UncertainPose2(Pose2(m.x() + e * n(rng), m.y() + e * n(rng), m.yaw() + e * n(rng)),
                          diag(std::max(e, 0.01), std::max(e, 0.01)));
  }
  BackendLoop loop(int sa, int ka, int sb, int kb, const Pose2& error = Pose2()) const {
    return {sa, ka, sb, kb,
            UncertainPose2(compose(between(sessions[sa][ka], sessions[sb][kb]), error), diag(0.005, 0.005))};
  }
  // Feeds session s into the back-end (start, motions, end).
  int feed(MultiSessionBackend* b, int s, bool end = true) {
    const int id = b->startSession();
    for (int k = 1; k < static_cast<int>(sessions[s].size()); ++k) b->addMotion(id, motion(s, k));
    if (end) b->endSession(id);
    return id;
  }
  // The truth of session s's keyframes in the frame of session `map`'s first keyframe.
  std::vector<Pose2> truthIn(int map, int s) const {
    std::vector<Pose2> out;
    for (const Pose2& p : sessions[s]) out.push_back(between(sessions[map][0], p));
    return out;
  }
};

// A straight line of n keyframes along the heading, 0.5 m apart.
std::vector<Pose2> line(const Pose2& start, int n) {
  std::vector<Pose2> p{start};
  for (int k = 1; k < n; ++k) p.push_back(compose(p.back(), Pose2(0.5, 0.0, 0.0)));
  return p;
}

double worstError(const std::vector<Pose2>& est, const std::vector<Pose2>& truth) {
  double w = 0.0;
  for (std::size_t k = 0; k < est.size(); ++k) w = std::max(w, between(truth[k], est[k]).translation().norm());
  return w;
}

// The tests below that join automatically were written for the count rule (K = join_min_loops
// loops; default 5); join_policy consistent (the default) has tests of its own from
// consistentOptions on.
BackendOptions optionsFor(OptimizerKind k) {
  BackendOptions o;
  o.join_policy = JoinPolicy::kCount;
  o.optimizer = k;
  o.optimise_every = 1;
  return o;
}

class BothOptimizers : public ::testing::TestWithParam<OptimizerKind> {};

TEST_P(BothOptimizers, AJoinFromOnePerfectLoopRecoversTheKnownLink) {
  World w;
  w.sessions = {line(Pose2(0, 0, 0), 10), line(Pose2(4.0, -1.0, M_PI / 2), 8)};
  MultiSessionBackend b(optionsFor(GetParam()));
  w.feed(&b, 0);
  w.feed(&b, 1);
  b.addLoop(w.loop(0, 8, 1, 2));  // K = 5 by default: stored, not joined
  EXPECT_NE(b.mapOf(0), b.mapOf(1));
  EXPECT_EQ(b.pendingJoinLoops(0, 1), 1);
  const BackendStatus st = b.join(1, 0, 1);
  ASSERT_TRUE(st.ok()) << st.message;
  EXPECT_EQ(b.mapOf(1), 0);
  ASSERT_EQ(b.links(0).size(), 1u);
  const Pose2 truth_link = between(w.sessions[0].back(), w.sessions[1].front());
  EXPECT_TRUE(approxEqual(b.links(0)[0].measured.mean, truth_link, 1e-6, 1e-6)) << b.links(0)[0].measured.mean;
  EXPECT_LT(worstError(b.sessionPoses(1), w.truthIn(0, 1)), 1e-6);
  EXPECT_EQ(b.pendingJoinLoops(0, 1), 0);  // the loop is summarised by the link
}

TEST_P(BothOptimizers, SquareWithOneExactLoopClosesExactly) {
  MultiSessionBackend b(optionsFor(GetParam()));
  const int s = b.startSession("square");
  for (int k = 0; k < 4; ++k) b.addMotion(s, UncertainPose2(Pose2(2.1, 0.0, M_PI / 2 + 0.05), diag(0.05, 0.02)));
  EXPECT_GT(b.sessionPoses(s)[4].translation().norm(), 0.2);
  b.addLoop({s, 0, s, 4, UncertainPose2(Pose2(), Eigen::Matrix3d::Identity() * 1e-10)});
  EXPECT_TRUE(approxEqual(b.sessionPoses(s)[4], Pose2(), 1e-4, 1e-4)) << b.sessionPoses(s)[4];
  EXPECT_EQ(b.stats().optimisations, 1);
}

TEST_P(BothOptimizers, JoinsAutomaticallyAfterKLoopsWhileTheSessionRecords) {
  // Session 1 crosses session 0 (at session 0's keyframe 4) with a drifting odometry; the third
  // global loop (K = 3) joins it while it is still recording.
  World w;
  w.odo_noise = 0.01;
  w.sessions = {line(Pose2(0, 0, 0), 20), line(Pose2(2.0, -3.0, M_PI / 2), 20)};
  BackendOptions o = optionsFor(GetParam());
  o.join_min_loops = 3;
  MultiSessionBackend b(o);
  w.feed(&b, 0);
  const int s1 = b.startSession();
  for (int k = 1; k < 20; ++k) {
    b.addMotion(s1, w.motion(1, k));
    if (k >= 5 && k <= 7) b.addLoop(w.loop(0, 4, 1, k));
    if (k == 7) {
      EXPECT_EQ(b.mapOf(s1), 0) << "joined after the third loop";
    } else if (k < 7) {
      EXPECT_EQ(b.mapOf(s1), s1);
    }
  }
  // The recording session went second: the link runs from session 0's end to session 1's start,
  // and its later motions were appended to the joined map.
  EXPECT_EQ(b.chain(0), (std::vector<int>{0, 1}));
  EXPECT_EQ(b.sessionPoses(s1).size(), 20u);
  b.endSession(s1);
  // Around the crossing, session 1 sits where the loops say, relative to session 0's keyframe 4
  // (whose own odometry drift both share).
  const Pose2 anchor = b.sessionPoses(0)[4];
  for (int k = 5; k <= 7; ++k) {
    const Pose2 est = between(anchor, b.sessionPoses(s1)[k]);
    const Pose2 truth = between(w.sessions[0][4], w.sessions[1][k]);
    EXPECT_LT(between(truth, est).translation().norm(), 0.02) << k;
  }
  EXPECT_EQ(b.stats().joins, 1);
}

TEST_P(BothOptimizers, SplitThenJoinReturnsTheSameTrajectory) {
  World w;
  w.sessions = {line(Pose2(0, 0, 0), 12), line(Pose2(1.0, -2.0, M_PI / 2), 10), line(Pose2(3.0, 2.0, -M_PI / 2), 10)};
  MultiSessionBackend b(optionsFor(GetParam()));
  for (int s = 0; s < 3; ++s) w.feed(&b, s);
  for (int k = 0; k < 3; ++k) b.addLoop(w.loop(0, 1 + k, 1, 4));
  for (int k = 0; k < 3; ++k) b.addLoop(w.loop(0, 5 + k, 2, 4));
  ASSERT_TRUE(b.join(0, 1, 3).ok());
  ASSERT_TRUE(b.join(0, 2, 3).ok());
  EXPECT_EQ(b.chain(0), (std::vector<int>{0, 1, 2}));
  std::vector<std::vector<Pose2>> joined;
  for (int s = 0; s < 3; ++s) joined.push_back(b.sessionPoses(s));
  EXPECT_LT(worstError(joined[2], w.truthIn(0, 2)), 1e-6);

  // Split the middle session: it becomes map 1 in its own frame; 0 and 2 stay joined through
  // the composed link, their poses unchanged.
  const BackendStatus st = b.split(1);
  ASSERT_TRUE(st.ok()) << st.message;
  EXPECT_EQ(b.mapOf(1), 1);
  EXPECT_EQ(b.chain(0), (std::vector<int>{0, 2}));
  EXPECT_LT(worstError(b.sessionPoses(2), joined[2]), 1e-9);
  EXPECT_LT(worstError(b.sessionPoses(1), w.truthIn(1, 1)), 1e-6);  // its own frame, its own motions
  EXPECT_EQ(b.pendingJoinLoops(0, 1), 3);                           // its loops are stored again

  // New loops between the split pair do not re-join it automatically...
  for (int k = 0; k < 6; ++k) b.addLoop(w.loop(0, k, 1, 5));
  EXPECT_EQ(b.mapOf(1), 1);
  // ...an explicit join does, and gives the same trajectory back.
  ASSERT_TRUE(b.join(1, 0, 1).ok());
  EXPECT_EQ(b.chain(0), (std::vector<int>{0, 2, 1}));
  for (int s = 0; s < 3; ++s) EXPECT_LT(worstError(b.sessionPoses(s), joined[s]), 1e-6) << s;
}

TEST_P(BothOptimizers, SplitAtEitherEndKeepsBothParts) {
  World w;
  w.sessions = {line(Pose2(0, 0, 0), 8), line(Pose2(1.0, -2.0, M_PI / 2), 8)};
  MultiSessionBackend b(optionsFor(GetParam()));
  w.feed(&b, 0);
  w.feed(&b, 1);
  b.addLoop(w.loop(0, 2, 1, 4));
  ASSERT_TRUE(b.join(0, 1).ok());
  const std::vector<Pose2> p0 = b.sessionPoses(0);
  ASSERT_TRUE(b.split(0).ok());  // the first session: the rest (session 1) becomes map 1
  EXPECT_EQ(b.mapOf(0), 0);
  EXPECT_EQ(b.mapOf(1), 1);
  EXPECT_LT(worstError(b.sessionPoses(0), p0), 1e-12);
  EXPECT_TRUE(approxEqual(b.sessionPoses(1)[0], Pose2(), 0.0, 0.0));  // its own frame again
  EXPECT_EQ(b.split(1).code, StatusCode::kFailedPrecondition);        // alone: nothing to split
}

TEST_P(BothOptimizers, WrongRequestsChangeNothing) {
  World w;
  w.sessions = {line(Pose2(0, 0, 0), 6), line(Pose2(0.5, -1.0, M_PI / 2), 6)};
  MultiSessionBackend b(optionsFor(GetParam()));
  w.feed(&b, 0);
  w.feed(&b, 1);
  EXPECT_EQ(b.join(0, 7).code, StatusCode::kNotFound);
  EXPECT_EQ(b.join(-1, 0).code, StatusCode::kNotFound);
  EXPECT_EQ(b.join(0, 1, -1).code, StatusCode::kInvalidArgument);
  EXPECT_EQ(b.join(0, 1, 0).code, StatusCode::kFailedPrecondition);  // 0: the configured rule (K = 5)
  const BackendStatus none = b.join(0, 1);
  EXPECT_EQ(none.code, StatusCode::kFailedPrecondition);
  EXPECT_NE(none.message.find("0 global loops"), std::string::npos) << none.message;
  EXPECT_EQ(b.join(0, 0).code, StatusCode::kFailedPrecondition);
  EXPECT_EQ(b.split(9).code, StatusCode::kNotFound);
  EXPECT_EQ(b.mapIds(), (std::vector<int>{0, 1}));
  EXPECT_THROW(b.addLoop({0, 1, 1, 6, UncertainPose2(Pose2(), diag(0.1, 0.1))}),
               std::invalid_argument);  // keyframe 6 does not exist
  EXPECT_THROW(b.addLoop({0, 1, 0, 1, UncertainPose2(Pose2(), diag(0.1, 0.1))}), std::invalid_argument);
  EXPECT_THROW(b.addLoop({0, 1, 1, 1, UncertainPose2(Pose2(), Eigen::Matrix3d::Zero())}), std::invalid_argument);
  EXPECT_THROW(b.addMotion(0, UncertainPose2(Pose2(1, 0, 0), diag(0.1, 0.1))), std::invalid_argument);  // ended
  EXPECT_EQ(b.stats().loops, 0);
}

TEST_P(BothOptimizers, AnInconsistentLoopIsRefusedAtTheJoin) {
  World w;
  w.sessions = {line(Pose2(0, 0, 0), 10), line(Pose2(1.0, -2.0, M_PI / 2), 10)};
  BackendOptions o = optionsFor(GetParam());
  MultiSessionBackend b(o);
  w.feed(&b, 0);
  w.feed(&b, 1);
  for (int k = 0; k < 4; ++k) b.addLoop(w.loop(0, 2, 1, 3 + k));
  EXPECT_EQ(b.mapOf(1), 1);
  b.addLoop(w.loop(0, 7, 1, 4, Pose2(2.0, 0.0, 0.3)));  // the fifth, and wrong
  EXPECT_EQ(b.mapOf(1), 1) << "4 good loops of 5: K = 5 not reached";
  b.addLoop(w.loop(0, 3, 1, 4));
  ASSERT_EQ(b.mapOf(1), 0);
  EXPECT_EQ(b.stats().loops_refused, 1);
  EXPECT_EQ(b.links(0)[0].loops, 5);
  EXPECT_LT(worstError(b.sessionPoses(1), w.truthIn(0, 1)), 1e-3);
}

// --- join_policy: consistent (core/backend/loop_consistency.h) ---

BackendOptions consistentOptions(OptimizerKind k) {
  BackendOptions o = optionsFor(k);
  o.join_policy = JoinPolicy::kConsistent;
  o.join_min_consistent = 2;
  o.join_min_inliers = 60;
  o.join_min_spread_m = 0.2;
  return o;
}

BackendLoop withInliers(BackendLoop l, int inliers) {
  l.inliers = inliers;
  return l;
}

TEST_P(BothOptimizers, ConsistentPolicyJoinsAShortRevisitFromTwoLoops) {
  // A second pass 0.3 m beside the first: two correct loops 1 m apart join it, where the count
  // policy (K = 5) would wait for loops that never come.
  World w;
  w.sessions = {line(Pose2(0, 0, 0), 10), line(Pose2(0.5, 0.3, 0.05), 10)};
  MultiSessionBackend b(consistentOptions(GetParam()));
  w.feed(&b, 0);
  w.feed(&b, 1);
  b.addLoop(withInliers(w.loop(0, 3, 1, 2), 40));
  EXPECT_EQ(b.mapOf(1), 1) << "one loop is no set";
  b.addLoop(withInliers(w.loop(0, 5, 1, 4), 40));
  ASSERT_EQ(b.mapOf(1), 0);
  EXPECT_EQ(b.links(0)[0].loops, 2);
  EXPECT_EQ(b.stats().joins_refused, 0);
  EXPECT_LT(worstError(b.sessionPoses(1), w.truthIn(0, 1)), 1e-3);

  BackendOptions count = optionsFor(GetParam());  // the same loops under the count policy: no join
  MultiSessionBackend c(count);
  w.feed(&c, 0);
  w.feed(&c, 1);
  c.addLoop(w.loop(0, 3, 1, 2));
  c.addLoop(w.loop(0, 5, 1, 4));
  EXPECT_EQ(c.mapOf(1), 1);
}

TEST_P(BothOptimizers, ConsistentPolicyLeavesAWrongLoopOut) {
  World w;
  w.sessions = {line(Pose2(0, 0, 0), 10), line(Pose2(1.0, -2.0, M_PI / 2), 10)};
  BackendOptions o = consistentOptions(GetParam());
  o.join_min_consistent = 4;
  MultiSessionBackend b(o);
  w.feed(&b, 0);
  w.feed(&b, 1);
  b.addLoop(withInliers(w.loop(0, 7, 1, 4, Pose2(2.0, 0.0, 0.3)), 300));  // wrong, and strong
  for (int k = 0; k < 3; ++k) b.addLoop(withInliers(w.loop(0, 2, 1, 3 + k), 40));
  EXPECT_EQ(b.mapOf(1), 1) << "3 consistent loops of 4: 4 needed";
  EXPECT_EQ(b.stats().joins_refused, 1);
  b.addLoop(withInliers(w.loop(0, 3, 1, 6), 40));
  ASSERT_EQ(b.mapOf(1), 0);
  EXPECT_EQ(b.stats().loops_refused, 1);
  EXPECT_EQ(b.links(0)[0].loops, 4);
  EXPECT_LT(worstError(b.sessionPoses(1), w.truthIn(0, 1)), 1e-3);
}

TEST_P(BothOptimizers, ConsistentPolicyRefusesLoopsAtOnePlaceAndSaysWhy) {
  World w;
  w.sessions = {line(Pose2(0, 0, 0), 10), line(Pose2(0.5, 0.3, 0.05), 10)};
  MultiSessionBackend b(consistentOptions(GetParam()));
  w.feed(&b, 0);
  w.feed(&b, 1);
  for (int k = 0; k < 3; ++k) b.addLoop(withInliers(w.loop(0, 4, 1, 3), 80));
  EXPECT_EQ(b.mapOf(1), 1);
  EXPECT_EQ(b.stats().joins_refused, 2);  // tried at the second and the third loop
  EXPECT_NE(b.stats().last_join_refusal.find("spread 0 m"), std::string::npos) << b.stats().last_join_refusal;
  // Too few inliers is refused the same way.
  MultiSessionBackend weak(consistentOptions(GetParam()));
  w.feed(&weak, 0);
  w.feed(&weak, 1);
  weak.addLoop(withInliers(w.loop(0, 3, 1, 2), 20));
  weak.addLoop(withInliers(w.loop(0, 6, 1, 5), 20));
  EXPECT_EQ(weak.mapOf(1), 1);
  EXPECT_NE(weak.stats().last_join_refusal.find("40 inliers"), std::string::npos) << weak.stats().last_join_refusal;
}

// Relocalisation's set-up: session 0 (10 keyframes) finished, session 1 (6 keyframes, starting
// 1 m ahead and 2 m beside it, turned pi/2) recording, automatic joins off (localisation mode).
World storedAndRecording(MultiSessionBackend* b) {
  World w;
  w.sessions = {line(Pose2(0, 0, 0), 10), line(Pose2(1.0, -2.0, M_PI / 2), 6)};
  b->setAutomaticJoins(false);
  w.feed(b, 0);
  w.feed(b, 1, false);
  return w;
}

TEST_P(BothOptimizers, RelocalisesFromOneKeyframeThatTwoStoredPlacesAgreeOn) {
  // One new keyframe verified against two stored keyframes 0.5 m apart relocalises (the spread is
  // the stored map's), where a join under the consistency policy waits for a second place in the
  // new session too; the same stored keyframe twice is one place, no relocalisation.
  World w;
  w.sessions = {line(Pose2(0, 0, 0), 10), line(Pose2(1.2, 0.2, 0.1), 3)};
  MultiSessionBackend b(consistentOptions(GetParam()));
  b.setAutomaticJoins(false);
  w.feed(&b, 0);
  w.feed(&b, 1, false);
  b.addLoop(withInliers(w.loop(0, 2, 1, 2), 80));
  b.addLoop(withInliers(w.loop(0, 2, 1, 2), 80));
  EXPECT_FALSE(b.relocalise(1)) << "one stored place";
  b.addLoop(withInliers(w.loop(0, 3, 1, 2), 80));
  const auto r = b.relocalise(1);
  ASSERT_TRUE(r);
  EXPECT_EQ(r->loops, 3);
  EXPECT_LT(between(between(w.sessions[0][0], w.sessions[1][2]), r->pose.mean).translation().norm(), 1e-6);
  const Status by_rule = b.join(0, 1, 0);  // 0: the configured rule, as the automatic join
  EXPECT_FALSE(by_rule.ok()) << "the rule's join needs the spread in both maps";
  EXPECT_NE(by_rule.message.find("spread 0 m"), std::string::npos) << by_rule.message;
  EXPECT_EQ(b.mapOf(1), 1);
  // An operator's count (join_sessions with min_loops 2): the consistent set of 3 is enough; the
  // rule's inliers and spread are not asked for, and the link is the one relocalisation found.
  const Status asked = b.join(0, 1, 2);
  ASSERT_TRUE(asked.ok()) << asked.message;
  EXPECT_NE(asked.message.find("from 3 global loops"), std::string::npos) << asked.message;
  EXPECT_LT(worstError(b.sessionPoses(1), w.truthIn(0, 1)), 1e-6);
}

TEST_P(BothOptimizers, RelocalisesAgainstAnotherMapWithoutJoiningIt) {
  // Session 1 is recording with automatic joins off (localisation mode): its pose in map 0 comes
  // from the consistent set of its loops to map 0, whatever join_policy is (count, K = 5 here),
  // and nothing changes.
  MultiSessionBackend b(optionsFor(GetParam()));
  World w = storedAndRecording(&b);
  EXPECT_FALSE(b.relocalise(1)) << "no loop";
  b.addLoop(withInliers(w.loop(0, 2, 1, 4), 80));
  EXPECT_FALSE(b.relocalise(1)) << "one loop is no set";
  b.addLoop(withInliers(w.loop(0, 7, 1, 3, Pose2(2.0, 0.0, 0.3)), 300));  // wrong, and strong
  EXPECT_FALSE(b.relocalise(1)) << "two loops that disagree";
  b.addLoop(withInliers(w.loop(0, 3, 1, 5), 80));
  const auto r = b.relocalise(1);
  ASSERT_TRUE(r);
  EXPECT_EQ(r->map, 0);
  EXPECT_EQ(r->loops, 2);
  EXPECT_EQ(r->inliers, 160);
  EXPECT_EQ(r->keyframe, 5);
  const Pose2 truth = between(w.sessions[0][0], w.sessions[1][5]);
  EXPECT_LT(between(truth, r->pose.mean).translation().norm(), 1e-6);
  EXPECT_LT(std::abs(normalizeAngle(between(truth, r->pose.mean).yaw())), 1e-6);
  const Pose2 origin = between(w.sessions[0][0], w.sessions[1][0]);
  EXPECT_LT(between(origin, r->origin.mean).translation().norm(), 1e-6);
  EXPECT_GT(r->pose.covariance.determinant(), r->origin.covariance.determinant()) << "its own motions add to it";
  EXPECT_EQ(b.mapOf(1), 1) << "relocalising joins nothing";
  EXPECT_EQ(b.stats().joins, 0);
  EXPECT_EQ(b.stats().loops_refused, 0);
  EXPECT_EQ(b.pendingJoinLoops(0, 1), 3);
  // The other way round (the loops read from b to a): session 0's last keyframe in map 1.
  const auto back = b.relocalise(0);
  ASSERT_TRUE(back);
  EXPECT_EQ(back->map, 1);
  EXPECT_LT(between(between(w.sessions[1][0], w.sessions[0][9]), back->pose.mean).translation().norm(), 1e-6);
}

TEST_P(BothOptimizers, ASplitTheUserAskedForStandsAgainstRelocalisation) {
  MultiSessionBackend b(optionsFor(GetParam()));
  World w = storedAndRecording(&b);
  b.addLoop(withInliers(w.loop(0, 2, 1, 4), 80));
  b.addLoop(withInliers(w.loop(0, 3, 1, 5), 80));
  ASSERT_TRUE(b.relocalise(1));
  const Status joined = b.join(0, 1, 2);
  ASSERT_TRUE(joined.ok()) << joined.message;
  EXPECT_FALSE(b.relocalise(1)) << "in one map: nothing to relocalise against";
  ASSERT_TRUE(b.split(1).ok());
  EXPECT_FALSE(b.relocalise(1)) << "the same loops do not undo the split";
}


TEST_P(BothOptimizers, AWrongLoopInsideAMapIsGatedAndAMildlyDriftedTrueOneIsNot) {
  // A 20-keyframe line with 1 cm odometry noise: a true loop (5 cm measurement noise on top of the
  // drift) passes the gate, one 2 m off is refused, counted and leaves the map as it was.
  World w;
  w.odo_noise = 0.01;
  w.sessions = {line(Pose2(0, 0, 0), 20)};
  MultiSessionBackend b(optionsFor(GetParam()));
  w.feed(&b, 0, false);
  b.addLoop(w.loop(0, 2, 0, 17, Pose2(0.03, -0.04, 0.01)));
  EXPECT_EQ(b.stats().loops_gated, 0);
  const std::vector<Pose2> before = b.sessionPoses(0);
  b.addLoop(w.loop(0, 4, 0, 12, Pose2(2.0, 0.0, 0.0)));
  EXPECT_EQ(b.stats().loops_gated, 1);
  EXPECT_EQ(b.stats().loops_refused, 1);
  EXPECT_TRUE(b.loopRecord(1).refused);
  EXPECT_FALSE(b.loopRecord(0).refused);
  b.flush();
  for (std::size_t k = 0; k < before.size(); ++k) EXPECT_TRUE(approxEqual(b.sessionPoses(0)[k], before[k])) << k;
  BackendOptions off = optionsFor(GetParam());  // without the gate the same wrong loop bends the map
  off.intra_loop_gate = false;
  off.loop_residual_gate = false;  // the second line (switched off after the solve) too
  MultiSessionBackend c(off);
  World w2;
  w2.odo_noise = 0.01;
  w2.sessions = w.sessions;
  w2.feed(&c, 0, false);
  c.addLoop(w2.loop(0, 4, 0, 12, Pose2(2.0, 0.0, 0.0)));
  c.flush();
  EXPECT_GT(worstError(c.sessionPoses(0), w2.truthIn(0, 0)), 0.3);
}

// --- loop_residual_gate: a loop that disagrees with the solution is switched off ---

// One 30-keyframe session with 1 cm odometry noise, three true loops and (optionally) a wrong one
// 1.5 m off between them, optimised once at the end. intra_loop_gate is off: the wrong loop
// stands for one the entry gate lets through (a long chain with a wide covariance).
struct ResidualGateRun {
  std::vector<Pose2> poses, truth;
  BackendStats stats;
  std::vector<LoopRecord> loops;
};
ResidualGateRun residualGateRun(OptimizerKind k, bool with_wrong, bool residual_gate, double entry_inflation = 10.0,
                                double residual_inflation = 10.0) {
  World w;
  w.odo_noise = 0.01;
  w.sessions = {line(Pose2(0, 0, 0), 30)};
  BackendOptions o = optionsFor(k);
  o.optimise_every = 100;
  o.intra_loop_gate = false;
  o.loop_residual_gate = residual_gate;
  o.intra_gate_inflation = entry_inflation;
  o.residual_gate_inflation = residual_inflation;
  MultiSessionBackend b(o);
  w.feed(&b, 0, false);
  b.addLoop(w.loop(0, 2, 0, 12));
  b.addLoop(w.loop(0, 5, 0, 20));
  if (with_wrong) b.addLoop(w.loop(0, 4, 0, 25, Pose2(1.5, 0.0, 0.0)));
  b.addLoop(w.loop(0, 10, 0, 28));
  b.flush();
  ResidualGateRun r{b.sessionPoses(0), w.truthIn(0, 0), b.stats(), {}};
  for (int id = 0; id < b.numLoops(); ++id) r.loops.push_back(b.loopRecord(id));
  return r;
}

TEST_P(BothOptimizers, AWrongLoopInTheSolveIsSwitchedOffAndTheSolutionIsTheOneWithoutIt) {
  const ResidualGateRun gated = residualGateRun(GetParam(), true, true);
  const ResidualGateRun clean = residualGateRun(GetParam(), false, true);
  ASSERT_EQ(gated.loops.size(), 4u);
  EXPECT_TRUE(gated.loops[2].refused);  // the wrong one
  for (int id : {0, 1, 3}) EXPECT_FALSE(gated.loops[id].refused) << id;
  EXPECT_EQ(gated.stats.loops_switched_off, 1);
  EXPECT_EQ(gated.stats.loops_refused, 1);
  EXPECT_EQ(clean.stats.loops_switched_off, 0);  // true loops stay in
  // Switched off = solved again from the same start without it: the solve that never saw it.
  ASSERT_EQ(gated.poses.size(), clean.poses.size());
  for (std::size_t k = 0; k < clean.poses.size(); ++k)
    EXPECT_TRUE(approxEqual(gated.poses[k], clean.poses[k], 1e-9, 1e-9)) << k << " " << gated.poses[k];
  // Without the gate the same wrong loop stays in and bends the map.
  const ResidualGateRun open = residualGateRun(GetParam(), true, false);
  EXPECT_FALSE(open.loops[2].refused);
  const double err_clean = worstError(clean.poses, clean.truth), err_open = worstError(open.poses, open.truth);
  EXPECT_GT(err_open, err_clean + 0.05) << "clean " << err_clean << " m, with the wrong loop " << err_open << " m";
}

TEST_P(BothOptimizers, TheResidualGateHasItsOwnInflation) {
  // The entry gate loosened (intra_gate_inflation 100) leaves the residual gate as it was: the
  // 1.5 m wrong loop is still switched off. The residual gate loosened the same way lets the IEKF
  // keep it (no robust loss there), which is why the two are apart.
  const ResidualGateRun loose_entry = residualGateRun(GetParam(), true, true, 100.0, 10.0);
  EXPECT_TRUE(loose_entry.loops[2].refused);
  EXPECT_EQ(loose_entry.stats.loops_switched_off, 1);
  if (GetParam() == OptimizerKind::kIekf) {
    const ResidualGateRun loose_residual = residualGateRun(GetParam(), true, true, 10.0, 100.0);
    EXPECT_FALSE(loose_residual.loops[2].refused);
    EXPECT_EQ(loose_residual.stats.loops_switched_off, 0);
  }
  BackendOptions bad;
  bad.residual_gate_inflation = 0.5;
  EXPECT_NE(bad.validate().find("residual_gate_inflation"), std::string::npos) << bad.validate();
}

// A 30-keyframe line whose odometry turns 0.01 rad too far at every motion (its covariance says
// 0.01 rad per motion: a steady bias, the map metres off at the end), then a long true loop 0 -> 29,
// short true loops k -> k + 3 and a wrong loop 1.2 m off; entry gates at inflation 1 (what is
// refused here is refused for being metres off, not for the inflation), one solve at the end.
struct ReadmitRun {
  std::vector<Pose2> poses, truth;
  BackendStats stats;
  std::vector<LoopRecord> loops;
};
ReadmitRun readmitRun(OptimizerKind k, bool readmit, bool entry_gate = true) {
  World w;
  w.sessions = {line(Pose2(0, 0, 0), 30)};
  BackendOptions o = optionsFor(k);
  o.optimise_every = 100;
  o.intra_loop_gate = entry_gate;
  o.intra_gate_inflation = 1.0;
  o.iekf_gate_inflation = 1.0;
  o.readmit_refused_loops = readmit;
  MultiSessionBackend b(o);
  const int s = b.startSession();
  for (int i = 1; i < 30; ++i) {
    const Pose2 m = between(w.sessions[0][i - 1], w.sessions[0][i]);
    b.addMotion(s, UncertainPose2(Pose2(m.x(), m.y(), m.yaw() + 0.01), diag(0.01, 0.01)));
  }
  b.addLoop(w.loop(0, 0, 0, 29));  // id 0: long, true, metres off the odometry
  for (int i = 0; i + 3 < 30; ++i) b.addLoop(w.loop(0, i, 0, i + 3));  // ids 1..27
  if (entry_gate) b.addLoop(w.loop(0, 2, 0, 27, Pose2(1.2, 0.0, 0.0)));  // id 28: wrong
  b.flush();
  ReadmitRun r{b.sessionPoses(0), w.truthIn(0, 0), b.stats(), {}};
  for (int id = 0; id < b.numLoops(); ++id) r.loops.push_back(b.loopRecord(id));
  return r;
}

TEST_P(BothOptimizers, ATrueLoopRefusedWhileTheMapWasOffIsTakenBackAfterTheSolveAndAWrongOneIsNot) {
  const ReadmitRun kept = readmitRun(GetParam(), false);
  ASSERT_EQ(kept.loops.size(), 29u);
  ASSERT_TRUE(kept.loops[0].refused) << "the long loop meets the biased odometry metres off";
  ASSERT_TRUE(kept.loops[28].refused);
  for (int id = 1; id <= 27; ++id) ASSERT_FALSE(kept.loops[id].refused) << id;
  EXPECT_EQ(kept.stats.loops_gated, 2);
  EXPECT_EQ(kept.stats.loops_readmitted, 0);

  const ReadmitRun back = readmitRun(GetParam(), true);
  EXPECT_FALSE(back.loops[0].refused) << "the short loops straightened the map: the long one agrees now";
  EXPECT_TRUE(back.loops[28].refused) << "a wrong loop 1.2 m off agrees with no solution of the true ones";
  for (int id = 1; id <= 27; ++id) EXPECT_FALSE(back.loops[id].refused) << id;
  EXPECT_EQ(back.stats.loops_gated, 2);
  EXPECT_EQ(back.stats.loops_readmitted, 1);
  EXPECT_EQ(back.stats.loops_switched_off, 0);
  // Taken back = as if it had been accepted at once: the solution of all the true loops (entry
  // gate off, no wrong loop), and closer to the truth than without the long loop.
  const ReadmitRun all = readmitRun(GetParam(), true, false);
  ASSERT_EQ(all.loops.size(), 28u);
  for (const LoopRecord& l : all.loops) ASSERT_FALSE(l.refused);
  ASSERT_EQ(back.poses.size(), all.poses.size());
  for (std::size_t k = 0; k < all.poses.size(); ++k)
    EXPECT_TRUE(approxEqual(back.poses[k], all.poses[k], 1e-6, 1e-6)) << k << " " << back.poses[k] << " " << all.poses[k];
  EXPECT_LT(worstError(back.poses, back.truth), worstError(kept.poses, kept.truth));
}

TEST_P(BothOptimizers, TheEntryGateIsLooseForSparseMapsAndTightForIekfMaps) {
  // A loop 1 m off along a 30-keyframe line (1 cm per motion): the chain's x variance is
  // 29e-4 m^2 (the IEKF's P before any update says the same), so the gate (chi-square 11.3)
  // passes about 0.31 m at inflation 3, 0.57 m at 10 and 1.8 m at 100.
  World w;
  w.sessions = {line(Pose2(0, 0, 0), 30)};
  BackendOptions o = optionsFor(GetParam());
  o.optimise_every = 100;
  MultiSessionBackend b(o);
  w.feed(&b, 0, false);
  b.addLoop(w.loop(0, 0, 0, 29, Pose2(1.0, 0.0, 0.0)));
  const bool iekf = GetParam() == OptimizerKind::kIekf;
  EXPECT_EQ(b.stats().loops_gated, iekf ? 1 : 0) << "defaults: iekf_gate_inflation 3, intra_gate_inflation 100";
  o.intra_gate_inflation = o.iekf_gate_inflation = 10.0;  // both tight: both refuse it
  MultiSessionBackend tight(o);
  w.feed(&tight, 0, false);
  tight.addLoop(w.loop(0, 0, 0, 29, Pose2(1.0, 0.0, 0.0)));
  EXPECT_EQ(tight.stats().loops_gated, 1);
  BackendOptions bad;
  bad.iekf_gate_inflation = 0.0;
  EXPECT_NE(bad.validate().find("iekf_gate_inflation"), std::string::npos) << bad.validate();
}

TEST(IekfEntryGate, UsesTheFiltersJointCovarianceOfTheTwoKeyframes) {
  // A 30-keyframe line kept by the IEKF, optimised at every loop. A first, true loop 0 -> 29
  // pins the two ends to each other: the filter's P then gives X_29^0 a covariance about the
  // loop's, while the motions' marginal blocks (what a chain composition would use) hardly shrink.
  // A second loop 0 -> 29 that is 0.15 m off is refused by the gate on P; a third, true one
  // passes. The same numbers computed here on a TrajectoryIekf show that the marginal chain
  // would have let the wrong loop through (so the test tells the two gates apart).
  World w;
  w.sessions = {line(Pose2(0, 0, 0), 30)};
  BackendOptions o = optionsFor(OptimizerKind::kIekf);
  MultiSessionBackend b(o);
  w.feed(&b, 0, false);
  b.addLoop(w.loop(0, 0, 0, 29));
  ASSERT_EQ(b.stats().loops_gated, 0);
  const BackendLoop wrong = w.loop(0, 0, 0, 29, Pose2(0.15, 0.0, 0.0));
  b.addLoop(wrong);
  EXPECT_EQ(b.stats().loops_gated, 1) << "the loop 0.15 m off passed the gate on P";
  b.addLoop(w.loop(0, 0, 0, 29, Pose2(0.004, -0.003, 0.002)));
  EXPECT_EQ(b.stats().loops_gated, 1) << "a true loop was refused";

  // Independently: the distances under the two covariances after the first loop.
  World w2;
  w2.sessions = w.sessions;
  TrajectoryIekf f;
  for (int k = 1; k < 30; ++k) f.addMotion(w2.motion(0, k));
  f.update({LoopMeasurement{0, 29, w2.loop(0, 0, 0, 29).z}});
  const double chi2 = chiSquare3Quantile(o.consistency.confidence);
  const UncertainPose2 joint = f.relative(0, 29);
  Eigen::Matrix3d marginal_chain = Eigen::Matrix3d::Zero();
  UncertainPose2 chain = UncertainPose2::exact(Pose2());
  for (int k = 0; k < 29; ++k)
    chain = compose(chain, UncertainPose2(f.motions()[k], f.covariance().block<3, 3>(3 * k, 3 * k)));
  marginal_chain = chain.covariance;
  const Pose2 e = between(joint.mean, wrong.z.mean);
  const double on_p = mahalanobis2(e, o.iekf_gate_inflation * joint.covariance + wrong.z.covariance, o.consistency);
  const double on_chain =
      mahalanobis2(e, o.iekf_gate_inflation * marginal_chain + wrong.z.covariance, o.consistency);
  EXPECT_GT(on_p, chi2);
  EXPECT_LT(on_chain, chi2) << "the marginal chain refuses it too: the test would not tell the gates apart";
  EXPECT_LT(joint.covariance(0, 0), 0.1 * marginal_chain(0, 0));
}

TEST_P(BothOptimizers, DriftedTrueLoopsAreNotSwitchedOff) {
  // 200 draws of a drifting 30-keyframe line (1 cm / 0.01 rad per motion, as its covariance says)
  // with three true loops measured with 5 mm noise: the residual gate (defaults) switches none off.
  int switched = 0;
  std::mt19937 rng(11);
  std::normal_distribution<double> n01(0.0, 1.0);
  for (int draw = 0; draw < 200; ++draw) {
    World w;
    w.rng.seed(100 + draw);
    w.odo_noise = 0.01;
    w.sessions = {line(Pose2(0, 0, 0), 30)};
    BackendOptions o = optionsFor(GetParam());
    o.optimise_every = 100;
    MultiSessionBackend b(o);
    w.feed(&b, 0, false);
    for (auto [i, j] : {std::pair<int, int>{2, 12}, {5, 20}, {10, 28}})
      b.addLoop(w.loop(0, i, 0, j, Pose2(0.005 * n01(rng), 0.005 * n01(rng), 0.005 * n01(rng))));
    b.flush();
    switched += b.stats().loops_switched_off + b.stats().loops_gated;
  }
  EXPECT_EQ(switched, 0);
}

TEST_P(BothOptimizers, OptimisationWaitsForMPendingLoops) {
  BackendOptions o = optionsFor(GetParam());
  o.optimise_every = 3;
  o.intra_loop_gate = false;  // loops 0.5 m off the odometry on purpose (this counts optimisations)
  MultiSessionBackend b(o);
  const int s = b.startSession();
  for (int k = 0; k < 8; ++k) b.addMotion(s, UncertainPose2(Pose2(0.5, 0.0, k == 3 ? M_PI : 0.0), diag(0.02, 0.01)));
  b.addLoop({s, 0, s, 7, UncertainPose2(Pose2(0, 0, M_PI), diag(0.01, 0.01))});
  b.addLoop({s, 1, s, 6, UncertainPose2(Pose2(0, 0, M_PI), diag(0.01, 0.01))});
  EXPECT_EQ(b.stats().optimisations, 0);
  b.addLoop({s, 2, s, 5, UncertainPose2(Pose2(0, 0, M_PI), diag(0.01, 0.01))});
  EXPECT_EQ(b.stats().optimisations, 1);
  b.addLoop({s, 0, s, 8, UncertainPose2(Pose2(-0.5, 0, M_PI), diag(0.01, 0.01))});
  EXPECT_EQ(b.stats().optimisations, 1);
  b.endSession(s);  // a session's end flushes its map
  EXPECT_EQ(b.stats().optimisations, 2);
}

// Runs every due map's optimisation the way the back-end nodelet does (prepare, solve, apply).
int runDue(MultiSessionBackend* b) {
  int applied = 0;
  for (std::vector<int> due = b->dueMaps(); !due.empty(); due = b->dueMaps()) {
    OptimisationJob job = b->prepareOptimisation(due.front());
    MultiSessionBackend::solveOptimisation(&job);
    if (!b->applyOptimisation(job)) ADD_FAILURE() << "nothing changed, yet the job was dropped";
    ++applied;
  }
  return applied;
}

TEST_P(BothOptimizers, DeferredOptimisationGivesTheSynchronousNumbers) {
  // Two noisy sessions, loops inside the first (optimised every 2), global loops that join them
  // automatically, then loops inside the second: synchronous, and deferred with the due maps run after every request.
  auto run = [](OptimizerKind k, bool deferred, std::vector<int>* due_after_request) {
    World w;
    w.odo_noise = 0.01;
    w.sessions = {line(Pose2(0, 0, 0), 12), line(Pose2(2.0, -2.0, M_PI / 2), 12)};
    BackendOptions o = optionsFor(k);
    o.optimise_every = 2;
    o.join_min_loops = 3;
    MultiSessionBackend b(o);
    b.setDeferred(deferred);
    auto request = [&](auto f) {
      f();
      if (!deferred) return;
      due_after_request->push_back(static_cast<int>(b.dueMaps().size()));
      const int before = b.stats().optimisations;
      runDue(&b);
      EXPECT_EQ(b.stats().optimisations - before, due_after_request->back());
    };
    const int s0 = b.startSession();
    for (int k = 1; k < 12; ++k) request([&] { b.addMotion(s0, w.motion(0, k)); });
    for (int k = 0; k < 4; ++k) request([&] { b.addLoop(w.loop(0, k, 0, 11 - k, Pose2(0.02, 0.0, 0.0))); });
    request([&] { b.endSession(s0); });
    w.feed(&b, 1);
    for (int k = 0; k < 3; ++k) request([&] { b.addLoop(w.loop(0, 4 + k, 1, 5)); });
    for (int k = 0; k < 2; ++k) request([&] { b.addLoop(w.loop(1, k, 1, 11 - k, Pose2(0.02, 0.0, 0.0))); });
    b.flush();
    EXPECT_EQ(b.mapOf(1), b.mapOf(0));
    return std::make_tuple(b.sessionPoses(0), b.sessionPoses(1), b.stats().optimisations);
  };
  std::vector<int> due;
  const auto sync = run(GetParam(), false, nullptr), deferred = run(GetParam(), true, &due);
  EXPECT_EQ(std::get<2>(sync), std::get<2>(deferred));
  EXPECT_GT(std::get<2>(sync), 2);
  // A request only marks maps due (it never optimises): loops 2 and 4 of session 0, then loop 2
  // of session 1 in the joined map.
  EXPECT_EQ(std::count(due.begin(), due.end(), 1), 3);
  auto identical = [](const std::vector<Pose2>& a, const std::vector<Pose2>& b) {
    if (a.size() != b.size()) return false;
    for (std::size_t k = 0; k < a.size(); ++k)
      if (a[k].x() != b[k].x() || a[k].y() != b[k].y() || a[k].yaw() != b[k].yaw()) return false;
    return true;
  };
  EXPECT_TRUE(identical(std::get<0>(sync), std::get<0>(deferred)));  // the same arithmetic, bit for bit
  EXPECT_TRUE(identical(std::get<1>(sync), std::get<1>(deferred)));
}

TEST_P(BothOptimizers, AResultForAMapThatChangedMeanwhileIsDroppedAndTheMapStaysDue) {
  World w;
  w.sessions = {line(Pose2(0, 0, 0), 10), line(Pose2(0, 1.0, 0), 10)};
  BackendOptions o = optionsFor(GetParam());
  o.join_min_loops = 0;
  MultiSessionBackend b(o);
  b.setDeferred(true);
  const int s0 = w.feed(&b, 0);
  const int s1 = w.feed(&b, 1);
  for (int k = 0; k < 3; ++k) b.addLoop(w.loop(s0, k, s1, k));  // between maps: stored, no join
  b.addLoop(w.loop(s0, 0, s0, 9, Pose2(0.05, 0.0, 0.0)));       // inside map 0: due
  ASSERT_EQ(b.dueMaps(), std::vector<int>{0});
  EXPECT_EQ(b.stats().optimisations, 0);
  const std::vector<Pose2> before = b.sessionPoses(s0);

  // A join while the job is being solved: the map the job was taken from is gone.
  OptimisationJob job = b.prepareOptimisation(0);
  MultiSessionBackend::solveOptimisation(&job);
  ASSERT_TRUE(b.join(s0, s1, 3).ok());
  EXPECT_FALSE(b.applyOptimisation(job));
  EXPECT_EQ(b.stats().optimisations_discarded, 1);
  EXPECT_EQ(b.stats().optimisations, 0);
  EXPECT_EQ(worstError(b.sessionPoses(s0), before), 0.0);  // nothing written
  ASSERT_EQ(b.dueMaps(), std::vector<int>{0});             // the joined map still waits for it

  // A loop added while solving changes the map: dropped again; the next job has both loops.
  job = b.prepareOptimisation(0);
  MultiSessionBackend::solveOptimisation(&job);
  b.addLoop(w.loop(s1, 0, s1, 9, Pose2(0.05, 0.0, 0.0)));
  EXPECT_FALSE(b.applyOptimisation(job));
  EXPECT_EQ(runDue(&b), 1);
  EXPECT_EQ(b.stats().optimisations, 1);
  EXPECT_TRUE(b.dueMaps().empty());
  EXPECT_GT(worstError(b.sessionPoses(s0), before), 1e-3);  // the loops moved the trajectory

  OptimisationJob unsolved = b.prepareOptimisation(0);
  EXPECT_THROW(b.applyOptimisation(unsolved), std::invalid_argument);
  EXPECT_THROW(b.prepareOptimisation(5), std::invalid_argument);
}

TEST_P(BothOptimizers, RemovingASessionShiftsTheOthersAndKeepsTheirMapsLinksAndLoops) {
  // delete_session: sessions 0, 1, 3 joined in map 0; session 2 alone, with two loops to session
  // 1 and one of its own. Removing 2 leaves the others' poses, links and loops as they were, under
  // ids shifted down past 2; a job prepared before is dropped; a recording session or one that
  // shares its map is refused with nothing changed.
  World w;
  w.sessions = {line(Pose2(0, 0, 0), 10), line(Pose2(0, 1.0, 0), 10), line(Pose2(3.0, -2.0, M_PI / 2), 8),
                line(Pose2(0, 2.0, 0), 10)};
  BackendOptions o = optionsFor(GetParam());
  o.join_min_loops = 0;
  MultiSessionBackend b(o);
  for (int s = 0; s < 4; ++s) w.feed(&b, s);
  for (int k = 0; k < 3; ++k) b.addLoop(w.loop(0, 2 + k, 1, 2 + k));
  b.addLoop(w.loop(1, 3, 2, 1));
  b.addLoop(w.loop(1, 4, 2, 2));
  b.addLoop(w.loop(2, 0, 2, 6));
  for (int k = 0; k < 3; ++k) b.addLoop(w.loop(1, 5 + k, 3, 5 + k));
  ASSERT_TRUE(b.join(0, 1, 3).ok());
  ASSERT_TRUE(b.join(1, 3, 3).ok());
  b.restoreSplitPair(1, 2);
  b.restoreSplitPair(0, 3);
  ASSERT_EQ(b.chain(0), (std::vector<int>{0, 1, 3}));
  std::vector<std::vector<Pose2>> poses;
  for (int s = 0; s < 4; ++s) poses.push_back(b.sessionPoses(s));
  auto loopsOfLinks = [&](int map) {
    std::vector<std::tuple<int, int, int, int>> out;
    for (const MapLinkState& l : b.mapState(map).links)
      for (int id : l.loops) {
        const BackendLoop& x = b.loopRecord(id).loop;
        out.emplace_back(x.session_a, x.keyframe_a, x.session_b, x.keyframe_b);
      }
    return out;
  };
  const auto linked = loopsOfLinks(0);
  ASSERT_EQ(linked.size(), 6u);
  b.setDeferred(true);
  b.addLoop(w.loop(0, 0, 0, 8, Pose2(0.02, 0.0, 0.0)));  // inside map 0: due
  OptimisationJob job = b.prepareOptimisation(0);
  MultiSessionBackend::solveOptimisation(&job);

  EXPECT_EQ(b.removeSession(1).code, StatusCode::kFailedPrecondition);  // shares map 0
  EXPECT_EQ(b.removeSession(7).code, StatusCode::kNotFound);
  const int recording = b.startSession("live");
  EXPECT_EQ(b.removeSession(recording).code, StatusCode::kFailedPrecondition);
  b.endSession(recording);
  EXPECT_EQ(b.numSessions(), 5);
  const BackendStatus st = b.removeSession(2);
  ASSERT_TRUE(st.ok()) << st.message;
  EXPECT_NE(st.message.find("3 loops"), std::string::npos) << st.message;

  EXPECT_EQ(b.numSessions(), 4);
  EXPECT_EQ(b.mapIds(), (std::vector<int>{0, 3}));  // map 0 and the empty live session, now 3
  EXPECT_EQ(b.chain(0), (std::vector<int>{0, 1, 2}));
  EXPECT_EQ(b.mapOf(2), 0);
  EXPECT_EQ(b.session(2).name, "session_3");  // the old session 3, its name kept
  for (const auto& [now, was] : {std::pair{0, 0}, {1, 1}, {2, 3}})
    EXPECT_EQ(worstError(b.sessionPoses(now), poses[was]), 0.0) << was;
  EXPECT_EQ(b.numLoops(), 10 - 3);
  for (int i = 0; i < b.numLoops(); ++i) {
    const BackendLoop& x = b.loopRecord(i).loop;
    EXPECT_TRUE(x.session_a != 2 || x.session_b != 2 || x.keyframe_b != 6) << "session 2's own loop is gone";
    EXPECT_LE(std::max(x.session_a, x.session_b), 2);
  }
  auto shifted = linked;
  for (auto& [sa, ka, sb, kb] : shifted) {
    sa = sa > 2 ? sa - 1 : sa;
    sb = sb > 2 ? sb - 1 : sb;
  }
  EXPECT_EQ(loopsOfLinks(0), shifted);  // the links name the same loops
  EXPECT_EQ(b.splitPairs(), (std::vector<std::pair<int, int>>{{0, 2}}));  // (1, 2) went with session 2
  EXPECT_FALSE(b.applyOptimisation(job));  // prepared before: dropped...
  EXPECT_EQ(b.dueMaps(), std::vector<int>{0});  // ...and map 0 still waits for it
  b.setDeferred(false);
  b.flush();
  EXPECT_LT(worstError(b.sessionPoses(2), w.truthIn(0, 3)), 0.05);
}

INSTANTIATE_TEST_SUITE_P(Backend, BothOptimizers, ::testing::Values(OptimizerKind::kIekf, OptimizerKind::kSparse),
                         [](const auto& info) { return std::string(optimizerName(info.param)); });

TEST(Backend, BothOptimizersAgreeOnTheSameNoisyRun) {
  auto run = [](OptimizerKind k) {
    World w;
    w.odo_noise = 0.01;
    w.sessions = {line(Pose2(0, 0, 0), 15), line(Pose2(3.0, -3.0, M_PI / 2), 15)};
    BackendOptions o = optionsFor(k);
    o.join_min_loops = 3;
    o.sparse.robust_loss = RobustLoss::kNone;
    MultiSessionBackend b(o);
    w.feed(&b, 0);
    w.feed(&b, 1);
    for (int k = 0; k < 3; ++k) b.addLoop(w.loop(0, 5 + k, 1, 6));
    for (int k = 0; k < 3; ++k) b.addLoop(w.loop(0, 6, 1, 5 + k));
    b.flush();
    return std::make_pair(b.sessionPoses(0), b.sessionPoses(1));
  };
  const auto iekf = run(OptimizerKind::kIekf), sparse = run(OptimizerKind::kSparse);
  EXPECT_LT(worstError(iekf.first, sparse.first), 0.01);
  EXPECT_LT(worstError(iekf.second, sparse.second), 0.01);
}

TEST(Backend, TheIekfHandsALargeMapToTheSparseOptimiser) {
  // Out and back along x with a loop 0.5 m off the odometry (50 sigma of the loop: far into the
  // sparse optimiser's robust loss, where the IEKF, plain least squares, lands elsewhere). After
  // the handover the map must be solved by the sparse optimiser: the same trajectory as a back-end
  // that was sparse from the start (same graph, same initial values), to rounding.
  auto run = [](OptimizerKind kind, std::vector<std::string>* said) {
    BackendOptions o = optionsFor(kind);
    o.max_keyframes = 10;
    MultiSessionBackend b(o, [said](const std::string& l) { said->push_back(l); });
    const int s = b.startSession();
    for (int k = 0; k < 12; ++k) b.addMotion(s, UncertainPose2(Pose2(0.5, 0.0, k == 5 ? M_PI : 0.0), diag(0.02, 0.01)));
    const std::vector<Pose2> odometry = b.sessionPoses(s);
    b.addLoop({s, 0, s, 11, UncertainPose2(Pose2(0, 0, M_PI), diag(0.01, 0.01))});
    EXPECT_EQ(b.stats().optimisations, 1);
    EXPECT_GT(worstError(b.sessionPoses(s), odometry), 0.1);  // the loop moved the trajectory
    return b.sessionPoses(s);
  };
  std::vector<std::string> said, said_sparse;
  const std::vector<Pose2> handed = run(OptimizerKind::kIekf, &said);
  ASSERT_EQ(said.size(), 1u);
  EXPECT_NE(said[0].find("sparse"), std::string::npos) << said[0];
  const std::vector<Pose2> sparse = run(OptimizerKind::kSparse, &said_sparse);
  EXPECT_TRUE(said_sparse.empty());
  ASSERT_EQ(handed.size(), 13u);
  ASSERT_EQ(sparse.size(), 13u);
  for (std::size_t k = 0; k < handed.size(); ++k)
    EXPECT_TRUE(approxEqual(handed[k], sparse[k], 1e-9, 1e-9)) << k << ": " << handed[k] << " vs " << sparse[k];
}

TEST(Backend, AKeyframesCovarianceInTheMapAgreesWithMonteCarlo) {
  // Motions with correlated covariances along a turning path; the propagated covariance of the
  // last keyframe against the sample covariance of 20000 composed draws (independent motions).
  BackendOptions o;
  o.optimise = false;
  MultiSessionBackend b(o);
  const int s = b.startSession();
  std::vector<UncertainPose2> motions;
  for (int k = 0; k < 6; ++k) {
    Eigen::Matrix3d c;
    c << 4e-4, 1e-4, 2e-5,  //
        1e-4, 3e-4, -1e-5,  //
        2e-5, -1e-5, 2e-4;
    motions.emplace_back(Pose2(0.5, 0.1 * k, 0.3), c * (1.0 + 0.2 * k));
    b.addMotion(s, motions.back());
  }
  const UncertainPose2 got = b.keyframeInMap(s, 6);
  std::mt19937 rng(7);
  std::normal_distribution<double> n(0.0, 1.0);
  const int draws = 20000;
  std::vector<Eigen::Vector3d> samples;
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (int d = 0; d < draws; ++d) {
    Pose2 x;
    for (const UncertainPose2& m : motions) {
      const Eigen::Matrix3d l = m.covariance.llt().matrixL();
      x = compose(x, Pose2::fromVector(m.mean.vector() + l * Eigen::Vector3d(n(rng), n(rng), n(rng))));
    }
    samples.push_back(x.vector());
    mean += x.vector() / draws;
  }
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (const Eigen::Vector3d& v : samples) cov += (v - mean) * (v - mean).transpose() / (draws - 1);
  EXPECT_LT((got.mean.vector() - mean).norm(), 0.01);
  // First order against the truth: within 5 % of the largest entry (the sampling error is ~1 %).
  EXPECT_LT((got.covariance - cov).cwiseAbs().maxCoeff(), 0.05 * cov.cwiseAbs().maxCoeff())
      << "propagated\n"
      << got.covariance << "\nsampled\n"
      << cov;
  EXPECT_THROW(b.keyframeInMap(s, 7), std::invalid_argument);
  EXPECT_EQ(b.keyframeInMap(s, 0).covariance.norm(), 0.0);  // the map's origin
}

TEST(Backend, RefusesBadOptions) {
  BackendOptions o;
  o.optimise_every = 0;
  EXPECT_THROW(MultiSessionBackend{o}, std::invalid_argument);
  o = BackendOptions();
  o.sparse.max_iterations = 0;
  EXPECT_THROW(MultiSessionBackend{o}, std::invalid_argument);
  OptimizerKind k;
  EXPECT_TRUE(parseOptimizer("iekf", &k) && k == OptimizerKind::kIekf);
  EXPECT_FALSE(parseOptimizer("g2o", &k));
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
