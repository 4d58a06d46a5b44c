// The survey generator: geometry of the rendering against the ground truth, missions, water,
// reproducibility, ground-truth loops and the YAML spec.
#include <gtest/gtest.h>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <filesystem>
#include <fstream>
#include <sstream>

#include "../../common/scoped_temp_dir.h"
#include "uw_multislam/core/frontend/camera_model.h"
#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/geometry/vehicle_frame.h"
#include "uw_multislam/sim/survey_config.h"
#include "uw_multislam/sim/survey_generator.h"

namespace uw_multislam {
namespace core {
namespace {

namespace fs = std::filesystem;

const CameraIntrinsics kCam{160, 120, 150.0, 160.0, 79.5, 59.5};

// A dark world with one bright dot at a known world point.
SeabedWorld dotWorld(const Eigen::Vector2d& dot_m, double mpp = 0.005) {
  cv::Mat img(1200, 1600, CV_8UC3, cv::Scalar(20, 20, 20));
  const SeabedWorld probe(img, mpp, Eigen::Vector2d(100.0, 150.0));
  const Eigen::Vector2d px = probe.worldToPixel(dot_m);
  cv::circle(img, cv::Point(cvRound(px.x() * 16), cvRound(px.y() * 16)), 3 * 16, cv::Scalar(255, 255, 255), cv::FILLED,
             cv::LINE_AA, 4);
  return SeabedWorld(img, mpp, Eigen::Vector2d(100.0, 150.0));
}

// Intensity-weighted centroid of the bright pixels.
Eigen::Vector2d brightCentroid(const cv::Mat& bgr) {
  cv::Mat g;
  cv::cvtColor(bgr, g, cv::COLOR_BGR2GRAY);
  g.convertTo(g, CV_64F);
  g -= 20.0;
  cv::threshold(g, g, 0.0, 0.0, cv::THRESH_TOZERO);
  const cv::Moments m = cv::moments(g);
  return Eigen::Vector2d(m.m10 / m.m00, m.m01 / m.m00);
}

// Where the camera at `pose` (altitude a) sees world point w: p_c = R^T (w - t), then pinhole.
Eigen::Vector2d project(const Pose2& pose, double a, const Eigen::Vector2d& w) {
  const Eigen::Vector2d pc = pose.rotation().transpose() * (w - pose.translation());
  return Eigen::Vector2d(kCam.cx + kCam.fx * pc.x() / a, kCam.cy + kCam.fy * pc.y() / a);
}

TEST(SeabedWorld, KnownWorldPointLandsWhereTheGroundTruthPredicts) {
  const Eigen::Vector2d dot(1.3, 0.4);
  const SeabedWorld world = dotWorld(dot);
  for (const Pose2& pose : {Pose2(1.2, 0.5, 0.0), Pose2(1.0, 0.3, 0.8), Pose2(1.5, 0.6, -2.5), Pose2(1.4, 0.2, M_PI)}) {
    for (double a : {1.5, 2.5}) {
      const cv::Mat view = world.render(pose, a, kCam);
      const Eigen::Vector2d seen = brightCentroid(view), predicted = project(pose, a, dot);
      EXPECT_LT((seen - predicted).norm(), 0.3) << "pose " << pose << " altitude " << a << ": seen " << seen.transpose()
                                                << " predicted " << predicted.transpose();
    }
  }
}

TEST(SeabedWorld, PixelWorldRoundTripAndValidity) {
  const SeabedWorld world = dotWorld(Eigen::Vector2d(1, 1));
  const Eigen::Vector2d w(2.0, -0.3);
  EXPECT_TRUE(world.pixelToWorld(world.worldToPixel(w)).isApprox(w));
  EXPECT_TRUE(world.viewIsValid(Pose2(1.0, 1.0, 0.3), 2.0, kCam));
  EXPECT_FALSE(world.viewIsValid(Pose2(-0.4, 1.0, 0.3), 2.0, kCam));  // left edge of the raster
}

TEST(SeabedWorld, MosaicBlackAreasNeverEnterAFrame) {
  const testing_util::ScopedTempDir tmp("uwms_mosaic");
  const fs::path& dir = tmp.path();
  cv::Mat img(800, 800, CV_8UC3, cv::Scalar(0, 0, 0));
  cv::Mat inner = img(cv::Rect(100, 100, 600, 600));
  cv::randu(inner, cv::Scalar::all(40), cv::Scalar::all(220));
  cv::imwrite((dir / "m.png").string(), img);
  std::ofstream(dir / "m.txt") << "m_per_px 0.005\norigin_px 100 100\n";
  const SeabedWorld world = SeabedWorld::fromMosaic((dir / "m.png").string(), (dir / "m.txt").string());
  // Imaged area: world [0, 3] m in x and y. Footprint at 1 m: 1.07 x 0.75 m.
  EXPECT_TRUE(world.viewIsValid(Pose2(1.5, 1.5, 0.4), 1.0, kCam));
  EXPECT_FALSE(world.viewIsValid(Pose2(0.3, 1.5, 0.0), 1.0, kCam));
  EXPECT_FALSE(world.viewIsValid(Pose2(1.5, 2.9, 1.0), 1.0, kCam));
  const cv::Mat view = world.render(Pose2(1.5, 1.5, 0.4), 1.0, kCam);
  double lo = 0;
  cv::minMaxLoc(view.reshape(1), &lo);
  EXPECT_GT(lo, 10.0);

  SurveySpec spec;
  spec.sessions.resize(1);
  spec.sessions[0].camera = kCam;
  spec.sessions[0].mission.pattern = MissionPattern::kOutAndBack;
  spec.sessions[0].mission.start_m = Eigen::Vector2d(0.8, 1.0);
  spec.sessions[0].mission.length_m = 5.0;  // runs off the 3 m mosaic
  spec.sessions[0].mission.altitude_m = 1.0;
  try {
    planSurvey(spec, world);
    FAIL() << "a mission leaving the mosaic was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("leaves the seabed"), std::string::npos) << e.what();
  }
  spec.sessions[0].mission.length_m = 1.2;
  spec.sessions[0].mission.leg_spacing_m = 0.3;
  EXPECT_NO_THROW(planSurvey(spec, world));
}

TEST(Mission, FramesAreEvenlySpacedAlongThePath) {
  for (auto pattern :
       {MissionPattern::kLawnmower, MissionPattern::kOutAndBack, MissionPattern::kLoop, MissionPattern::kFigureEight}) {
    MissionSpec m;
    m.pattern = pattern;
    m.speed_m_s = 0.4;
    m.frame_period_s = 0.5;
    m.heading_rad = 0.7;
    const auto frames = planMission(m);
    ASSERT_GT(frames.size(), 20u) << patternName(pattern);
    EXPECT_TRUE(approxEqual(Pose2(frames[0].pose.x(), frames[0].pose.y(), 0), Pose2(4.0, 4.0, 0), 1e-9));
    for (std::size_t k = 1; k < frames.size(); ++k) {
      const double d = (frames[k].pose.translation() - frames[k - 1].pose.translation()).norm();
      // Chords of a curved path are slightly shorter than the 0.2 m of path between frames.
      ASSERT_LE(d, 0.2 + 1e-6) << patternName(pattern) << " frame " << k;
      ASSERT_GT(d, 0.17) << patternName(pattern) << " frame " << k;
      ASSERT_NEAR(frames[k].stamp_s - frames[k - 1].stamp_s, 0.5, 1e-9);
    }
    // The initial direction of travel is the heading.
    const Eigen::Vector2d d0 = frames[1].pose.translation() - frames[0].pose.translation();
    EXPECT_NEAR(normalizeAngle(std::atan2(d0.y(), d0.x()) - 0.7), 0.0, 0.05) << patternName(pattern);
  }
}

TEST(Mission, LoopsComeBackAndOutAndBackReturns) {
  MissionSpec m;
  m.pattern = MissionPattern::kLoop;
  m.laps = 1.0;
  auto f = planMission(m);
  EXPECT_LT((f.back().pose.translation() - f.front().pose.translation()).norm(), 0.5);
  m.pattern = MissionPattern::kOutAndBack;
  m.leg_spacing_m = 0.8;
  f = planMission(m);
  EXPECT_NEAR((f.back().pose.translation() - f.front().pose.translation()).norm(), 0.8, 0.5);
  m.pattern = MissionPattern::kLawnmower;
  m.length_m = 10;
  m.width_m = 4.2;
  m.leg_spacing_m = 1.4;
  m.wobble_yaw_rad = 0;
  f = planMission(m);
  // Four legs: the last one runs back towards x = start, 4.2 m across.
  EXPECT_NEAR(f.back().pose.y() - f.front().pose.y(), 4.2, 0.25);
  EXPECT_NEAR(std::abs(normalizeAngle(f.back().pose.yaw())), M_PI, 0.05);
  m.altitude_amplitude_m = 3.0;  // more than the altitude
  EXPECT_THROW(planMission(m), std::invalid_argument);
}

cv::Scalar stddev(const cv::Mat& img) {
  cv::Scalar mean, sd;
  cv::meanStdDev(img, mean, sd);
  return sd;
}

TEST(Water, TurbidityLowersContrastAndBlankFramesAreFeatureless) {
  ProceduralSeabedOptions o;
  o.width_m = 6;
  o.height_m = 5;
  o.featureless_fraction = 0;
  const SeabedWorld world = SeabedWorld::procedural(o);
  const cv::Mat clean = world.render(Pose2(3, 2.5, 0.2), 2.0, kCam);
  WaterFrame f;
  f.altitude_m = 2.0;
  WaterOptions clear;
  clear.noise_sigma = 0;
  WaterOptions murky = clear;
  murky.turbidity_per_m = 0.3;
  cv::RNG r1(1), r2(1), r3(1);
  const double sd_clear = stddev(applyWater(clean, clear, f, r1))[1];
  const double sd_murky = stddev(applyWater(clean, murky, f, r2))[1];
  EXPECT_LT(sd_murky, 0.6 * sd_clear);
  WaterOptions blank = clear;
  blank.vignetting = 0;
  blank.stretches = {{0, 3, FrameStretch::Kind::kBlank}};
  EXPECT_LT(stddev(applyWater(clean, blank, f, r3))[1], 1.0);
  f.index = 3;  // first frame after the stretch
  EXPECT_GT(stddev(applyWater(clean, blank, f, r3))[1], 0.5 * sd_clear);
}

TEST(Water, MarineSnowAddsBrightSpots) {
  const cv::Mat grey(120, 160, CV_8UC3, cv::Scalar(60, 60, 60));
  WaterOptions o;
  o.noise_sigma = 0;
  o.vignetting = 0;
  o.turbidity_per_m = 0;
  o.marine_snow_per_frame = 50;
  WaterFrame f;
  cv::RNG rng(3);
  cv::Mat out = applyWater(grey, o, f, rng);
  cv::Mat g;
  cv::cvtColor(out, g, cv::COLOR_BGR2GRAY);
  EXPECT_GT(cv::countNonZero(g > 120), 20);
}

class SurveyTest : public ::testing::Test {
 protected:
  void SetUp() override {
    spec_.world.procedural.width_m = 10;
    spec_.world.procedural.height_m = 7;
    SessionSpec a;
    a.name = "a";
    a.camera = kCam;
    a.mission.pattern = MissionPattern::kOutAndBack;
    a.mission.start_m = Eigen::Vector2d(2.0, 2.5);
    a.mission.length_m = 4.0;
    a.mission.leg_spacing_m = 0.6;
    a.mission.altitude_m = 1.5;
    a.image_format = "png";
    SessionSpec b = a;
    b.name = "b";
    b.mission.pattern = MissionPattern::kLoop;
    b.mission.start_m = Eigen::Vector2d(5.0, 3.0);
    b.mission.heading_rad = M_PI / 2;
    b.mission.length_m = 3.0;
    b.mission.width_m = 2.0;
    b.water.illumination = 0.7;
    spec_.sessions = {a, b};
  }
  testing_util::ScopedTempDir tmp_{"uwms_survey"};
  const fs::path out_ = tmp_.path() / "out";
  SurveySpec spec_;
};

TEST_F(SurveyTest, WritesDatasetFoldersConsistentWithWorldGroundTruth) {
  const SurveyResult r = generateSurvey(spec_, out_.string());
  ASSERT_EQ(r.session_dirs.size(), 2u);
  std::map<std::pair<int, int>, Pose2> world;
  for (const auto& p : r.world_poses) world[{p.session, p.index}] = p.pose;
  for (int s = 0; s < 2; ++s) {
    const Dataset d = loadDataset(r.session_dirs[s]);
    EXPECT_EQ(d.camera.fy, kCam.fy);
    ASSERT_EQ(d.frames.size(), d.ground_truth.size());
    EXPECT_TRUE(approxEqual(d.ground_truth[0].pose, Pose2::identity(), 1e-6, 1e-6));
    for (const auto& g : d.ground_truth) {
      // gt.csv is the world pose seen from the session's first frame.
      const Pose2 expected = between(world[{s, 0}], world[{s, g.index}]);
      ASSERT_TRUE(approxEqual(g.pose, expected, 2e-6, 2e-6)) << "session " << s << " frame " << g.index;
    }
    for (const auto& f : d.frames) EXPECT_NEAR(f.altitude_m, 1.5, 0.06);  // altimeter noise 1 cm
    const cv::Mat img = cv::imread(d.imagePath(d.frames[0]));
    EXPECT_EQ(img.cols, kCam.width);
    EXPECT_EQ(img.rows, kCam.height);
  }
  // world_gt.csv holds every frame.
  std::ifstream wg(out_ / "world_gt.csv");
  std::string line;
  int rows = -1;
  while (std::getline(wg, line)) ++rows;
  EXPECT_EQ(rows, r.frames);
}

TEST_F(SurveyTest, ConsecutiveFramesMatchTheirGroundTruthMotion) {
  // Independent check of the rendering: warp frame k+1 into frame k with the ground-truth
  // motion; the overlapping pixels must agree far better than with a wrong motion.
  spec_.sessions.resize(1);
  spec_.sessions[0].water.noise_sigma = 0;
  spec_.sessions[0].water.vignetting = 0;
  const SurveyResult r = generateSurvey(spec_, out_.string());
  const Dataset d = loadDataset(r.session_dirs[0]);
  auto residual = [&](int k, const Pose2& motion) {
    const cv::Mat a = cv::imread(d.imagePath(d.frames[k]), cv::IMREAD_GRAYSCALE);
    const cv::Mat b = cv::imread(d.imagePath(d.frames[k + 1]), cv::IMREAD_GRAYSCALE);
    // Pixel of a -> metres in a -> metres in b -> pixel of b.
    const double ax = d.frames[k].altitude_m, bx = d.frames[k + 1].altitude_m;
    (void)ax;
    (void)bx;
    cv::Mat map_x(a.size(), CV_32F), map_y(a.size(), CV_32F);
    const double alt = 1.5;
    for (int v = 0; v < a.rows; ++v) {
      for (int u = 0; u < a.cols; ++u) {
        const Eigen::Vector2d pa((u - kCam.cx) * alt / kCam.fx, (v - kCam.cy) * alt / kCam.fy);
        const Eigen::Vector2d pb = invert(motion).rotation() * pa + invert(motion).translation();
        map_x.at<float>(v, u) = static_cast<float>(kCam.cx + pb.x() * kCam.fx / alt);
        map_y.at<float>(v, u) = static_cast<float>(kCam.cy + pb.y() * kCam.fy / alt);
      }
    }
    cv::Mat warped, mask;
    cv::remap(b, warped, map_x, map_y, cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar(0));
    cv::remap(cv::Mat(b.size(), CV_8U, cv::Scalar(255)), mask, map_x, map_y, cv::INTER_NEAREST, cv::BORDER_CONSTANT,
              cv::Scalar(0));
    cv::Mat diff;
    cv::absdiff(a, warped, diff);
    return cv::mean(diff, mask)[0];
  };
  for (int k : {0, 5, 9}) {
    const Pose2 motion = between(d.ground_truth[k].pose, d.ground_truth[k + 1].pose);
    const double good = residual(k, motion);
    const double bad = residual(k, compose(motion, Pose2(0.02, 0.0, 0.0)));  // 2 cm off
    EXPECT_LT(good, 0.6 * bad) << "frame " << k << ": residual " << good << " vs " << bad;
  }
}

TEST_F(SurveyTest, ADistortedLensSeesThePinholeViewWhereItsModelSays) {
  // The same session through a pinhole and through a lens with radial distortion: each raw pixel
  // of the distorted image shows what the pinhole image shows at its undistorted position.
  spec_.sessions.resize(1);
  spec_.sessions[0].water.noise_sigma = 0;
  spec_.sessions[0].water.vignetting = 0;
  spec_.sessions[0].mission.length_m = 1.0;
  const Dataset pinhole = loadDataset(generateSurvey(spec_, (out_ / "pinhole").string()).session_dirs[0]);
  spec_.sessions[0].camera.distortion_model = DistortionModel::kPlumbBob;
  spec_.sessions[0].camera.distortion = {-0.3, 0.1, 0.0, 0.0, 0.0};
  const Dataset lens = loadDataset(generateSurvey(spec_, (out_ / "lens").string()).session_dirs[0]);
  EXPECT_EQ(lens.camera, spec_.sessions[0].camera) << "camera.yaml carries D";
  EXPECT_EQ(pinhole.camera, kCam);
  const cv::Mat a = cv::imread(pinhole.imagePath(pinhole.frames[0]), cv::IMREAD_GRAYSCALE);
  const cv::Mat b = cv::imread(lens.imagePath(lens.frames[0]), cv::IMREAD_GRAYSCALE);
  std::vector<cv::Point2f> raw;
  for (int v = 0; v < b.rows; ++v)
    for (int u = 0; u < b.cols; ++u) raw.emplace_back(static_cast<float>(u), static_cast<float>(v));
  const std::vector<cv::Point2f> ideal = undistortPixels(raw, lens.camera);
  cv::Mat map_x(b.size(), CV_32F), map_y(b.size(), CV_32F), inside(b.size(), CV_8U);
  for (std::size_t i = 0; i < raw.size(); ++i) {
    const int u = static_cast<int>(raw[i].x), v = static_cast<int>(raw[i].y);
    map_x.at<float>(v, u) = ideal[i].x;
    map_y.at<float>(v, u) = ideal[i].y;
    inside.at<std::uint8_t>(v, u) =
        ideal[i].x >= 1 && ideal[i].y >= 1 && ideal[i].x <= a.cols - 2 && ideal[i].y <= a.rows - 2 ? 255 : 0;
  }
  cv::Mat through, diff_model, diff_none;
  cv::remap(a, through, map_x, map_y, cv::INTER_LINEAR);
  cv::absdiff(b, through, diff_model);
  cv::absdiff(b, a, diff_none);
  const double with_model = cv::mean(diff_model, inside)[0], without = cv::mean(diff_none, inside)[0];
  EXPECT_LT(with_model, 0.35 * without) << with_model << " vs " << without;
  EXPECT_GT(cv::countNonZero(inside), b.total() / 2);
}

TEST_F(SurveyTest, SameSeedSameOutputOtherSeedOtherWorld) {
  spec_.sessions.resize(1);
  generateSurvey(spec_, (out_ / "one").string());
  generateSurvey(spec_, (out_ / "two").string());
  spec_.seed = 2;
  generateSurvey(spec_, (out_ / "three").string());
  auto read = [&](const char* run, const char* file) {
    std::ifstream in(out_ / run / "a" / file, std::ios::binary);
    std::stringstream ss;
    ss << in.rdbuf();
    return ss.str();
  };
  EXPECT_EQ(read("one", "0003.png"), read("two", "0003.png"));
  EXPECT_EQ(read("one", "frames.csv"), read("two", "frames.csv"));
  EXPECT_NE(read("one", "0003.png"), read("three", "0003.png"));
  EXPECT_EQ(read("one", "gt.csv"), read("three", "gt.csv"));  // same mission, other world
}

TEST_F(SurveyTest, GroundTruthLoopsAreExactlyTheClosePairs) {
  const SeabedWorld world = buildWorld(spec_);
  const auto plans = planSurvey(spec_, world);
  std::vector<WorldPose> poses;
  for (int s = 0; s < 2; ++s) {
    for (std::size_t k = 0; k < plans[s].size(); ++k) {
      poses.push_back({s, static_cast<int>(k), plans[s][k].pose, plans[s][k].altitude_m});
    }
  }
  const auto loops = groundTruthLoops(spec_, poses);
  const double limit = 0.4 * kCam.height * 1.5 / kCam.fy;  // 0.45 m
  std::set<std::tuple<int, int, int, int>> listed;
  for (const auto& l : loops) listed.insert({l.session_a, l.index_a, l.session_b, l.index_b});
  int expected = 0, inter = 0;
  for (std::size_t i = 0; i < poses.size(); ++i) {
    for (std::size_t j = i + 1; j < poses.size(); ++j) {
      const bool neighbours = poses[i].session == poses[j].session && std::abs(poses[i].index - poses[j].index) < 3;
      const bool close = (poses[i].pose.translation() - poses[j].pose.translation()).norm() < limit;
      const bool in = listed.count({poses[i].session, poses[i].index, poses[j].session, poses[j].index}) > 0;
      EXPECT_EQ(in, close && !neighbours);
      expected += close && !neighbours;
      inter += close && !neighbours && poses[i].session != poses[j].session;
    }
  }
  EXPECT_EQ(static_cast<int>(loops.size()), expected);
  EXPECT_GT(expected, 10);  // the out-and-back passes over itself, the loop closes
  EXPECT_GT(inter, 0);      // and the two sessions overlap
}

TEST(SurveyConfig, YamlRoundTripAndClearErrors) {
  const SurveySpec demo = surveyPreset("demo");
  const std::string yaml = surveyToYaml(demo);
  const SurveySpec back = surveyFromYaml(yaml);
  EXPECT_EQ(surveyToYaml(back), yaml);
  ASSERT_EQ(back.sessions.size(), 2u);
  EXPECT_EQ(back.sessions[1].mission.pattern, MissionPattern::kLoop);
  EXPECT_DOUBLE_EQ(back.sessions[1].water.illumination, 0.7);

  const SurveySpec overridden = surveyFromYaml("preset: demo\nseed: 7\nworld: {width_m: 30}\n");
  EXPECT_EQ(overridden.seed, 7u);
  EXPECT_DOUBLE_EQ(overridden.world.procedural.width_m, 30.0);
  EXPECT_EQ(overridden.sessions.size(), 2u);

  auto error = [](const std::string& text) {
    try {
      surveyFromYaml(text);
    } catch (const std::invalid_argument& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_NE(error("sesions: []\n").find("unknown key 'sesions'"), std::string::npos);
  EXPECT_NE(error("sessions: [{mission: {pattern: spiral}}]\n").find("unknown pattern 'spiral'"), std::string::npos);
  EXPECT_NE(error("sessions: [{mission: {speed_m_s: -1}}]\n").find("speed_m_s"), std::string::npos);
  EXPECT_NE(error("sessions: [{water: {turbidity_per_m: abc}}]\n").find("turbidity_per_m"), std::string::npos);
  EXPECT_NE(error("sessions: [{name: a}, {name: a}]\n").find("duplicate"), std::string::npos);
  EXPECT_NE(error("preset: nope\n").find("unknown preset"), std::string::npos);
  EXPECT_NE(error("sessions: [{water: {stretches: [{first_frame: 2, num_frames: 3, kind: fog}]}}]\n").find("kind"),
            std::string::npos);
  for (const auto& p : surveyPresets()) EXPECT_EQ(surveyPreset(p).validate(), "") << p;
}

// A straight track along world direction 0.3 rad, the camera turned 0.7 rad from it: the nav's
// body-frame handling must not depend on either.
std::vector<MissionFrame> straightTrack(int frames, double step_m) {
  std::vector<MissionFrame> plan;
  const Eigen::Vector2d dir(std::cos(0.3), std::sin(0.3));
  for (int k = 0; k < frames; ++k) {
    const Eigen::Vector2d p = Eigen::Vector2d(3.0, 2.0) + k * step_m * dir;
    plan.push_back({Pose2(p.x(), p.y(), 1.0), 2.5, 10.0 + k, k * step_m, dir * step_m});
  }
  return plan;
}

TEST(NavErrorModel, SystematicDriftIsTheConfiguredFractionOfTheDistance) {
  // No random walk: the final error over the distance is |(1 + s) e^{ib} - 1| for every seed
  // (either sign), sqrt(s^2 + b^2) to first order; the yaw error is the bias.
  NavErrorSpec spec;
  spec.random_walk_m_per_sqrt_m = 0.0;
  spec.heading_random_walk_rad_per_sqrt_m = 0.0;
  const std::vector<MissionFrame> plan = straightTrack(41, 0.5);
  const double d = 20.0;
  const double s = spec.scale_error, b = spec.heading_bias_rad;
  const double exact = std::sqrt(s * s + 2 * (1 + s) * (1 - std::cos(b)));  // |(1+s)e^{ib} - 1|, s > 0
  const double exact_neg = std::sqrt(s * s + 2 * (1 - s) * (1 - std::cos(b)));  // s < 0
  for (std::uint64_t seed = 1; seed <= 8; ++seed) {
    const std::vector<NavRecord> nav = simulateNav(plan, spec, seed);
    ASSERT_EQ(nav.size(), plan.size());
    EXPECT_TRUE(approxEqual(nav.front().pose, Pose2(0, 0, nav.front().pose.yaw()), 1e-12, 0.0));
    EXPECT_NEAR(std::abs(nav.front().pose.yaw()), b, 1e-12);  // the heading bias from the start
    const Pose2 truth = between(plan.front().pose, plan.back().pose);
    const double ratio = (nav.back().pose.translation() - truth.translation()).norm() / d;
    EXPECT_TRUE(std::abs(ratio - exact) < 1e-9 || std::abs(ratio - exact_neg) < 1e-9) << ratio;
    EXPECT_NEAR(ratio, 0.01, 0.0005);  // the default: about 1 % of the distance
    EXPECT_NEAR(std::abs(normalizeAngle(nav.back().pose.yaw() - truth.yaw())), b, 1e-12);
    EXPECT_NEAR(nav.back().sigma_xy_m, std::hypot(s, b) * d, 1e-9);
    EXPECT_NEAR(nav.back().stamp_s, plan.back().stamp_s, 0.0);
  }
}

TEST(NavErrorModel, MonteCarloOverSeedsMatchesTheModel) {
  // The defaults over 400 seeds: the mean final error / distance is the systematic drift
  // (sqrt(s^2 + b^2) = 0.99 %) within 3 %; with only the random walk, the final error's per-axis
  // variance is random_walk^2 * distance within 10 % (chi-square with 800 dof: 1 sigma = 5 %).
  const std::vector<MissionFrame> plan = straightTrack(41, 0.5);
  const double d = 20.0;
  const Pose2 truth = between(plan.front().pose, plan.back().pose);
  NavErrorSpec spec;
  double sum_ratio = 0.0;
  const int n = 400;
  for (int seed = 0; seed < n; ++seed) {
    const std::vector<NavRecord> nav = simulateNav(plan, spec, 1000 + seed);
    sum_ratio += (nav.back().pose.translation() - truth.translation()).norm() / d;
  }
  const double drift = std::hypot(spec.scale_error, spec.heading_bias_rad);
  std::printf("nav error model: mean final error / distance %.5f over %d seeds (configured %.5f)\n", sum_ratio / n, n,
              drift);
  EXPECT_NEAR(sum_ratio / n, drift, 0.03 * drift);

  NavErrorSpec walk;
  walk.scale_error = 0.0;
  walk.heading_bias_rad = 0.0;
  walk.heading_random_walk_rad_per_sqrt_m = 0.0;
  walk.random_walk_m_per_sqrt_m = 0.004;
  double sum_sq = 0.0;
  for (int seed = 0; seed < n; ++seed) {
    const std::vector<NavRecord> nav = simulateNav(plan, walk, 5000 + seed);
    sum_sq += (nav.back().pose.translation() - truth.translation()).squaredNorm();
  }
  const double expected = walk.random_walk_m_per_sqrt_m * walk.random_walk_m_per_sqrt_m * d;
  std::printf("nav random walk: per-axis variance %.3g (model %.3g)\n", sum_sq / (2 * n), expected);
  EXPECT_NEAR(sum_sq / (2 * n), expected, 0.1 * expected);
}

TEST(NavErrorModel, YamlKeysAndValidation) {
  const SurveySpec s = surveyFromYaml("sessions: [{nav: {enabled: true, scale_error: 0.02}}]\n");
  EXPECT_TRUE(s.sessions[0].nav.enabled);
  EXPECT_DOUBLE_EQ(s.sessions[0].nav.scale_error, 0.02);
  EXPECT_EQ(surveyToYaml(surveyFromYaml(surveyToYaml(s))), surveyToYaml(s));
  EXPECT_THROW(surveyFromYaml("sessions: [{nav: {scale: 0.02}}]\n"), std::invalid_argument);
  EXPECT_THROW(surveyFromYaml("sessions: [{nav: {random_walk_m_per_sqrt_m: -1}}]\n"), std::invalid_argument);
}

TEST(NavErrorModel, WorldFrameYamlKeysAndValidation) {
  const SurveySpec s = surveyFromYaml(
      "nav_datum: {name: site_enu, origin_lat_lon_deg: [-33.8, 151.2]}\n"
      "sessions: [{nav: {enabled: true, frame: ned}}]\n");
  EXPECT_EQ(s.sessions[0].nav.frame, NavOutputFrame::kNed);
  EXPECT_EQ(s.nav_datum.name, "site_enu");
  const NavFrame f = s.nav_datum.frame(WorldConvention::kNed);
  EXPECT_TRUE(f.has_origin);
  EXPECT_DOUBLE_EQ(f.latitude_deg, -33.8);
  EXPECT_DOUBLE_EQ(f.longitude_deg, 151.2);
  EXPECT_EQ(surveyToYaml(surveyFromYaml(surveyToYaml(s))), surveyToYaml(s));
  EXPECT_FALSE(SurveySpec().nav_datum.frame(WorldConvention::kEnu).has_origin);  // no origin by default
  auto error = [](const std::string& text) {
    try {
      surveyFromYaml(text);
    } catch (const std::invalid_argument& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_NE(error("sessions: [{nav: {frame: nwu}}]\n").find("frame 'nwu' is not session, enu or ned"),
            std::string::npos);
  EXPECT_NE(error("nav_datum: {origin_lat_lon_deg: [1]}\nsessions: [{}]\n").find("origin_lat_lon_deg"),
            std::string::npos);
  EXPECT_NE(error("nav_datum: {origin_lat_lon_deg: [91, 0]}\nsessions: [{}]\n").find("latitude_deg 91"),
            std::string::npos);
  EXPECT_NE(error("nav_datum: {name: 'a b'}\nsessions: [{}]\n").find("name 'a b'"), std::string::npos);
  EXPECT_NE(error("nav_datum: {nam: x}\n").find("unknown key 'nam'"), std::string::npos);
}

// One mission rendered three times, its nav written in gt.csv's frame, in ENU and in NED (same
// seed: the same nav track). Its first leg runs along the world's +x (east on the chart), the way
// back along -x, the turn between towards +y (south).
class WorldNavTest : public ::testing::Test {
 protected:
  void SetUp() override {
    spec_.world.procedural.width_m = 8;
    spec_.world.procedural.height_m = 6;
    spec_.nav_datum.name = "site";
    spec_.nav_datum.origin_lat_lon_deg = {43.1, 5.9};
    SessionSpec a;
    a.name = "a";
    a.camera = CameraIntrinsics{64, 48, 60.0, 60.0, 31.5, 23.5};
    a.mission.pattern = MissionPattern::kOutAndBack;
    a.mission.start_m = Eigen::Vector2d(2.0, 2.0);
    a.mission.length_m = 3.0;
    a.mission.leg_spacing_m = 1.0;
    a.mission.altitude_m = 1.5;
    a.mission.speed_m_s = 0.5;
    a.mission.wobble_yaw_rad = 0.0;
    a.mission.camera_yaw_offset_rad = 0.4;
    a.image_format = "png";
    a.nav.enabled = true;
    a.nav.scale_error = 0.02;
    a.nav.heading_bias_rad = 0.01;
    spec_.sessions = {a};
  }
  Dataset generate(NavOutputFrame frame, const std::string& name) {
    SurveySpec s = spec_;
    s.sessions[0].nav.frame = frame;
    result_ = generateSurvey(s, (tmp_.path() / name).string());
    return loadDataset(result_.session_dirs[0]);
  }
  std::vector<NavRecord> rawNav(const std::string& name) const {
    return readNavCsv((tmp_.path() / name / "a" / "nav.csv").string());
  }
  testing_util::ScopedTempDir tmp_{"uwms_world_nav"};
  SurveySpec spec_;
  SurveyResult result_;
};

TEST_F(WorldNavTest, EnuIsTheChartNorthUpAndNedIsEnuMirroredAsRep103Says) {
  const Dataset session = generate(NavOutputFrame::kSession, "session");
  EXPECT_FALSE(session.nav_frame);
  EXPECT_FALSE(fs::exists(tmp_.path() / "session" / "a" / "nav_frame.yaml"));
  const Dataset enu = generate(NavOutputFrame::kEnu, "enu");
  const std::vector<WorldPose> world = result_.world_poses;
  const Dataset ned = generate(NavOutputFrame::kNed, "ned");
  ASSERT_TRUE(enu.nav_frame && ned.nav_frame);
  EXPECT_EQ(*enu.nav_frame, spec_.nav_datum.frame(WorldConvention::kEnu));
  EXPECT_EQ(ned.nav_frame->convention, WorldConvention::kNed);
  EXPECT_EQ(ned.nav_frame->name, "site");
  const std::vector<NavRecord> e = rawNav("enu"), n = rawNav("ned");
  ASSERT_EQ(e.size(), world.size());
  ASSERT_EQ(n.size(), e.size());
  // The first row's position is exact (nav starts at the truth): east = world x, north = -world y.
  EXPECT_NEAR(e[0].pose.x(), world[0].pose.x(), 1e-6);
  EXPECT_NEAR(e[0].pose.y(), -world[0].pose.y(), 1e-6);
  EXPECT_NEAR(std::abs(normalizeAngle(e[0].pose.yaw() + world[0].pose.yaw())), 0.01, 1e-6);  // yaw = -world yaw + bias
  // The first leg goes east (ENU x grows, NED y grows); the turn goes south (ENU y, NED x fall).
  const std::size_t mid = e.size() / 2;
  EXPECT_GT(e[3].pose.x() - e[0].pose.x(), 1.0);
  EXPECT_GT(n[3].pose.y() - n[0].pose.y(), 1.0);
  EXPECT_LT(e[mid].pose.y() - e[0].pose.y(), -0.5);
  EXPECT_LT(n[mid].pose.x() - n[0].pose.x(), -0.5);
  // An image whose columns point 0.4 rad from east towards south (world yaw 0.4): ENU yaw -0.4, NED
  // heading pi/2 + 0.4 (clockwise from north), both off by the heading bias.
  EXPECT_NEAR(std::abs(normalizeAngle(e[1].pose.yaw() + 0.4)), 0.01, 0.02);
  EXPECT_NEAR(std::abs(normalizeAngle(n[1].pose.yaw() - (M_PI / 2 + 0.4))), 0.01, 0.02);
  for (std::size_t i = 0; i < e.size(); ++i) {  // REP-103: x_ned = y_enu, y_ned = x_enu, yaw_ned = pi/2 - yaw_enu
    ASSERT_NEAR(n[i].pose.x(), e[i].pose.y(), 1e-6) << i;
    ASSERT_NEAR(n[i].pose.y(), e[i].pose.x(), 1e-6) << i;
    ASSERT_NEAR(normalizeAngle(n[i].pose.yaw() - (M_PI / 2 - e[i].pose.yaw())), 0.0, 2e-7) << i;
    ASSERT_EQ(n[i].sigma_xy_m, e[i].sigma_xy_m);
  }
  // Read: NED and ENU give the same rows; relative motions are those of the nav in gt.csv's frame
  // (a mirrored reading would flip the sign of every lateral step and turn).
  ASSERT_EQ(enu.nav.size(), session.nav.size());
  for (std::size_t i = 0; i < enu.nav.size(); ++i) {
    ASSERT_TRUE(approxEqual(enu.nav[i].pose, ned.nav[i].pose, 2e-6, 4e-7)) << i;
    ASSERT_TRUE(approxEqual(zUp(enu.nav[i].pose), e[i].pose, 1e-9, 1e-9)) << i;
    for (const std::size_t j : {i + 1, i + 5, std::size_t{0}}) {
      if (j >= enu.nav.size()) continue;
      ASSERT_TRUE(approxEqual(between(enu.nav[i].pose, enu.nav[j].pose),
                              between(session.nav[i].pose, session.nav[j].pose), 5e-6, 5e-7))
          << i << " -> " << j;
    }
  }
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
