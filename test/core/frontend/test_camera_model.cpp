// The camera model: feature points undistorted (against an independent round trip through
// cv::projectPoints), metric conversion of raw pixels, and the ROS calibration YAML of dataset
// folders (a good file, missing keys, wrong sizes).
#include <gtest/gtest.h>

#include <opencv2/calib3d.hpp>

#include <filesystem>
#include <fstream>

#include "../../common/scoped_temp_dir.h"
#include "uw_multislam/core/frontend/camera_model.h"
#include "uw_multislam/core/frontend/features.h"

namespace uw_multislam {
namespace core {
namespace {

CameraIntrinsics distortedCamera(DistortionModel model = DistortionModel::kPlumbBob) {
  CameraIntrinsics c{320, 240, 300.0, 305.0, 161.0, 118.0};
  c.distortion_model = model;
  c.distortion = model == DistortionModel::kPlumbBob
                     ? std::vector<double>{-0.28, 0.09, 0.001, -0.0007, -0.01}
                     : std::vector<double>{-0.28, 0.09, 0.001, -0.0007, -0.01, 0.02, 0.003, 0.001};
  return c;
}

// Ideal pinhole pixels over the whole image (corners included) and where the lens puts them:
// cv::projectPoints of their normalised rays with D.
void idealAndRaw(const CameraIntrinsics& c, std::vector<cv::Point2f>* ideal, std::vector<cv::Point2f>* raw) {
  std::vector<cv::Point3d> rays;
  for (double v = 0; v <= c.height; v += c.height / 8.0) {
    for (double u = 0; u <= c.width; u += c.width / 8.0) {
      ideal->emplace_back(static_cast<float>(u), static_cast<float>(v));
      rays.emplace_back((u - c.cx) / c.fx, (v - c.cy) / c.fy, 1.0);
    }
  }
  std::vector<cv::Point2d> projected;
  cv::projectPoints(rays, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), cameraMatrix(c), c.distortion, projected);
  for (const auto& p : projected) raw->emplace_back(static_cast<float>(p.x), static_cast<float>(p.y));
}

class UndistortRoundTrip : public ::testing::TestWithParam<DistortionModel> {};

TEST_P(UndistortRoundTrip, RecoversTheIdealPixelsToAThousandthOfAPixel) {
  const CameraIntrinsics c = distortedCamera(GetParam());
  ASSERT_EQ(c.validate(), "");
  std::vector<cv::Point2f> ideal, raw;
  idealAndRaw(c, &ideal, &raw);
  const std::vector<cv::Point2f> back = undistortPixels(raw, c);
  ASSERT_EQ(back.size(), ideal.size());
  double worst = 0.0, moved = 0.0;
  for (std::size_t i = 0; i < ideal.size(); ++i) {
    worst = std::max(worst, cv::norm(back[i] - ideal[i]));
    moved = std::max(moved, cv::norm(raw[i] - ideal[i]));
  }
  EXPECT_LT(worst, 1e-3) << "px";
  EXPECT_GT(moved, 20.0) << "the lens must move the corners, or the test shows nothing";
  // OpenCV's default five iterations fall short at the corners: why undistortPixels iterates more.
  std::vector<cv::Point2f> five;
  cv::undistortPoints(raw, five, cameraMatrix(c), c.distortion, cv::noArray(), cameraMatrix(c));
  double worst_five = 0.0;
  for (std::size_t i = 0; i < ideal.size(); ++i) worst_five = std::max(worst_five, cv::norm(five[i] - ideal[i]));
  EXPECT_GT(worst_five, 10 * worst);
}

INSTANTIATE_TEST_SUITE_P(Models, UndistortRoundTrip,
                         ::testing::Values(DistortionModel::kPlumbBob, DistortionModel::kRationalPolynomial));

TEST(CameraModel, PinholeAndZeroDistortionLeavePointsAlone) {
  CameraIntrinsics c = distortedCamera();
  const std::vector<cv::Point2f> px{{0.5f, 3.25f}, {300.0f, 200.0f}};
  EXPECT_EQ(undistortPixels(px, c.pinhole()), px);
  c.distortion.assign(5, 0.0);
  EXPECT_FALSE(c.distorted());
  EXPECT_EQ(undistortPixels(px, c), px);
  EXPECT_TRUE(c.pinhole().distortion.empty());
  EXPECT_EQ(c.pinhole().distortion_model, DistortionModel::kNone);
}

TEST(CameraModel, KeypointsAndMetresUseTheUndistortedPoint) {
  const CameraIntrinsics c = distortedCamera();
  std::vector<cv::Point2f> ideal, raw;
  idealAndRaw(c, &ideal, &raw);
  std::vector<cv::KeyPoint> kp;
  for (const auto& p : raw) kp.emplace_back(p, 3.0f, 10.0f, 0.5f);
  undistortKeypoints(&kp, c);
  const std::vector<Eigen::Vector2d> metres = applyAltitude(
      [&] {
        std::vector<cv::KeyPoint> r;
        for (const auto& p : raw) r.emplace_back(p, 3.0f);
        return r;
      }(),
      c, 2.0);
  for (std::size_t i = 0; i < ideal.size(); ++i) {
    EXPECT_LT(cv::norm(kp[i].pt - ideal[i]), 1e-3);
    EXPECT_FLOAT_EQ(kp[i].size, 3.0f);  // only the position changes
    const Eigen::Vector2d expected((ideal[i].x - c.cx) * 2.0 / c.fx, (ideal[i].y - c.cy) * 2.0 / c.fy);
    EXPECT_LT((pixelToMetres(raw[i], c, 2.0) - expected).norm(), 1e-5);
    EXPECT_LT((metres[i] - expected).norm(), 1e-5);
  }
}

TEST(CameraModel, ValidateNamesBadDistortion) {
  CameraIntrinsics c = distortedCamera();
  c.distortion.resize(3);
  EXPECT_NE(c.validate().find("plumb_bob with 3 coefficients"), std::string::npos) << c.validate();
  c = distortedCamera(DistortionModel::kRationalPolynomial);
  c.distortion.resize(5);
  EXPECT_NE(c.validate().find("rational_polynomial with 5"), std::string::npos) << c.validate();
  c = distortedCamera();
  c.distortion[1] = std::nan("");
  EXPECT_NE(c.validate().find("not finite"), std::string::npos) << c.validate();
  c = CameraIntrinsics{320, 240, 300.0, 305.0, 161.0, 118.0};
  c.distortion = {0.1};
  EXPECT_NE(c.validate().find("none with 1"), std::string::npos) << c.validate();
}

// What camera_calibration's cameracalibrator writes (ost.yaml).
const char* kCalibration = R"(image_width: 320
image_height: 240
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [300.0, 0.0, 161.0, 0.0, 305.0, 118.0, 0.0, 0.0, 1.0]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.28, 0.09, 0.001, -0.0007, -0.01]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
projection_matrix:
  rows: 3
  cols: 4
  data: [250.0, 0.0, 158.0, 0.0, 0.0, 260.0, 119.0, 0.0, 0.0, 0.0, 1.0, 0.0]
)";

std::string replaced(std::string text, const std::string& from, const std::string& to) {
  const auto at = text.find(from);
  EXPECT_NE(at, std::string::npos) << from;
  return text.replace(at, from.size(), to);
}

// Expects parseRosCalibrationYaml to throw std::invalid_argument containing `needle`.
void expectRefused(const std::string& text, const std::string& needle, bool rectified = false) {
  try {
    parseRosCalibrationYaml(text, "cam.yaml", rectified);
    FAIL() << "accepted, expected an error containing '" << needle << "'";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
    EXPECT_EQ(std::string(e.what()).rfind("cam.yaml: ", 0), 0u) << e.what();
  }
}

TEST(RosCalibrationYaml, RawImagesTakeKAndD) {
  const CameraIntrinsics c = parseRosCalibrationYaml(kCalibration, "cam.yaml");
  EXPECT_EQ(c, distortedCamera());
}

TEST(RosCalibrationYaml, RectifiedImagesTakeP) {
  const CameraIntrinsics c = parseRosCalibrationYaml(kCalibration, "cam.yaml", true);
  EXPECT_EQ(c, (CameraIntrinsics{320, 240, 250.0, 260.0, 158.0, 119.0}));
}

TEST(RosCalibrationYaml, RoundTripThroughTheWriter) {
  for (const auto model : {DistortionModel::kPlumbBob, DistortionModel::kRationalPolynomial}) {
    EXPECT_EQ(parseRosCalibrationYaml(rosCalibrationYaml(distortedCamera(model)), "w"), distortedCamera(model));
  }
}

TEST(RosCalibrationYaml, MissingKeysAndWrongSizesAreNamed) {
  for (const char* key : {"image_width", "image_height", "distortion_model"}) {
    expectRefused(replaced(kCalibration, std::string(key) + ":", "other_key:"), std::string("missing key '") + key);
  }
  expectRefused(replaced(kCalibration, "camera_matrix:", "cam_matrix:"), "missing key 'camera_matrix'");
  expectRefused(replaced(kCalibration, "distortion_coefficients:", "distortion:"),
                "missing key 'distortion_coefficients'");
  expectRefused(replaced(kCalibration, "projection_matrix:", "projection:"), "missing key 'projection_matrix'", true);
  expectRefused(replaced(kCalibration, "rows: 3\n  cols: 3\n  data: [300.0", "rows: 3\n  cols: 2\n  data: [300.0"),
                "'camera_matrix' is 3x2, expected 3x3");
  expectRefused(replaced(kCalibration, "cols: 5", "cols: 3"), "'distortion_coefficients' is 1x3, expected 1x4 or 1x5");
  expectRefused(replaced(kCalibration, "-0.01]", "-0.01, 0.0]"), "has 6 numbers in data, rows x cols = 5");
  expectRefused(replaced(kCalibration, "plumb_bob", "rational_polynomial"),
                "'distortion_coefficients' is 1x5, expected 1x8");
  expectRefused(replaced(kCalibration, "plumb_bob", "equidistant"), "distortion_model 'equidistant' is not supported");
  expectRefused(replaced(kCalibration, "305.0", "x"),
                "'camera_matrix': rows and cols must be integers and data numbers");
  expectRefused(replaced(kCalibration, "image_width: 320", "image_width: -3"), "'image_width' must be a whole number");
  expectRefused(replaced(kCalibration, "300.0, 0.0, 161.0", "0.0, 0.0, 161.0"), "focal length");
  expectRefused("[1, 2", "YAML");
}

TEST(RosCalibrationYaml, DatasetFoldersAcceptIt) {
  testing_util::ScopedTempDir tmp("uwms_camera_model");
  const std::string path = (tmp.path() / "camera.yaml").string();
  std::ofstream(path) << kCalibration;
  EXPECT_EQ(readCameraYaml(path), distortedCamera());
  std::ofstream(path) << replaced(kCalibration, "cols: 5", "cols: 3");
  try {
    readCameraYaml(path);
    FAIL() << "accepted a 1x3 distortion";
  } catch (const DatasetError& e) {
    EXPECT_NE(std::string(e.what()).find(path + ": 'distortion_coefficients' is 1x3"), std::string::npos) << e.what();
  }
  // The writer picks the format: six keys for a pinhole, the ROS format with distortion.
  writeCameraYaml(path, distortedCamera());
  EXPECT_EQ(readCameraYaml(path), distortedCamera());
  EXPECT_NE(readTextFile(path).find("distortion_model: plumb_bob"), std::string::npos);
  writeCameraYaml(path, distortedCamera().pinhole());
  EXPECT_EQ(readCameraYaml(path), distortedCamera().pinhole());
  EXPECT_EQ(readTextFile(path).find("camera_matrix"), std::string::npos);
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
