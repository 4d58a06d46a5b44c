// The optimisers behind MapOptimizer (core/backend/map_optimizer.h), the map estimate's two forms
// (map_estimate.h), and the back-end driven by the optimiser it is given.
#include <gtest/gtest.h>

#include <Eigen/Dense>

#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include "uw_multislam/core/backend/backend.h"
#include "uw_multislam/core/backend/iekf_optimizer.h"
#include "uw_multislam/core/backend/map_estimate.h"
#include "uw_multislam/core/backend/pose_graph_optimizer.h"

namespace uw_multislam {
namespace core {
namespace {

Eigen::Matrix3d diag(double sxy, double syaw) {
  return Eigen::Vector3d(sxy * sxy, sxy * sxy, syaw * syaw).asDiagonal();
}

// A drifted square of 8 motions, each with its own covariance.
std::vector<UncertainPose2> square() {
  std::vector<UncertainPose2> m;
  for (int k = 0; k < 8; ++k)
    m.emplace_back(Pose2(1.05, 0.02 * k, k % 2 ? M_PI / 2 + 0.03 : 0.01), diag(0.02 + 0.005 * k, 0.01));
  return m;
}

MapEstimate marginalOf(const std::vector<UncertainPose2>& motions) {
  MapEstimate e;
  for (const UncertainPose2& m : motions) e.append(m);
  return e;
}

// The square's graph: its motions as the chain, one loop closing it (keyframe 8 back on 0).
MapGraph squareGraph() {
  MapGraph g;
  const std::vector<UncertainPose2> m = square();
  for (int k = 0; k < static_cast<int>(m.size()); ++k) g.chain.push_back({k, k + 1, m[k], false});
  g.loops.push_back({7, 0, 8, UncertainPose2(Pose2(), diag(0.01, 0.005))});
  g.applied.push_back(false);
  return g;
}

PoseGraphOptimizer sparseOptimizer() { return PoseGraphOptimizer(SparseOptions(), 100.0); }
IekfOptimizer iekfOptimizer(int max_keyframes = 1500) {
  return IekfOptimizer(IekfOptions(), max_keyframes, 3.0, sparseOptimizer());
}

void expectNear(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b, double tol) {
  EXPECT_LE((a - b).cwiseAbs().maxCoeff(), tol) << a << "\nvs\n" << b;
}

TEST(MapOptimizerFactory, MakesTheOptimiserTheOptionsName) {
  BackendOptions o;
  o.optimizer = OptimizerKind::kIekf;
  EXPECT_STREQ(makeMapOptimizer(o)->name(), "iekf");
  o.optimizer = OptimizerKind::kSparse;
  EXPECT_STREQ(makeMapOptimizer(o)->name(), "sparse");
  // Nothing is solved without optimise: the maps keep the odometry's marginals.
  o.optimizer = OptimizerKind::kIekf;
  o.optimise = false;
  EXPECT_STREQ(makeMapOptimizer(o)->name(), "sparse");
  o.optimise_every = 0;
  EXPECT_THROW(makeMapOptimizer(o), std::invalid_argument);
}

TEST(MapEstimate, TheJointFormAndItsMarginalsAgreeOnMotionsAndBlocks) {
  const MapEstimate marginal = marginalOf(square());
  const MapEstimate joint = iekfOptimizer().adopt(marginal);
  ASSERT_NE(joint.filter(), nullptr);
  EXPECT_EQ(marginal.filter(), nullptr);
  ASSERT_EQ(joint.numMotions(), 8);
  for (int k = 0; k < 8; ++k) {
    EXPECT_TRUE(approxEqual(joint.motion(k), marginal.motion(k), 0.0, 0.0));
    expectNear(joint.motionCov(k), marginal.motionCov(k), 0.0);
  }
  const MapEstimate back = joint.marginal();
  EXPECT_EQ(back.filter(), nullptr);
  for (int k = 0; k < 8; ++k) expectNear(back.motionCov(k), marginal.motionCov(k), 0.0);
  EXPECT_THROW(MapEstimate(std::vector<Pose2>(2), std::vector<Eigen::Matrix3d>(1)), std::invalid_argument);
  MapEstimate j = joint;
  EXPECT_THROW(j.setMotion(0, Pose2()), std::logic_error);
}

TEST(MapEstimate, AComposedSliceOfTheJointFormIsTheFiltersOwnRelativeWithItsCorrelations) {
  // A loop correlates the motions; the composed motion of a slice must carry them (J P Jᵀ with the
  // cross terms), i.e. equal what the filter itself says of the pose of keyframe 6 in keyframe 2.
  MapEstimate joint = iekfOptimizer().adopt(marginalOf(square()));
  TrajectoryIekf filter = *joint.filter();
  filter.update({{0, 8, UncertainPose2(Pose2(), diag(0.01, 0.005))}});
  joint = MapEstimate(filter);
  const MapEstimate s = joint.slice({{0, 2}, {2, 6}, {6, 8}}, 1);
  ASSERT_NE(s.filter(), nullptr);
  ASSERT_EQ(s.numMotions(), 5);
  const UncertainPose2 truth = filter.relative(2, 6);
  EXPECT_TRUE(approxEqual(s.motion(2), truth.mean, 1e-12, 1e-12));
  expectNear(s.motionCov(2), truth.covariance, 1e-12);
  // The kept motions keep their blocks, and their correlation with the composed one.
  for (int k : {0, 1}) expectNear(s.motionCov(k), joint.motionCov(k), 0.0);
  for (int k : {3, 4}) expectNear(s.motionCov(k), joint.motionCov(k + 3), 0.0);
  const UncertainPose2 across = s.filter()->relative(1, 4);  // motions 1, composed, 6 of the original
  const UncertainPose2 original = filter.relative(1, 7);
  EXPECT_TRUE(approxEqual(across.mean, original.mean, 1e-12, 1e-12));
  expectNear(across.covariance, original.covariance, 1e-12);
  // The marginal form composes the marginals alone.
  const MapEstimate m = joint.marginal().slice({{0, 2}, {2, 6}, {6, 8}}, 1);
  EXPECT_EQ(m.filter(), nullptr);
  EXPECT_TRUE(approxEqual(m.motion(2), truth.mean, 1e-12, 1e-12));
}

TEST(MapOptimizers, TheIekfAppliesALoopOnceThePoseGraphSolvesItEveryTime) {
  const MapGraph g = squareGraph();
  for (const bool iekf : {true, false}) {
    SCOPED_TRACE(iekf ? "iekf" : "sparse");
    const PoseGraphOptimizer sparse = sparseOptimizer();
    const IekfOptimizer dense = iekfOptimizer();
    const MapOptimizer& o = iekf ? static_cast<const MapOptimizer&>(dense) : sparse;
    MapEstimate e = o.adopt(marginalOf(square()));
    EXPECT_EQ(e.filter() != nullptr, iekf);
    std::vector<MapLoop> loops;
    std::unique_ptr<MapProblem> p = o.prepare(e, g, &loops);
    ASSERT_TRUE(p);
    ASSERT_EQ(loops.size(), 1u);
    EXPECT_EQ(loops[0].id, 7);
    const double open = p->relative(0, 8).translation().norm();
    p->solve(loops);
    EXPECT_LT(p->relative(0, 8).translation().norm(), 0.1 * open);
    p->reset();
    EXPECT_NEAR(p->relative(0, 8).translation().norm(), open, 1e-12);
    p->solve(loops);
    EXPECT_EQ(p->apply(&e), iekf);
    Pose2 end;
    for (int k = 0; k < e.numMotions(); ++k) end = compose(end, e.motion(k));
    EXPECT_LT(end.translation().norm(), 0.1 * open);
    // The loop applied: the IEKF does not take it again, the pose graph does.
    MapGraph after = g;
    after.applied[0] = true;
    EXPECT_EQ(o.prepare(e, after, &loops) == nullptr, iekf);
    EXPECT_EQ(loops.size(), iekf ? 0u : 1u);
  }
}

TEST(MapOptimizers, TheIekfHandsAMapThatOutgrowsItToTheSparseForm) {
  const IekfOptimizer o = iekfOptimizer(6);
  MapEstimate e = o.start();
  ASSERT_NE(e.filter(), nullptr);
  std::string note;
  for (int k = 0; k < 4; ++k) o.addMotion(&e, square()[k], &note);
  EXPECT_NE(e.filter(), nullptr);
  EXPECT_EQ(note, "");
  o.addMotion(&e, square()[4], &note);  // 6 keyframes: still joint
  EXPECT_NE(e.filter(), nullptr);
  o.addMotion(&e, square()[5], &note);  // 7
  EXPECT_EQ(e.filter(), nullptr);
  EXPECT_NE(note.find("max_keyframes = 6"), std::string::npos) << note;
  EXPECT_EQ(e.numMotions(), 6);
  // A join of two joint maps that fits stays joint, with the link's block between theirs.
  const MapEstimate a = o.adopt(marginalOf({square()[0], square()[1]}));
  const MapEstimate b = o.adopt(marginalOf({square()[2]}));
  note.clear();
  const UncertainPose2 link(Pose2(0.3, 0.1, 0.2), diag(0.2, 0.05));
  const MapEstimate j = o.join(a, link, b, &note);
  ASSERT_NE(j.filter(), nullptr);
  EXPECT_EQ(note, "");
  expectNear(j.motionCov(2), link.covariance, 0.0);
  EXPECT_TRUE(approxEqual(j.motion(3), square()[2].mean, 0.0, 0.0));
  const MapEstimate c = o.adopt(marginalOf({square()[2], square()[3], square()[4]}));
  const MapEstimate too_large = o.join(a, link, c, &note);  // 7 keyframes
  EXPECT_EQ(too_large.filter(), nullptr);
  EXPECT_NE(note.find("joined map exceeds"), std::string::npos) << note;
}

// A pose-graph optimiser that counts what the back-end asks of it.
class CountingOptimizer : public PoseGraphOptimizer {
 public:
  explicit CountingOptimizer(int* prepared) : PoseGraphOptimizer(SparseOptions(), 100.0), prepared_(prepared) {}
  std::unique_ptr<MapProblem> prepare(const MapEstimate& e, const MapGraph& g,
                                      std::vector<MapLoop>* loops) const override {
    ++*prepared_;
    return PoseGraphOptimizer::prepare(e, g, loops);
  }

 private:
  int* prepared_;
};

TEST(MultiSessionBackend, OptimisesWithTheOptimiserItIsGivenWhateverTheOptionsName) {
  BackendOptions o;
  o.optimise_every = 1;
  auto run = [&](std::unique_ptr<MapOptimizer> optimizer) {
    MultiSessionBackend b = optimizer ? MultiSessionBackend(o, std::move(optimizer)) : MultiSessionBackend(o);
    const int s = b.startSession();
    for (const UncertainPose2& m : square()) b.addMotion(s, m);
    b.addLoop({s, 0, s, 8, UncertainPose2(Pose2(), diag(0.01, 0.005))});
    return b.sessionPoses(s);
  };
  o.optimizer = OptimizerKind::kSparse;
  const std::vector<Pose2> sparse = run(nullptr);
  o.optimizer = OptimizerKind::kIekf;
  const std::vector<Pose2> iekf = run(nullptr);
  int prepared = 0;
  const std::vector<Pose2> given = run(std::make_unique<CountingOptimizer>(&prepared));
  EXPECT_EQ(prepared, 1);
  ASSERT_EQ(given.size(), sparse.size());
  bool differs_from_iekf = false;
  for (std::size_t k = 0; k < given.size(); ++k) {
    EXPECT_TRUE(approxEqual(given[k], sparse[k], 0.0, 0.0)) << k;  // bit for bit: the same solver
    differs_from_iekf = differs_from_iekf || !approxEqual(given[k], iekf[k], 1e-9, 1e-9);
  }
  EXPECT_TRUE(differs_from_iekf);
  EXPECT_THROW(MultiSessionBackend(o, std::unique_ptr<MapOptimizer>()), std::invalid_argument);
}

// Position priors through MapOptimizer: on a tiny map (three keyframes, two odometry motions, two
// absolute position priors) both optimisers reach the minimiser of the same cost found by a
// brute-force Gauss-Newton written here with numeric derivatives, over the two motions:
//   sum_k |m_k - z_k|^2_{P_k} (yaw wrapped) + sum_p |t(X_p^0) - z_p|^2_{C_p}.
struct TinyPriorMap {
  std::vector<UncertainPose2> motions{
      UncertainPose2(Pose2(10.0, 0.0, 0.1), Eigen::Vector3d(0.04, 0.04, 0.001).asDiagonal()),
      UncertainPose2(Pose2(10.0, 1.0, -0.05), Eigen::Vector3d(0.09, 0.04, 0.002).asDiagonal())};
  std::vector<PositionPrior> priors{
      {1, Eigen::Vector2d(10.5, 0.8), (Eigen::Matrix2d() << 0.25, 0.05, 0.05, 0.16).finished()},
      {2, Eigen::Vector2d(19.0, 3.5), Eigen::Vector2d(0.36, 0.25).asDiagonal()}};

  double cost(const Eigen::Matrix<double, 6, 1>& x) const {
    double c = 0.0;
    std::vector<Pose2> at{Pose2()};
    for (int k = 0; k < 2; ++k) {
      const Pose2 m = Pose2::fromVector(x.segment<3>(3 * k));
      Eigen::Vector3d e = m.vector() - motions[k].mean.vector();
      e(2) = std::remainder(e(2), 2.0 * M_PI);
      c += e.dot(motions[k].covariance.inverse() * e);
      at.push_back(compose(at.back(), m));
    }
    for (const PositionPrior& p : priors) {
      const Eigen::Vector2d e = Eigen::Vector2d(at[p.index].x(), at[p.index].y()) - p.position;
      c += e.dot(p.covariance.inverse() * e);
    }
    return c;
  }
  // Newton on the cost with central-difference gradient and Hessian: no Jacobian of this code base.
  std::vector<Pose2> bruteForce() const {
    Eigen::Matrix<double, 6, 1> x;
    x << motions[0].mean.vector(), motions[1].mean.vector();
    const double h = 1e-4;
    for (int it = 0; it < 50; ++it) {
      Eigen::Matrix<double, 6, 1> g;
      Eigen::Matrix<double, 6, 6> hess;
      for (int a = 0; a < 6; ++a) {
        Eigen::Matrix<double, 6, 1> da = Eigen::Matrix<double, 6, 1>::Zero();
        da(a) = h;
        g(a) = (cost(x + da) - cost(x - da)) / (2 * h);
        for (int b = 0; b < 6; ++b) {
          Eigen::Matrix<double, 6, 1> db = Eigen::Matrix<double, 6, 1>::Zero();
          db(b) = h;
          hess(a, b) = (cost(x + da + db) - cost(x + da - db) - cost(x - da + db) + cost(x - da - db)) / (4 * h * h);
        }
      }
      const Eigen::Matrix<double, 6, 1> step = hess.ldlt().solve(g);
      x -= step;
      if (step.lpNorm<Eigen::Infinity>() < 1e-10) break;
    }
    return {Pose2::fromVector(x.segment<3>(0)), Pose2::fromVector(x.segment<3>(3))};
  }
};

TEST(MapOptimizer, PositionPriorsMoveBothOptimisersToTheBruteForceLeastSquares) {
  const TinyPriorMap t;
  const std::vector<Pose2> want = t.bruteForce();
  // The priors disagree with the odometry by decimetres: the minimiser is far from the odometry.
  EXPECT_GT(poseError(want[1], t.motions[1].mean).head<2>().norm(), 0.1);
  const PoseGraphOptimizer sparse(SparseOptions(), 1.0);
  const IekfOptimizer iekf(IekfOptions(), 100, 1.0, sparse);
  for (const MapOptimizer* o : std::vector<const MapOptimizer*>{&sparse, &iekf}) {
    MapEstimate e = o->start();
    std::string note;
    MapGraph graph;
    for (int k = 0; k < 2; ++k) {
      o->addMotion(&e, t.motions[k], &note);
      graph.chain.push_back({k, k + 1, t.motions[k], false});
    }
    std::vector<MapLoop> loops;
    EXPECT_EQ(o->prepare(e, graph, &loops), nullptr) << o->name();  // nothing to solve without priors
    graph.priors = t.priors;
    const std::unique_ptr<MapProblem> problem = o->prepare(e, graph, &loops);
    ASSERT_NE(problem, nullptr) << o->name();
    EXPECT_TRUE(loops.empty());
    problem->solve(loops);
    problem->apply(&e);
    for (int k = 0; k < 2; ++k)
      EXPECT_TRUE(approxEqual(e.motion(k), want[k], 1e-5, 1e-6))
          << o->name() << " motion " << k << ": " << e.motion(k) << " vs " << want[k];
  }
}

TEST(MapOptimizer, APositionPriorOnKeyframeZeroOrNotPositiveDefiniteIsRefused) {
  EXPECT_NE(checkPositionPrior({0, Eigen::Vector2d(1, 1), Eigen::Matrix2d::Identity()}, 3).find("outside [1, 2]"),
            std::string::npos);
  EXPECT_NE(checkPositionPrior({3, Eigen::Vector2d(1, 1), Eigen::Matrix2d::Identity()}, 3).find("outside [1, 2]"),
            std::string::npos);
  EXPECT_NE(checkPositionPrior({1, Eigen::Vector2d(NAN, 1), Eigen::Matrix2d::Identity()}, 3).find("not finite"),
            std::string::npos);
  EXPECT_NE(checkPositionPrior({1, Eigen::Vector2d(1, 1), -Eigen::Matrix2d::Identity()}, 3).find("positive definite"),
            std::string::npos);
  EXPECT_EQ(checkPositionPrior({2, Eigen::Vector2d(1, 1), Eigen::Matrix2d::Identity()}, 3), "");
  std::vector<Pose2> poses(3);
  EXPECT_THROW(
      optimisePoseGraph(&poses, {}, SparseOptions(), 0, {{0, Eigen::Vector2d(1, 1), Eigen::Matrix2d::Identity()}}),
      std::invalid_argument);
  TrajectoryIekf f;
  f.addMotion(UncertainPose2(Pose2(1, 0, 0), Eigen::Matrix3d::Identity()));
  EXPECT_THROW(f.update({}, {{2, Eigen::Vector2d(1, 1), Eigen::Matrix2d::Identity()}}), std::invalid_argument);
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
