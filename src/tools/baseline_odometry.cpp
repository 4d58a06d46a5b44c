// baseline_odometry: the naive OpenCV odometry our SIFT odometry is measured against ("SIFT, ratio
// test, estimateAffinePartial2D with RANSAC between consecutive frames"). Every
// frame is a keyframe; points are scaled to metres with each frame's altitude exactly as ours
// are, so the comparison isolates the estimator. Output: odometry.csv and trajectory.csv in the
// offline runner's format, so evaluate.py scores both the same way.
#include <opencv2/calib3d.hpp>
#include <opencv2/features2d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <optional>
#include <string>
#include <vector>

#include "cli.h"

#include "uw_multislam/core/common/stage_timer.h"
#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/frontend/features.h"

namespace core = uw_multislam::core;
namespace fs = std::filesystem;
namespace po = boost::program_options;
namespace tools = uw_multislam::tools;

namespace {

const char* kUsage =
    "usage: baseline_odometry --session DIR [--session DIR ...] --out OUT\n"
    "Naive OpenCV odometry (SIFT, ratio test 0.75, estimateAffinePartial2D RANSAC 3 px) between\n"
    "consecutive frames, scaled by altitude. Writes odometry.csv, trajectory.csv, loops.csv, timing.csv\n"
    "in the offline runner's format (every frame a keyframe; a failed frame keeps the identity motion).";

std::optional<int> parseArguments(int argc, char** argv, std::vector<std::string>* sessions, std::string* out) {
  tools::CommandLine cli("baseline_odometry", kUsage);
  auto option = cli.add();
  option("session", po::value(sessions));
  option("out", po::value(out));
  if (const auto status = cli.parse(argc, argv)) return status;
  if (sessions->empty() || out->empty()) return cli.bad("--session and --out are required");
  return std::nullopt;
}

int runBaseline(const std::vector<std::string>& sessions, const std::string& out) {
  try {
    cv::setNumThreads(1);
    fs::create_directories(out);
    std::ofstream odo(fs::path(out) / "odometry.csv"), traj(fs::path(out) / "trajectory.csv");
    odo << "session,index,x_m,y_m,yaw_rad\n" << std::fixed << std::setprecision(6);
    traj << "session,index,map,x_m,y_m,yaw_rad\n" << std::fixed << std::setprecision(6);
    const cv::Ptr<cv::SIFT> sift = cv::SIFT::create();
    const cv::BFMatcher matcher(cv::NORM_L2);
    core::StageTimes times;
    for (std::size_t s = 0; s < sessions.size(); ++s) {
      const core::Dataset d = core::loadDataset(sessions[s]);
      std::vector<cv::KeyPoint> prev_kp;
      cv::Mat prev_desc;
      double prev_alt = 0.0;
      double x = 0, y = 0, yaw = 0;
      int failures = 0, unreadable = 0;  // pairs without a motion (an unreadable frame fails two)
      for (const auto& f : d.frames) {
        // Stages (timing.csv): baseline_total the whole step; load_image and sift (OpenCV SIFT
        // alone, default settings: the reference column of scripts/bench_frontend.sh) inside it.
        core::ScopedStage total(&times, "baseline_total");
        cv::Mat grey;
        {
          core::ScopedStage load(&times, "load_image");
          grey = cv::imread(d.imagePath(f), cv::IMREAD_GRAYSCALE);
        }
        std::vector<cv::KeyPoint> kp;
        cv::Mat desc;
        if (grey.empty()) ++unreadable;
        if (!grey.empty()) {
          core::ScopedStage s(&times, "sift");
          sift->detectAndCompute(grey, cv::noArray(), kp, desc);
        }
        if (!prev_kp.empty() && !kp.empty()) {
          std::vector<std::vector<cv::DMatch>> knn;
          matcher.knnMatch(desc, prev_desc, knn, 2);
          std::vector<cv::Point2f> from, to;  // current frame -> previous frame, metres
          for (const auto& m : knn) {
            if (m.size() == 2 && m[0].distance < 0.75f * m[1].distance) {
              const Eigen::Vector2d b = core::pixelToMetres(kp[m[0].queryIdx].pt, d.camera, f.altitude_m);
              const Eigen::Vector2d a = core::pixelToMetres(prev_kp[m[0].trainIdx].pt, d.camera, prev_alt);
              from.emplace_back(static_cast<float>(b.x()), static_cast<float>(b.y()));
              to.emplace_back(static_cast<float>(a.x()), static_cast<float>(a.y()));
            }
          }
          cv::Mat m;
          if (from.size() >= 3) {
            m = cv::estimateAffinePartial2D(from, to, cv::noArray(), cv::RANSAC, 3.0 * f.altitude_m / d.camera.fx);
          }
          if (!m.empty()) {
            // The current frame's pose in the previous one: rotation and translation of the fit.
            const double th = std::atan2(m.at<double>(1, 0), m.at<double>(0, 0));
            const double tx = m.at<double>(0, 2), ty = m.at<double>(1, 2);
            x += std::cos(yaw) * tx - std::sin(yaw) * ty;
            y += std::sin(yaw) * tx + std::cos(yaw) * ty;
            yaw = core::normalizeAngle(yaw + th);
          } else {
            ++failures;
          }
        } else if (&f != &d.frames.front()) {
          ++failures;  // either frame unreadable or without a keypoint: no motion, the pose held
        }
        odo << s << "," << f.index << "," << x << "," << y << "," << yaw << "\n";
        traj << s << "," << f.index << "," << s << "," << x << "," << y << "," << yaw << "\n";
        prev_kp = kp;
        prev_desc = desc;
        prev_alt = f.altitude_m;
      }
      std::printf("baseline session %zu (%s): %zu frames (%d unreadable), %d of %zu pairs failed, %.1f ms/frame\n", s,
                  sessions[s].c_str(), d.frames.size(), unreadable, failures,
                  d.frames.empty() ? std::size_t{0} : d.frames.size() - 1, times.get("baseline_total").meanMs());
    }
    std::ofstream(fs::path(out) / "loops.csv") << "session_a,index_a,session_b,index_b,kind,inliers\n";
    std::ofstream timing(fs::path(out) / "timing.csv");
    timing << "stage,calls,total_ms,mean_ms,max_ms\n";
    for (const auto& st : times.stats()) {
      timing << st.stage << "," << st.calls << "," << st.total_ms << "," << st.meanMs() << "," << st.max_ms << "\n";
    }
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "baseline_odometry: %s\n", e.what());
    return 1;
  }
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<std::string> sessions;
  std::string out;
  if (const auto status = parseArguments(argc, argv, &sessions, &out)) return *status;
  return runBaseline(sessions, out);
}
