// NavDriftModel and NavCovarianceCheck: the sigmas of a nav without a usable covariance.
#include <gtest/gtest.h>

#include <vector>

#include "uw_multislam/core/frontend/nav_drift.h"

namespace uw_multislam {
namespace core {
namespace {

using Verdict = NavCovarianceCheck::Verdict;

NavRecord at(double x, double sigma_xy, double sigma_yaw) {
  NavRecord r;
  r.stamp_s = x;
  r.pose = Pose2(x, 0.0, 0.0);
  r.sigma_xy_m = sigma_xy;
  r.sigma_yaw_rad = sigma_yaw;
  return r;
}

TEST(NavDriftModel, SigmaGrowsWithTheDistanceTravelled) {
  NavDriftModel m(0.01, 0.001);
  m.advance({0, 0});
  m.advance({3, 4});
  m.advance({3, 0});
  EXPECT_DOUBLE_EQ(m.distance(), 9.0);
  EXPECT_DOUBLE_EQ(m.sigmaXy(), 0.09);
  EXPECT_DOUBLE_EQ(m.sigmaYaw(), 0.009);
  m.reset();
  m.advance({10, 10});
  EXPECT_DOUBLE_EQ(m.distance(), 0.0) << "no step from before the reset";
}

TEST(NavCovarianceCheck, AGrowingCovarianceIsUsedOnceItHasGrown) {
  NavCovarianceCheck c(0.01, 0.001);
  NavCovarianceCheck::Result r = c.add(at(0.0, 0.1, 0.01));
  EXPECT_EQ(r.xy, Verdict::kUndecided);
  EXPECT_DOUBLE_EQ(r.row.sigma_xy_m, 0.0) << "not grown yet: the drift model's, 0 m travelled";
  r = c.add(at(0.5, 0.105, 0.0101));
  EXPECT_EQ(r.xy, Verdict::kGrowing);
  EXPECT_EQ(r.yaw, Verdict::kGrowing);
  EXPECT_DOUBLE_EQ(r.row.sigma_xy_m, 0.105);
  EXPECT_DOUBLE_EQ(r.row.sigma_yaw_rad, 0.0101);
  EXPECT_FALSE(r.replaced);
  // Shrinking later (a position fix) is still the nav's own.
  r = c.add(at(10.0, 0.02, 0.005));
  EXPECT_EQ(r.xy, Verdict::kGrowing);
  EXPECT_DOUBLE_EQ(r.row.sigma_xy_m, 0.02);
  EXPECT_FALSE(r.replaced);
}

TEST(NavCovarianceCheck, AConstantCovarianceIsReplacedByTheDriftModelAfterTwoMetres) {
  NavCovarianceCheck c(0.01, 0.001);
  int decided = 0;
  std::vector<NavCovarianceCheck::Result> rs;
  for (int i = 0; i <= 40; ++i) {  // 0.1 m steps, sigma 0.3 m and 0.02 rad throughout
    rs.push_back(c.add(at(0.1 * i, 0.3, 0.02)));
    decided += rs.back().decided;
  }
  EXPECT_EQ(decided, 1) << "decided once";
  EXPECT_EQ(rs[19].xy, Verdict::kUndecided);  // 1.9 m
  EXPECT_FALSE(rs[19].replaced);
  EXPECT_EQ(rs[20].xy, Verdict::kNotGrowing);  // 2.0 m
  EXPECT_TRUE(rs[20].decided);
  EXPECT_TRUE(rs[40].replaced);
  EXPECT_NEAR(rs[40].row.sigma_xy_m, 0.01 * 4.0, 1e-12);
  EXPECT_NEAR(rs[40].row.sigma_yaw_rad, 0.001 * 4.0, 1e-12);
  EXPECT_NEAR(rs[10].row.sigma_xy_m, 0.01 * 1.0, 1e-12) << "the drift model's while undecided too";
}

TEST(NavCovarianceCheck, AZeroCovarianceIsZeroAndEachComponentIsJudgedAlone) {
  NavCovarianceCheck c(0.01, 0.001);
  NavCovarianceCheck::Result r;
  for (int i = 0; i <= 30; ++i) r = c.add(at(0.1 * i, 0.0, 0.001 * i));  // x-y zero, yaw growing
  EXPECT_EQ(r.xy, Verdict::kZero);
  EXPECT_EQ(r.yaw, Verdict::kGrowing);
  EXPECT_NEAR(r.row.sigma_xy_m, 0.03, 1e-12);
  EXPECT_DOUBLE_EQ(r.row.sigma_yaw_rad, 0.03);
  EXPECT_TRUE(r.replaced);
  c.reset();  // a new clock: judged again from the start
  r = c.add(at(100.0, 0.0, 0.0));
  EXPECT_EQ(r.xy, Verdict::kUndecided);
  EXPECT_DOUBLE_EQ(c.distance(), 0.0);
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
