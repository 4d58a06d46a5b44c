// Absolute position priors through the multi-session back-end (MultiSessionBackend::addPositionPrior):
// a drifting trajectory pulled toward two fixes by exactly what the weighted least squares says,
// with both optimisers, with no loop at all; the IEKF applying each prior once; a join moving a
// prior into the joined map's frame; a prior on a later session of a map staying where it was put.
#include <gtest/gtest.h>

#include <Eigen/Dense>

#include <cmath>
#include <vector>

#include "uw_multislam/core/backend/backend.h"

namespace uw_multislam {
namespace core {
namespace {

// A survey leg of 9 motions whose odometry drifts: each says 2 m ahead and 5 cm to the left with
// a slow turn, while the vehicle went straight (the truth is (2k, 0)). Two fixes near the truth.
struct DriftingLeg {
  static constexpr int kMotions = 9;
  std::vector<UncertainPose2> motions;
  struct Fix {
    int keyframe;
    Eigen::Vector2d position;
    Eigen::Matrix2d covariance;
  };
  std::vector<Fix> fixes{{5, Eigen::Vector2d(10.0, -0.2), (Eigen::Matrix2d() << 0.09, 0.02, 0.02, 0.16).finished()},
                         {9, Eigen::Vector2d(18.0, -0.2), Eigen::Vector2d(0.25, 0.25).asDiagonal()}};

  DriftingLeg() {
    for (int k = 0; k < kMotions; ++k)
      motions.emplace_back(Pose2(2.0, 0.05, 0.01), Eigen::Vector3d(0.01, 0.01, 1e-4).asDiagonal());
  }

  // The keyframes' poses from the motions x (3 per motion).
  static std::vector<Pose2> posesOf(const Eigen::VectorXd& x) {
    std::vector<Pose2> at{Pose2()};
    for (int k = 0; k < kMotions; ++k) at.push_back(compose(at.back(), Pose2::fromVector(x.segment<3>(3 * k))));
    return at;
  }
  // sum_k |m_k - z_k|^2_{P_k} (yaw wrapped) + sum_f |t(X_f^0) - z_f|^2_{C_f}, over the fixes used.
  double cost(const Eigen::VectorXd& x, int fixes_used) const {
    double c = 0.0;
    for (int k = 0; k < kMotions; ++k) {
      Eigen::Vector3d e = x.segment<3>(3 * k) - motions[k].mean.vector();
      e(2) = std::remainder(e(2), 2.0 * M_PI);
      c += e.dot(motions[k].covariance.inverse() * e);
    }
    const std::vector<Pose2> at = posesOf(x);
    for (int f = 0; f < fixes_used; ++f) {
      const Eigen::Vector2d e = at[fixes[f].keyframe].translation() - fixes[f].position;
      c += e.dot(fixes[f].covariance.inverse() * e);
    }
    return c;
  }
  // Newton with central-difference gradient and Hessian (no Jacobian of the code under test).
  std::vector<Pose2> bruteForce(int fixes_used) const {
    const int n = 3 * kMotions;
    Eigen::VectorXd x(n);
    for (int k = 0; k < kMotions; ++k) x.segment<3>(3 * k) = motions[k].mean.vector();
    const double h = 1e-4;
    for (int it = 0; it < 30; ++it) {
      Eigen::VectorXd g(n);
      Eigen::MatrixXd hess(n, n);
      for (int a = 0; a < n; ++a) {
        Eigen::VectorXd da = Eigen::VectorXd::Zero(n);
        da(a) = h;
        g(a) = (cost(x + da, fixes_used) - cost(x - da, fixes_used)) / (2 * h);
        for (int b = a; b < n; ++b) {
          Eigen::VectorXd db = Eigen::VectorXd::Zero(n);
          db(b) = h;
          hess(a, b) = hess(b, a) = (cost(x + da + db, fixes_used) - cost(x + da - db, fixes_used) -
                                     cost(x - da + db, fixes_used) + cost(x - da - db, fixes_used)) /
                                    (4 * h * h);
        }
      }
      const Eigen::VectorXd step = hess.ldlt().solve(g);
      x -= step;
      if (step.lpNorm<Eigen::Infinity>() < 1e-10) break;
    }
    return posesOf(x);
  }
};

BackendOptions priorOptions(OptimizerKind k) {
  BackendOptions o;
  o.optimizer = k;
  return o;
}

class PriorsBothOptimizers : public ::testing::TestWithParam<OptimizerKind> {};

TEST_P(PriorsBothOptimizers, TwoFixesPullADriftingLegByWhatTheWeightedLeastSquaresSays) {
  const DriftingLeg leg;
  MultiSessionBackend b(priorOptions(GetParam()));
  const int s = b.startSession();
  for (const UncertainPose2& m : leg.motions) b.addMotion(s, m);
  const std::vector<Pose2> odometry = b.sessionPoses(s);
  // No loop anywhere: the priors alone make the problem.
  for (const DriftingLeg::Fix& f : leg.fixes) {
    const BackendStatus st = b.addPositionPrior(s, f.keyframe, f.position, f.covariance);
    ASSERT_TRUE(st.ok()) << st.message;
  }
  EXPECT_EQ(b.stats().priors, 2);
  EXPECT_GE(b.stats().optimisations, 1);
  const std::vector<Pose2> got = b.sessionPoses(s);
  // The IEKF took the two fixes one after the other (one solve each), the pose graph both at once
  // the second time: both reach the minimiser with both fixes.
  const std::vector<Pose2> want = leg.bruteForce(2);
  for (const DriftingLeg::Fix& f : leg.fixes) {
    const double before = (odometry[f.keyframe].translation() - f.position).norm();
    const double after = (got[f.keyframe].translation() - f.position).norm();
    const double expected = (want[f.keyframe].translation() - f.position).norm();
    EXPECT_GT(before, 0.5) << "the odometry's drift at keyframe " << f.keyframe;
    EXPECT_LT(after, before) << optimizerName(GetParam()) << " keyframe " << f.keyframe;
    EXPECT_NEAR(after, expected, 2e-3) << optimizerName(GetParam()) << " keyframe " << f.keyframe;
  }
  for (int k = 0; k <= DriftingLeg::kMotions; ++k)
    EXPECT_LT((got[k].translation() - want[k].translation()).norm(), 2e-3)
        << optimizerName(GetParam()) << " keyframe " << k << ": " << got[k] << " vs " << want[k];
  // Solving again (a flush, or a later loop's solve) must not pull a second time.
  b.addLoop({s, 2, s, 4, UncertainPose2(between(got[2], got[4]), Eigen::Vector3d(1e4, 1e4, 1e2).asDiagonal())});
  b.flush();
  const std::vector<Pose2> again = b.sessionPoses(s);
  for (int k = 0; k <= DriftingLeg::kMotions; ++k)
    EXPECT_LT((again[k].translation() - want[k].translation()).norm(), 3e-3)
        << optimizerName(GetParam()) << " keyframe " << k << " after a second solve: " << again[k] << " vs " << want[k];
  const bool iekf = GetParam() == OptimizerKind::kIekf;
  for (const PriorRecord& p : b.priors()) EXPECT_EQ(p.applied, iekf);  // the IEKF's are in its estimate for good
}

TEST_P(PriorsBothOptimizers, OneFixMovesTheLegByTheWeightedLeastSquaresAmount) {
  const DriftingLeg leg;
  MultiSessionBackend b(priorOptions(GetParam()));
  const int s = b.startSession();
  for (const UncertainPose2& m : leg.motions) b.addMotion(s, m);
  const DriftingLeg::Fix& f = leg.fixes[0];
  ASSERT_TRUE(b.addPositionPrior(s, f.keyframe, f.position, f.covariance).ok());
  const std::vector<Pose2> got = b.sessionPoses(s), want = leg.bruteForce(1);
  for (int k = 0; k <= DriftingLeg::kMotions; ++k)
    EXPECT_LT((got[k].translation() - want[k].translation()).norm(), 1e-3)
        << optimizerName(GetParam()) << " keyframe " << k << ": " << got[k] << " vs " << want[k];
}

TEST_P(PriorsBothOptimizers, BadPriorsAreRefusedWithNothingChanged) {
  MultiSessionBackend b(priorOptions(GetParam()));
  const int s = b.startSession();
  for (int k = 0; k < 3; ++k) b.addMotion(s, UncertainPose2(Pose2(1, 0, 0), Eigen::Matrix3d::Identity() * 0.01));
  const Eigen::Matrix2d c = Eigen::Matrix2d::Identity();
  EXPECT_EQ(b.addPositionPrior(7, 1, Eigen::Vector2d(1, 0), c).code, StatusCode::kInvalidArgument);
  EXPECT_EQ(b.addPositionPrior(s, 4, Eigen::Vector2d(1, 0), c).code, StatusCode::kInvalidArgument);
  EXPECT_EQ(b.addPositionPrior(s, 0, Eigen::Vector2d(1, 0), c).code, StatusCode::kFailedPrecondition);
  EXPECT_EQ(b.addPositionPrior(s, 1, Eigen::Vector2d(NAN, 0), c).code, StatusCode::kInvalidArgument);
  EXPECT_EQ(b.addPositionPrior(s, 1, Eigen::Vector2d(1, 0), -c).code, StatusCode::kInvalidArgument);
  EXPECT_TRUE(b.priors().empty());
  EXPECT_EQ(b.stats().optimisations, 0);
  ASSERT_TRUE(b.addPositionPrior(s, 2, Eigen::Vector2d(2, 0), c).ok());
  EXPECT_EQ(b.addPositionPrior(s, 2, Eigen::Vector2d(2.1, 0), c).code, StatusCode::kAlreadyExists);
  EXPECT_EQ(b.priors().size(), 1u);
}

TEST_P(PriorsBothOptimizers, AJoinMovesTheSecondMapsPriorIntoTheJoinedFrame) {
  // Map 0: a finished leg along x. Map 1 (recording, so placed second): a leg starting at (20, 5)
  // heading +y in map 0's frame, with a prior on its keyframe 3 in its own frame.
  MultiSessionBackend b(priorOptions(GetParam()));
  const Eigen::Matrix3d cov = Eigen::Vector3d(1e-4, 1e-4, 1e-6).asDiagonal();
  const int s0 = b.startSession();
  for (int k = 0; k < 4; ++k) b.addMotion(s0, UncertainPose2(Pose2(5, 0, 0), cov));
  b.endSession(s0);
  const int s1 = b.startSession();
  for (int k = 0; k < 4; ++k) b.addMotion(s1, UncertainPose2(Pose2(2, 0, 0), cov));
  const Eigen::Vector2d in_own(6.0, 0.0);  // keyframe 3 of s1, in s1's frame
  const Eigen::Matrix2d prior_cov = (Eigen::Matrix2d() << 0.04, 0.0, 0.0, 0.01).finished();
  ASSERT_TRUE(b.addPositionPrior(s1, 3, in_own, prior_cov).ok());
  const Pose2 origin1(20.0, 5.0, M_PI / 2);                              // s1's origin in map 0
  const Pose2 kf4_of_s0(20.0, 0.0, 0.0);                                 // s0's last keyframe
  const Pose2 z = between(kf4_of_s0, compose(origin1, Pose2(2, 0, 0)));  // s0:4 -> s1:1
  b.addLoop({s0, 4, s1, 1, UncertainPose2(z, Eigen::Vector3d(1e-4, 1e-4, 1e-6).asDiagonal())});
  ASSERT_TRUE(b.join(s0, s1, 1).ok());
  ASSERT_EQ(b.mapOf(s1), s0);
  ASSERT_EQ(b.priors().size(), 1u);
  const PriorRecord& p = b.priors()[0];
  const Eigen::Vector2d want = origin1.rotation() * in_own + origin1.translation();
  EXPECT_LT((p.position - want).norm(), 1e-6) << p.position.transpose() << " vs " << want.transpose();
  const Eigen::Matrix2d want_cov = origin1.rotation() * prior_cov * origin1.rotation().transpose();
  EXPECT_LT((p.covariance - want_cov).norm(), 1e-12) << p.covariance;
  // And the joined map still honours it: keyframe 3 of s1 near where the prior says.
  b.flush();
  EXPECT_LT((b.sessionPoses(s1)[3].translation() - want).norm(), 0.05);
}

TEST_P(PriorsBothOptimizers, SplittingTheFirstSessionOffMovesTheRestsPriorIntoItsNewFrame) {
  // Map 0 = s0 then s1 (joined by a loop); a prior on s1's keyframe 2 in map 0's frame. Splitting
  // s0 off re-roots the rest at s1's origin: the prior must follow, as s1's poses do.
  MultiSessionBackend b(priorOptions(GetParam()));
  const Eigen::Matrix3d cov = Eigen::Vector3d(1e-4, 1e-4, 1e-6).asDiagonal();
  const int s0 = b.startSession();
  for (int k = 0; k < 4; ++k) b.addMotion(s0, UncertainPose2(Pose2(5, 0, 0), cov));
  b.endSession(s0);
  const int s1 = b.startSession();
  for (int k = 0; k < 4; ++k) b.addMotion(s1, UncertainPose2(Pose2(2, 0, 0), cov));
  const Pose2 origin1(20.0, 5.0, M_PI / 2);
  const Pose2 z = between(Pose2(20.0, 0.0, 0.0), compose(origin1, Pose2(2, 0, 0)));
  b.addLoop({s0, 4, s1, 1, UncertainPose2(z, cov)});
  ASSERT_TRUE(b.join(s0, s1, 1).ok());
  b.endSession(s1);
  const Pose2 kf2 = b.sessionPoses(s1)[2];  // in map 0's frame
  ASSERT_TRUE(b.addPositionPrior(s1, 2, kf2.translation(), Eigen::Matrix2d::Identity() * 0.01).ok());
  const Pose2 kf2_before = b.sessionPoses(s1)[2];
  ASSERT_TRUE(b.split(s0).ok());
  ASSERT_EQ(b.mapOf(s1), s1);
  const Pose2 kf2_after = b.sessionPoses(s1)[2];  // now in s1's own frame
  ASSERT_EQ(b.priors().size(), 1u);
  const Eigen::Vector2d want = kf2_after.translation() + kf2_after.rotation() * kf2_before.rotation().transpose() *
                                                             (kf2.translation() - kf2_before.translation());
  EXPECT_LT((b.priors()[0].position - want).norm(), 1e-6)
      << b.priors()[0].position.transpose() << " vs " << want.transpose();
  EXPECT_GT((b.priors()[0].position - kf2.translation()).norm(), 1.0);  // it did move with the frame
}

TEST_P(PriorsBothOptimizers, APriorOnALaterSessionStaysWhereItWasPutWhenTheMapIsSolvedAgain) {
  // A fix is absolute: it says where a keyframe is in the map's frame, whatever the map's estimate
  // of that keyframe's session. Map 0 = s0 then s1, joined by a loop 1 m off along x (s1's origin
  // said to be at (20, 5), truly at (21, 5)). The first fix moves s1's origin by that metre when
  // the map is solved; a second fix solves it again. Kept relative to s1's (estimated) origin, the
  // first fix would move with it, a metre past the truth, and pull s1 there.
  MultiSessionBackend b(priorOptions(GetParam()));
  const Eigen::Matrix3d cov = Eigen::Vector3d(1e-4, 1e-4, 1e-6).asDiagonal();
  const int s0 = b.startSession();
  for (int k = 0; k < 4; ++k) b.addMotion(s0, UncertainPose2(Pose2(5, 0, 0), cov));
  b.endSession(s0);
  const int s1 = b.startSession();
  for (int k = 0; k < 4; ++k) b.addMotion(s1, UncertainPose2(Pose2(2, 0, 0), cov));
  const Pose2 said(20.0, 5.0, M_PI / 2), truth(21.0, 5.0, M_PI / 2);
  const Pose2 z = between(Pose2(20.0, 0.0, 0.0), compose(said, Pose2(2, 0, 0)));  // s0:4 -> s1:1
  b.addLoop({s0, 4, s1, 1, UncertainPose2(z, Eigen::Vector3d(0.25, 0.25, 1e-4).asDiagonal())});
  ASSERT_TRUE(b.join(s0, s1, 1).ok());
  const Eigen::Matrix2d tight = Eigen::Matrix2d::Identity() * 1e-4;
  const Eigen::Vector2d fix3 = compose(truth, Pose2(6, 0, 0)).translation();
  const Eigen::Vector2d fix4 = compose(truth, Pose2(8, 0, 0)).translation();
  ASSERT_TRUE(b.addPositionPrior(s1, 3, fix3, tight).ok());
  b.flush();
  ASSERT_GT((b.sessionPoses(s1)[0].translation() - said.translation()).norm(), 0.5);  // the fix moved s1's origin
  ASSERT_TRUE(b.addPositionPrior(s1, 4, fix4, tight).ok());
  b.flush();
  ASSERT_EQ(b.priors().size(), 2u);
  EXPECT_EQ(b.priors()[0].position, fix3);
  EXPECT_EQ(b.priors()[1].position, fix4);
  EXPECT_LT((b.sessionPoses(s1)[3].translation() - fix3).norm(), 0.05)
      << b.sessionPoses(s1)[3].translation().transpose();
  EXPECT_LT((b.sessionPoses(s1)[4].translation() - fix4).norm(), 0.05)
      << b.sessionPoses(s1)[4].translation().transpose();
}

INSTANTIATE_TEST_SUITE_P(Backend, PriorsBothOptimizers, ::testing::Values(OptimizerKind::kIekf, OptimizerKind::kSparse),
                         [](const ::testing::TestParamInfo<OptimizerKind>& i) { return optimizerName(i.param); });

}  // namespace
}  // namespace core
}  // namespace uw_multislam
