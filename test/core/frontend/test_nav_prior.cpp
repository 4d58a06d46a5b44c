// nav.csv (reader errors, round trip), the nav track's interpolation at image stamps (yaw on the
// circle), the relative nav motion's covariance model, the chi-square gate and the fusion.
#include <gtest/gtest.h>
#include <tuple>

#include <Eigen/Cholesky>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>

#include "../../common/scoped_temp_dir.h"
#include "uw_multislam/core/backend/loop_consistency.h"
#include "uw_multislam/core/frontend/nav_prior.h"
#include "uw_multislam/core/session/slam_config.h"

namespace uw_multislam {
namespace core {
namespace {

namespace fs = std::filesystem;

class NavCsvTest : public ::testing::Test {
 protected:
  std::string write(const std::string& text) {
    const std::string p = (tmp_.path() / "nav.csv").string();
    std::ofstream(p) << text;
    return p;
  }
  void expectError(const std::string& text, const std::string& needle) {
    const std::string p = write(text);
    try {
      readNavCsv(p);
      FAIL() << "no error, expected one containing '" << needle << "'";
    } catch (const DatasetError& e) {
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(p), std::string::npos) << e.what();
    }
  }
  testing_util::ScopedTempDir tmp_{"uwms_nav"};
};

const char* kHeader = "stamp_s,x_m,y_m,yaw_rad,sigma_xy_m,sigma_yaw_rad\n";

TEST_F(NavCsvTest, RoundTrip) {
  const std::vector<NavRecord> rows = {{0.0, Pose2(0, 0, 0), 0.0, 0.0}, {1.5, Pose2(0.5, -0.25, 3.1), 0.01, 0.002}};
  const std::string p = (tmp_.path() / "nav.csv").string();
  writeNavCsv(p, rows);
  const std::vector<NavRecord> back = readNavCsv(p);
  ASSERT_EQ(back.size(), 2u);
  EXPECT_EQ(back[1].stamp_s, 1.5);
  EXPECT_TRUE(approxEqual(back[1].pose, rows[1].pose, 1e-6, 1e-6));
  EXPECT_NEAR(back[1].sigma_xy_m, 0.01, 1e-9);
  EXPECT_NEAR(back[1].sigma_yaw_rad, 0.002, 1e-9);
}

TEST_F(NavCsvTest, BadFilesAreRefusedWithTheLine) {
  expectError("stamp_s,x_m,y_m,yaw_rad\n0,0,0,0\n", "unexpected header");
  expectError(std::string(kHeader) + "0,0,0,0,0,0\n1,nan,0,0,0,0\n", ":3: x_m is not finite");
  expectError(std::string(kHeader) + "0,0,0,0,0,inf\n", "sigma_yaw_rad is not finite");
  expectError(std::string(kHeader) + "0,0,0,0,-1,0\n", "must be >= 0");
  expectError(std::string(kHeader) + "0,0,0,0,0,0\n2,0,0,0,0,0\n1,0,0,0,0,0\n", ":4: stamp 1 is not after");
  expectError(std::string(kHeader) + "0,0,0,0,0,0\n0,0,0,0,0,0\n", "stamps must increase");
  expectError(std::string(kHeader) + "0,0,zero,0,0,0\n", "bad number in y_m");
  expectError(std::string(kHeader), "no rows");
  expectError(std::string(kHeader) + "0,0,0,0,0\n", "expected 6 columns");
}

TEST_F(NavCsvTest, DatasetReadsItWhenPresent) {
  const fs::path d = tmp_.path() / "set";
  fs::create_directories(d);
  writeCameraYaml((d / "camera.yaml").string(), CameraIntrinsics{320, 240, 300.0, 300.0, 160.0, 120.0});
  writeFramesCsv((d / "frames.csv").string(), {{0, "0000.jpg", 0.0, 2.5}});
  std::ofstream(d / "0000.jpg") << "x";
  EXPECT_TRUE(loadDataset(d.string()).nav.empty());
  std::ofstream(d / "nav.csv") << kHeader << "0,1,2,0.5,0,0\n";
  const Dataset ds = loadDataset(d.string());
  ASSERT_EQ(ds.nav.size(), 1u);
  EXPECT_EQ(ds.nav[0].pose.y(), 2.0);
  std::ofstream(d / "nav.csv") << kHeader << "0,1,2,0.5,0,0\n0,1,2,0.5,0,0\n";
  EXPECT_THROW(loadDataset(d.string()), DatasetError);
}

TEST(NavTrack, InterpolatesLinearlyAndYawAlongTheShorterArc) {
  // Yaw crosses +-pi between the rows: the naive average of 3.0 and -3.0 would be 0.
  const NavTrack track({{10.0, Pose2(0, 0, 3.0), 0.0, 0.0}, {12.0, Pose2(2, -4, -3.0), 0.02, 0.004}});
  NavRecord r;
  ASSERT_TRUE(track.at(11.0, &r));
  EXPECT_NEAR(r.pose.x(), 1.0, 1e-12);
  EXPECT_NEAR(r.pose.y(), -2.0, 1e-12);
  EXPECT_NEAR(std::abs(r.pose.yaw()), M_PI, 1e-12);  // 3.0 + (2pi - 6)/2 = pi
  EXPECT_NEAR(r.sigma_xy_m, 0.01, 1e-12);
  ASSERT_TRUE(track.at(11.5, &r));
  EXPECT_NEAR(r.pose.yaw(), normalizeAngle(3.0 + 0.75 * (2 * M_PI - 6.0)), 1e-12);
  ASSERT_TRUE(track.at(12.0, &r));  // a row's stamp: the row itself
  EXPECT_EQ(r.pose.yaw(), -3.0);
  EXPECT_FALSE(track.at(9.99, &r));  // no extrapolation
  EXPECT_FALSE(track.at(12.01, &r));
  EXPECT_FALSE(track.at(std::nan(""), &r));
  EXPECT_THROW(NavTrack({{1.0, Pose2(), 0, 0}, {1.0, Pose2(), 0, 0}}), std::invalid_argument);
}

TEST(NavTrack, ALiveTrackRefusesBadRowsAndForgetsOldOnes) {
  NavTrack live;
  std::string why;
  EXPECT_TRUE(live.append({1.0, Pose2(0, 0, 0), 0.0, 0.0}, &why)) << why;
  EXPECT_TRUE(live.append({2.0, Pose2(1, 0, 0), 0.01, 0.001}));
  EXPECT_FALSE(live.append({2.0, Pose2(5, 5, 0), 0.01, 0.001}, &why)) << "a repeated stamp";
  EXPECT_NE(why.find("not after"), std::string::npos) << why;
  EXPECT_FALSE(live.append({1.5, Pose2(5, 5, 0), 0.01, 0.001}, &why)) << "out of order";
  EXPECT_FALSE(live.append({3.0, Pose2(std::nan(""), 0, 0), 0.01, 0.001}, &why)) << "NaN";
  EXPECT_NE(why.find("not finite"), std::string::npos) << why;
  EXPECT_FALSE(live.append({3.0, Pose2(2, 0, 0), -0.01, 0.001}, &why)) << "a negative sigma";
  EXPECT_EQ(live.rows().size(), 2u) << "refused rows change nothing";
  EXPECT_TRUE(live.append({3.0, Pose2(2, 0, 0), 0.02, 0.002}));
  EXPECT_TRUE(live.append({4.0, Pose2(3, 0, 0), 0.03, 0.003}));
  NavRecord r;
  ASSERT_TRUE(live.at(2.5, &r));
  EXPECT_NEAR(r.pose.x(), 1.5, 1e-12);
  live.dropBefore(3.5);  // keeps the row at 3.0, the last one before 3.5
  ASSERT_EQ(live.rows().size(), 2u);
  EXPECT_EQ(live.rows().front().stamp_s, 3.0);
  ASSERT_TRUE(live.at(3.5, &r));
  EXPECT_NEAR(r.pose.x(), 2.5, 1e-12);
  EXPECT_FALSE(live.at(2.5, &r)) << "forgotten";
  live.dropBefore(0.0);
  EXPECT_EQ(live.rows().size(), 2u);
  // With a restart threshold: a little back is refused as before, far back starts a new track.
  EXPECT_FALSE(live.append({3.8, Pose2(0, 0, 0), 0.0, 0.0}, &why, 1.0));
  EXPECT_EQ(live.rows().size(), 2u);
  EXPECT_TRUE(live.append({0.5, Pose2(9, 9, 0), 0.0, 0.0}, &why, 1.0)) << why;
  EXPECT_NE(why.find("starts again"), std::string::npos) << why;
  ASSERT_EQ(live.rows().size(), 1u);
  EXPECT_FALSE(live.at(3.5, &r)) << "the old clock's rows are gone";
  EXPECT_TRUE(live.append({1.5, Pose2(10, 9, 0), 0.0, 0.0}, &why, 1.0));
  ASSERT_TRUE(live.at(1.0, &r));
  EXPECT_NEAR(r.pose.x(), 9.5, 1e-12);
}

TEST(NavTrack, AJumpBackOfTheImageClockDropsTheReadingsOfTheClockBefore) {
  // A bag of 30 s played twice: the first pass's readings cover the stamps the second pass's first
  // image has; its own reading has not arrived yet (the nav and the images travel apart).
  NavTrack live;
  for (int k = 0; k <= 30; ++k) ASSERT_TRUE(live.append({100.0 + k, Pose2(0.5 * k, 0, 0), 0.01 * k, 0.001}));
  NavRecord r;
  ASSERT_TRUE(live.at(100.0, &r)) << "the first pass's reading at the replayed stamp";
  EXPECT_EQ(live.dropClockBefore(100.0, 1.0), 31u);
  EXPECT_TRUE(live.empty());
  EXPECT_FALSE(live.at(100.0, &r)) << "the new session waits for its own clock's readings";
  // A track the nav already restarted (its first reading of the new pass came first) is kept.
  ASSERT_TRUE(live.append({100.0, Pose2(0, 0, 0), 0.0, 0.0}));
  ASSERT_TRUE(live.append({101.0, Pose2(0.5, 0, 0), 0.01, 0.001}));
  EXPECT_EQ(live.dropClockBefore(100.5, 1.0), 0u);
  EXPECT_EQ(live.rows().size(), 2u);
  EXPECT_EQ(NavTrack().dropClockBefore(0.0, 1.0), 0u);
}

TEST(NavPrior, MotionCovarianceIsTheInflatedGrowthOfSigmaWithFloors) {
  NavPriorOptions o;
  o.inflation = 3.0;
  o.min_sigma_m = 0.001;
  o.min_sigma_rad = 0.002;
  const NavRecord a{0.0, Pose2(1, 1, M_PI / 2), 0.10, 0.010};
  const NavRecord b{1.0, Pose2(1, 2, M_PI / 2), 0.11, 0.010};
  const UncertainPose2 m = navMotion(a, b, o);
  EXPECT_TRUE(approxEqual(m.mean, Pose2(1, 0, 0), 1e-12, 1e-12));  // 1 m ahead in a's frame
  EXPECT_NEAR(m.covariance(0, 0), std::pow(3.0 * 0.01, 2), 1e-12);
  EXPECT_NEAR(m.covariance(1, 1), std::pow(3.0 * 0.01, 2), 1e-12);
  EXPECT_NEAR(m.covariance(2, 2), std::pow(0.002, 2), 1e-15);  // sigma_yaw did not grow: the floor
  EXPECT_EQ(m.covariance(0, 1), 0.0);
  NavPriorOptions bad = o;
  bad.inflation = 0.5;
  EXPECT_NE(bad.validate().find("inflation"), std::string::npos);
  bad = o;
  bad.gate_confidence = 1.0;
  EXPECT_NE(bad.validate().find("gate_confidence"), std::string::npos);
  // In the SLAM configuration the block is `nav`, and an error names it so.
  try {
    slamConfigFromYaml("nav: {inflation: 0.5}\n");
    ADD_FAILURE() << "no error";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("nav.inflation"), std::string::npos) << e.what();
  }
  const SlamConfig c = slamConfigFromYaml("nav: {on_tracking_loss: new_session, gate_ransac: false}\n");
  EXPECT_EQ(c.odometry.nav.on_tracking_loss, TrackingLossPolicy::kNewSession);
  EXPECT_FALSE(c.odometry.nav.gate_ransac);
  EXPECT_EQ(slamConfigToYaml(slamConfigFromYaml(slamConfigToYaml(c))), slamConfigToYaml(c));
  EXPECT_THROW(slamConfigFromYaml("nav: {on_tracking_loss: pray}\n"), std::invalid_argument);
  // A block or key written twice (two configurations pasted together): yaml-cpp would read the
  // first and drop the second without a word; refused with its path and line.
  for (const auto& [text, path, line] : std::vector<std::tuple<std::string, std::string, int>>{
           {"nav:\n  fuse: true\nbackend:\n  optimizer: iekf\nnav:\n  fuse: false\n", "nav", 5},
           {"nav:\n  fuse: true\n  inflation: 3\n  fuse: false\n", "nav.fuse", 4}}) {
    try {
      slamConfigFromYaml(text);
      ADD_FAILURE() << "accepted: " << text;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find("line " + std::to_string(line) + ": key '" + path + "' appears twice"),
                std::string::npos)
          << e.what();
    }
  }
  EXPECT_NO_THROW(slamConfigFromYaml("nav:\n  fuse: true\nbackend:\n  optimizer: iekf\n"));  // same keys, other maps
  // An alias that refers to itself (each node is walked once: no endless recursion) and a shared one.
  EXPECT_THROW(slamConfigFromYaml("x: &a [*a]\n"), std::invalid_argument);  // unknown key x, not a crash
  EXPECT_NO_THROW(slamConfigFromYaml("nav: &n {fuse: true}\n"));
}

TEST(NavPrior, AStepFasterThanTheVehicleIsAGlitchNotAMotion) {
  NavPriorOptions o;  // max_speed_m_s 10, inflation 2, floor 5 mm
  const NavRecord a{0.0, Pose2(0, 0, 0), 0.10, 0.01};
  // 2 s apart, sigma growing by 0.05 m: sigma of the step 0.1 m, allowed 20 + 3 sqrt(2) 0.1 m.
  const double allowed = 20.0 + 3.0 * std::sqrt(2.0) * 0.1;
  EXPECT_EQ(navStepImplausible(a, NavRecord{2.0, Pose2(allowed * 0.6, allowed * 0.8 - 1e-6, 0), 0.15, 0.01}, o), "");
  const std::string why =
      navStepImplausible(a, NavRecord{2.0, Pose2(allowed * 0.6, allowed * 0.8 + 1e-3, 0), 0.15, 0.01}, o);
  EXPECT_NE(why.find("nav step of 20.4 m in 2 s"), std::string::npos) << why;
  EXPECT_EQ(navStepImplausible(NavRecord{2.0, Pose2(0, 0, 0), 0.1, 0.01}, NavRecord{0.0, Pose2(5, 0, 0), 0.1, 0.01}, o),
            "");  // order of the two does not matter
  EXPECT_NE(navStepImplausible(a, NavRecord{2.0, Pose2(1e300, 0, 0), 0.15, 0.01}, o), "");
  // The heading: max_yaw_rate_rad_s 1 over 2 s, sigma_yaw not growing: the floor, 5 mrad, and
  // two readings' noise of 2 degrees each.
  const double noise = 2.0 * M_PI / 180.0;
  const double turn = 2.0 + 3.0 * std::sqrt(0.005 * 0.005 + 2.0 * noise * noise);
  EXPECT_EQ(navStepImplausible(a, NavRecord{2.0, Pose2(1, 0, turn - 1e-6), 0.15, 0.01}, o), "");
  const std::string spin = navStepImplausible(a, NavRecord{2.0, Pose2(1, 0, turn + 1e-3), 0.15, 0.01}, o);
  EXPECT_NE(spin.find("nav turn of 2.15 rad in 2 s"), std::string::npos) << spin;
  EXPECT_EQ(navStepImplausible(a, NavRecord{2.0, Pose2(1, 0, -turn + 1e-6), 0.15, 0.01}, o), "");  // either way
  o.max_speed_m_s = 0.0;
  EXPECT_NE(o.validate().find("max_speed_m_s"), std::string::npos);
  o.max_speed_m_s = 10.0;
  o.max_yaw_rate_rad_s = -1.0;
  EXPECT_NE(o.validate().find("max_yaw_rate_rad_s"), std::string::npos);
}

TEST(NavPrior, GateThresholdHoldsItsConfidenceUnderTheModel) {
  // Monte-Carlo: visual and nav drawn around one true motion with their covariances; the fraction
  // passing the gate must be the gate's confidence (an independent check of distance and quantile).
  NavPriorOptions o;
  o.gate_confidence = 0.95;
  const double threshold = navGateThreshold(o);
  EXPECT_NEAR(threshold, 7.8147, 1e-3);  // chi-square 3 dof, 95 % (tables)
  const Pose2 truth(0.4, -0.1, 0.05);
  Eigen::Matrix3d cv, cn;
  cv << 4e-6, 1e-6, 0, 1e-6, 9e-6, 2e-7, 0, 2e-7, 1e-6;
  cn = Eigen::Vector3d(1e-4, 1e-4, 4e-5).asDiagonal();
  const Eigen::Matrix3d lv = cv.llt().matrixL(), ln = cn.llt().matrixL();
  std::mt19937 rng(3);
  std::normal_distribution<double> g;
  int pass = 0;
  const int n = 20000;
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector3d ev = lv * Eigen::Vector3d(g(rng), g(rng), g(rng));
    const Eigen::Vector3d en = ln * Eigen::Vector3d(g(rng), g(rng), g(rng));
    const UncertainPose2 v(Pose2::fromVector(truth.vector() + ev), cv), nav(Pose2::fromVector(truth.vector() + en), cn);
    if (navGateDistance2(v, nav) <= threshold) ++pass;
  }
  EXPECT_NEAR(pass / static_cast<double>(n), 0.95, 0.006);  // 4 sigma of a binomial at n = 20000
  // A visual motion 10 cm off a nav of 1 cm sigma fails.
  EXPECT_GT(navGateDistance2(UncertainPose2(Pose2(0.5, -0.1, 0.05), cv), UncertainPose2(truth, cn)), threshold);
}

TEST(NavPrior, FusionIsTheInformationWeightedMean) {
  const UncertainPose2 v(Pose2(1.0, 0.0, 0.1), Eigen::Vector3d(1e-4, 4e-4, 1e-4).asDiagonal());
  const UncertainPose2 n(Pose2(1.3, 0.2, 0.4), Eigen::Vector3d(3e-4, 4e-4, 1e-4).asDiagonal());
  const UncertainPose2 f = fuseMotions(v, n);
  // Diagonal covariances: per component (x_v / s_v + x_n / s_n) / (1 / s_v + 1 / s_n).
  EXPECT_NEAR(f.mean.x(), (1.0 / 1e-4 + 1.3 / 3e-4) / (1 / 1e-4 + 1 / 3e-4), 1e-12);
  EXPECT_NEAR(f.mean.y(), 0.1, 1e-12);
  EXPECT_NEAR(f.mean.yaw(), 0.25, 1e-12);
  EXPECT_NEAR(f.covariance(0, 0), 1.0 / (1 / 1e-4 + 1 / 3e-4), 1e-15);
  EXPECT_NEAR(f.covariance(1, 1), 2e-4, 1e-15);
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
