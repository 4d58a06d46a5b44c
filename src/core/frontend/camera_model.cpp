#include "uw_multislam/core/frontend/camera_model.h"

#include <yaml-cpp/yaml.h>
#include <opencv2/calib3d.hpp>

#include <cmath>
#include <sstream>
#include <stdexcept>

#include "uw_multislam/core/common/yaml_map_reader.h"

namespace uw_multislam {
namespace core {

namespace {

[[noreturn]] void fail(const std::string& where, const std::string& what) {
  throw std::invalid_argument(where + ": " + what);
}

// A {rows, cols, data} matrix of the calibration file; rows x cols must be one of the sizes allowed.
std::vector<double> readMatrix(const YAML::Node& root, const char* key, const std::string& where,
                               const std::vector<std::pair<int, int>>& sizes) {
  const YAML::Node m = root[key];
  if (!m) fail(where, std::string("missing key '") + key + "'");
  if (!m.IsMap() || !m["rows"] || !m["cols"] || !m["data"] || !m["data"].IsSequence()) {
    fail(where, std::string("'") + key + "' must be a map with rows, cols and a data list");
  }
  int rows = 0, cols = 0;
  std::vector<double> data;
  try {
    rows = m["rows"].as<int>();
    cols = m["cols"].as<int>();
    data = m["data"].as<std::vector<double>>();
  } catch (const YAML::Exception&) {
    fail(where, std::string("'") + key + "': rows and cols must be integers and data numbers");
  }
  bool allowed = false;
  std::ostringstream expected;
  for (const auto& s : sizes) {
    allowed = allowed || (rows == s.first && cols == s.second);
    expected << (expected.tellp() > 0 ? " or " : "") << s.first << "x" << s.second;
  }
  if (!allowed) {
    fail(where, std::string("'") + key + "' is " + std::to_string(rows) + "x" + std::to_string(cols) + ", expected " +
                    expected.str());
  }
  if (static_cast<int>(data.size()) != rows * cols) {
    fail(where, std::string("'") + key + "' has " + std::to_string(data.size()) +
                    " numbers in data, rows x cols = " + std::to_string(rows * cols));
  }
  for (double v : data) {
    if (!std::isfinite(v)) fail(where, std::string("'") + key + "' has a number that is not finite");
  }
  return data;
}

int readSize(const YAML::Node& root, const char* key, const std::string& where) {
  if (!root[key]) fail(where, std::string("missing key '") + key + "'");
  try {
    const int v = root[key].as<int>();
    if (v >= 1 && v <= 1000000) return v;
  } catch (const YAML::Exception&) {
  }
  fail(where, std::string("'") + key + "' must be a whole number of pixels in [1, 1000000]");
}

void putMatrix(YAML::Emitter& out, const char* key, int rows, int cols, const std::vector<double>& data) {
  out << YAML::Key << key << YAML::Value << YAML::BeginMap << YAML::Key << "rows" << YAML::Value << rows << YAML::Key
      << "cols" << YAML::Value << cols << YAML::Key << "data" << YAML::Value << YAML::Flow << data << YAML::EndMap;
}

}  // namespace

cv::Matx33d cameraMatrix(const CameraIntrinsics& c) { return {c.fx, 0.0, c.cx, 0.0, c.fy, c.cy, 0.0, 0.0, 1.0}; }

std::vector<cv::Point2f> undistortPixels(const std::vector<cv::Point2f>& raw, const CameraIntrinsics& camera) {
  if (!camera.distorted() || raw.empty()) return raw;
  std::vector<cv::Point2f> ideal;
  const cv::Matx33d k = cameraMatrix(camera);
  // OpenCV's default is 5 iterations: short of convergence near the corners of a wide lens.
  cv::undistortPoints(raw, ideal, k, camera.distortion, cv::noArray(), k,
                      cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 100, 1e-5));
  return ideal;
}

void undistortKeypoints(std::vector<cv::KeyPoint>* keypoints, const CameraIntrinsics& camera) {
  if (!camera.distorted() || keypoints->empty()) return;
  std::vector<cv::Point2f> raw;
  raw.reserve(keypoints->size());
  for (const auto& k : *keypoints) raw.push_back(k.pt);
  const std::vector<cv::Point2f> ideal = undistortPixels(raw, camera);
  for (std::size_t i = 0; i < keypoints->size(); ++i) (*keypoints)[i].pt = ideal[i];
}

CameraIntrinsics parseRosCalibrationYaml(const std::string& text, const std::string& where, bool rectified) {
  YAML::Node root;
  try {
    root = parseYaml(text, "calibration");
  } catch (const std::invalid_argument& e) {
    fail(where, e.what());
  }
  if (!root.IsMap()) fail(where, "not a ROS calibration YAML (expected a map with image_width, camera_matrix, ...)");
  CameraIntrinsics c;
  c.width = readSize(root, "image_width", where);
  c.height = readSize(root, "image_height", where);
  const std::vector<double> k = readMatrix(root, "camera_matrix", where, {{3, 3}});
  if (!root["distortion_model"]) fail(where, "missing key 'distortion_model'");
  const std::string model = root["distortion_model"].as<std::string>("");
  DistortionModel m = DistortionModel::kNone;
  if (!parseDistortionModel(model, &m) || m == DistortionModel::kNone) {
    fail(where, "distortion_model '" + model +
                    "' is not supported (plumb_bob or rational_polynomial; rectify other lenses' images first)");
  }
  const std::vector<double> d =
      readMatrix(root, "distortion_coefficients", where,
                 m == DistortionModel::kPlumbBob ? std::vector<std::pair<int, int>>{{1, 4}, {1, 5}}
                                                 : std::vector<std::pair<int, int>>{{1, 8}});
  if (root["rectification_matrix"]) readMatrix(root, "rectification_matrix", where, {{3, 3}});
  if (rectified) {
    const std::vector<double> p = readMatrix(root, "projection_matrix", where, {{3, 4}});
    c.fx = p[0], c.fy = p[5], c.cx = p[2], c.cy = p[6];
  } else {
    if (root["projection_matrix"]) readMatrix(root, "projection_matrix", where, {{3, 4}});
    c.fx = k[0], c.fy = k[4], c.cx = k[2], c.cy = k[5];
    c.distortion_model = m;
    c.distortion = d;
  }
  const std::string bad = c.validate();
  if (!bad.empty()) fail(where, bad);
  return c;
}

std::string rosCalibrationYaml(const CameraIntrinsics& c, const std::string& camera_name) {
  const DistortionModel m =
      c.distortion_model == DistortionModel::kNone ? DistortionModel::kPlumbBob : c.distortion_model;
  std::vector<double> d = c.distortion;
  d.resize(m == DistortionModel::kPlumbBob ? std::max<std::size_t>(d.size(), 5) : 8, 0.0);
  YAML::Emitter out;
  out.SetDoublePrecision(12);
  out << YAML::BeginMap;
  out << YAML::Key << "image_width" << YAML::Value << c.width << YAML::Key << "image_height" << YAML::Value << c.height
      << YAML::Key << "camera_name" << YAML::Value << camera_name;
  putMatrix(out, "camera_matrix", 3, 3, {c.fx, 0, c.cx, 0, c.fy, c.cy, 0, 0, 1});
  out << YAML::Key << "distortion_model" << YAML::Value << distortionModelName(m);
  putMatrix(out, "distortion_coefficients", 1, static_cast<int>(d.size()), d);
  putMatrix(out, "rectification_matrix", 3, 3, {1, 0, 0, 0, 1, 0, 0, 0, 1});
  putMatrix(out, "projection_matrix", 3, 4, {c.fx, 0, c.cx, 0, 0, c.fy, c.cy, 0, 0, 0, 1, 0});
  out << YAML::EndMap;
  return std::string(out.c_str()) + "\n";
}

}  // namespace core
}  // namespace uw_multislam
