// First-order covariance propagation through ⊕ and ⊖ against Monte-Carlo estimates.
//
// Statistical tolerance: for N independent samples of a (near-)Gaussian vector with covariance
// S, the sample covariance entry (r, c) has standard error sqrt((S_rr S_cc + S_rc^2) / N). Each
// entry must agree within 5 standard errors (a false alarm probability of ~6e-7 per entry for a
// Gaussian statistic). The noise levels are chosen so that the second-order terms dropped by
// the linearisation (about |t| sigma_yaw^2) stay below one standard error; a wrong Jacobian
// (e.g. a missing rotation) moves entries by tens of standard errors. The seeds are fixed, so
// the test is deterministic.
#include <gtest/gtest.h>

#include <Eigen/Dense>

#include <cmath>
#include <random>

#include "uw_multislam/core/geometry/uncertain_pose.h"

namespace uw_multislam {
namespace core {
namespace {

class Sampler {
 public:
  explicit Sampler(unsigned seed) : rng_(seed) {}
  Pose2 draw(const UncertainPose2& p) {
    const Eigen::Matrix3d l = p.covariance.llt().matrixL();
    Eigen::Vector3d z(n_(rng_), n_(rng_), n_(rng_));
    return Pose2::fromVector(p.mean.vector() + l * z);
  }

 private:
  std::mt19937_64 rng_;
  std::normal_distribution<double> n_{0.0, 1.0};
};

struct SampleStats {
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
};

// Errors are taken relative to the reference mean (yaw wrapped) so that samples near ±pi are
// not split in two.
SampleStats stats(const std::vector<Pose2>& samples, const Pose2& reference) {
  SampleStats s;
  for (const auto& p : samples) s.mean += poseError(p, reference);
  s.mean /= static_cast<double>(samples.size());
  for (const auto& p : samples) {
    const Eigen::Vector3d d = poseError(p, reference) - s.mean;
    s.cov += d * d.transpose();
  }
  s.cov /= static_cast<double>(samples.size() - 1);
  return s;
}

void expectCovarianceWithinStandardErrors(const Eigen::Matrix3d& predicted, const Eigen::Matrix3d& sampled, int n,
                                          double k_se = 5.0) {
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) {
      const double se = std::sqrt((predicted(r, r) * predicted(c, c) + predicted(r, c) * predicted(r, c)) / n);
      EXPECT_NEAR(sampled(r, c), predicted(r, c), k_se * se) << "entry (" << r << "," << c << ")";
    }
  }
}

// Fraction of samples inside the 95 % ellipsoid of the predicted covariance (chi-square, 3 dof).
double coverage95(const std::vector<Pose2>& samples, const UncertainPose2& predicted) {
  const Eigen::Matrix3d info = predicted.covariance.inverse();
  int inside = 0;
  for (const auto& p : samples) {
    const Eigen::Vector3d e = poseError(p, predicted.mean);
    if (e.dot(info * e) < 7.814727903) ++inside;
  }
  return static_cast<double>(inside) / samples.size();
}

Eigen::Matrix3d cov(double sx, double sy, double st, double rho_xy = 0.0) {
  Eigen::Matrix3d p;
  p << sx * sx, rho_xy * sx * sy, 0.0,  //
      rho_xy * sx * sy, sy * sy, 0.0,   //
      0.0, 0.0, st * st;
  return p;
}

constexpr int kSamples = 100000;

TEST(UncertainPose, ComposeMatchesMonteCarlo) {
  const UncertainPose2 a(Pose2(1.0, -2.0, 2.8), cov(0.10, 0.08, 0.03, 0.4));
  const UncertainPose2 b(Pose2(2.0, 0.5, 0.9), cov(0.05, 0.12, 0.04, -0.3));
  const UncertainPose2 c = compose(a, b);
  Sampler s(42);
  std::vector<Pose2> samples;
  for (int i = 0; i < kSamples; ++i) samples.push_back(compose(s.draw(a), s.draw(b)));
  const SampleStats st = stats(samples, c.mean);
  expectCovarianceWithinStandardErrors(c.covariance, st.cov, kSamples);
  // The yaw crosses pi in this case (2.8 + 0.9): the mean must still be right.
  EXPECT_NEAR(st.mean.z(), 0.0, 5 * std::sqrt(c.covariance(2, 2) / kSamples));
  EXPECT_NEAR(coverage95(samples, c), 0.95, 0.005);
}

TEST(UncertainPose, InvertMatchesMonteCarlo) {
  const UncertainPose2 a(Pose2(3.0, 1.0, -2.0), cov(0.08, 0.10, 0.03, 0.2));
  const UncertainPose2 inv = invert(a);
  Sampler s(43);
  std::vector<Pose2> samples;
  for (int i = 0; i < kSamples; ++i) samples.push_back(invert(s.draw(a)));
  expectCovarianceWithinStandardErrors(inv.covariance, stats(samples, inv.mean).cov, kSamples);
  EXPECT_NEAR(coverage95(samples, inv), 0.95, 0.005);
}

TEST(UncertainPose, WrongJacobianWouldBeDetected) {
  // Guard on the test itself: ignoring the rotation of a in J2 gives a covariance the
  // Monte-Carlo comparison must reject.
  const UncertainPose2 a(Pose2(0.0, 0.0, 1.2), Eigen::Matrix3d::Zero());
  const UncertainPose2 b(Pose2(1.0, 0.0, 0.0), cov(0.20, 0.02, 0.01));
  Sampler s(44);
  std::vector<Pose2> samples;
  for (int i = 0; i < kSamples; ++i) samples.push_back(compose(a.mean, s.draw(b)));
  const Eigen::Matrix3d sampled = stats(samples, compose(a, b).mean).cov;
  const Eigen::Matrix3d wrong = b.covariance;  // J2 = I instead of R(yaw_a)
  const double se = std::sqrt(2.0 * wrong(0, 0) * wrong(0, 0) / kSamples);
  EXPECT_GT(std::abs(sampled(0, 0) - wrong(0, 0)), 50 * se);
}

TEST(UncertainPose, ExactPosesStayExact) {
  const UncertainPose2 c = compose(UncertainPose2::exact(Pose2(1, 2, 0.3)), UncertainPose2::exact(Pose2(-1, 0, 1)));
  EXPECT_TRUE(c.covariance.isZero(0.0));
}

TEST(CheckCovariance, AcceptsValidRejectsBroken) {
  EXPECT_EQ(checkCovariance(cov(0.1, 0.1, 0.01, 0.5)), "");
  EXPECT_EQ(checkCovariance(Eigen::Matrix3d::Zero()), "");
  Eigen::Matrix3d asym = cov(0.1, 0.1, 0.1);
  asym(0, 1) = 0.001;
  EXPECT_NE(checkCovariance(asym).find("symmetric"), std::string::npos);
  Eigen::Matrix3d neg = cov(0.1, 0.1, 0.1);
  neg(2, 2) = -0.01;
  EXPECT_NE(checkCovariance(neg).find("positive"), std::string::npos);
  Eigen::Matrix3d nan = cov(0.1, 0.1, 0.1);
  nan(1, 1) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_NE(checkCovariance(nan).find("finite"), std::string::npos);
}

TEST(CheckUncertainPose, CovarianceThenMeanThenInverse) {
  const UncertainPose2 good(Pose2(1, 2, 0.3), cov(0.1, 0.1, 0.01, 0.5));
  EXPECT_EQ(checkUncertainPose(good), "");
  EXPECT_EQ(checkUncertainPose(good, true), "");
  UncertainPose2 nan_mean = good;
  nan_mean.mean = Pose2(1, std::numeric_limits<double>::quiet_NaN(), 0.3);
  EXPECT_EQ(checkUncertainPose(nan_mean), "mean not finite");
  UncertainPose2 inf_yaw = good;
  inf_yaw.mean = Pose2(1, 2, std::numeric_limits<double>::infinity());
  EXPECT_EQ(checkUncertainPose(inf_yaw), "mean not finite");
  // Finite, but no motion between keyframes: refused beyond kMaxRelativeTranslationM, in x or y.
  UncertainPose2 far = good;
  far.mean = Pose2(kMaxRelativeTranslationM, -kMaxRelativeTranslationM, 0.3);
  EXPECT_EQ(checkUncertainPose(far), "");
  far.mean = Pose2(std::nextafter(kMaxRelativeTranslationM, 2e7), 2, 0.3);
  EXPECT_NE(checkUncertainPose(far).find("farther than 1e7 m"), std::string::npos);
  far.mean = Pose2(1, -1e300, 0.3);
  EXPECT_NE(checkUncertainPose(far).find("farther than 1e7 m"), std::string::npos);
  UncertainPose2 asym = good;
  asym.covariance(0, 1) += 0.01;
  EXPECT_NE(checkUncertainPose(asym).find("symmetric"), std::string::npos);
  // Singular: fine for a motion (an exact first pose), refused where an information matrix is needed.
  UncertainPose2 singular = good;
  singular.covariance.row(2).setZero();
  singular.covariance.col(2).setZero();
  EXPECT_EQ(checkUncertainPose(singular), "");
  EXPECT_NE(checkUncertainPose(singular, true).find("singular"), std::string::npos);
  EXPECT_NE(checkUncertainPose(UncertainPose2::exact(Pose2()), true).find("singular"), std::string::npos);
  // Positive definite, but an inverse that overflows (the determinant underflows to 0).
  const UncertainPose2 tiny(Pose2(1, 2, 0.3), Eigen::Matrix3d::Identity() * 1e-110);
  EXPECT_EQ(checkUncertainPose(tiny), "");
  EXPECT_NE(checkUncertainPose(tiny, true).find("singular"), std::string::npos);
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
