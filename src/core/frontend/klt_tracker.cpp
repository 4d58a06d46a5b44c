#include "uw_multislam/core/frontend/klt_tracker.h"

#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>

#include <algorithm>
#include <sstream>
#include <stdexcept>

namespace uw_multislam {
namespace core {

std::string KltOptions::validate() const {
  std::ostringstream os;
  if (max_corners < 8 || max_corners > 20000) {
    os << "max_corners " << max_corners << " must be in [8, 20000]";
  } else if (!(corner_quality > 0.0 && corner_quality < 1.0)) {
    os << "corner_quality " << corner_quality << " must be in (0, 1)";
  } else if (!(corner_min_distance_px >= 0.0 && corner_min_distance_px <= 1000.0)) {
    // Upper bounds: OpenCV's corner search crashed on 1e308 and 2^31 (2 * border_px overflowed).
    os << "corner_min_distance_px " << corner_min_distance_px << " must be in [0, 1000]";
  } else if (border_px < 0 || border_px > 1000) {
    os << "border_px " << border_px << " must be in [0, 1000]";
  } else if (window_px < 5 || window_px > 101 || window_px % 2 == 0) {
    os << "window_px " << window_px << " must be odd, in [5, 101]";
  } else if (pyramid_levels < 0 || pyramid_levels > 8) {
    os << "pyramid_levels " << pyramid_levels << " must be in [0, 8]";
  } else if (!(max_error > 0.0)) {
    os << "max_error must be > 0";
  } else if (!(max_forward_backward_px >= 0.0)) {
    os << "max_forward_backward_px must be >= 0 (0: no check)";
  } else if (min_tracks < 3) {
    os << "min_tracks " << min_tracks << " must be >= 3";
  }
  return os.str();
}

KltTracker::KltTracker(const KltOptions& options) : options_(options) {
  const std::string bad = options.validate();
  if (!bad.empty()) throw std::invalid_argument("klt: " + bad);
}

void KltTracker::invalidate() {
  keyframe_id_ = -1;
  previous_pyramid_.clear();
  keyframe_px_.clear();
  previous_px_.clear();
  step_px_.clear();
}

void KltTracker::reset(const cv::Mat& grey, int keyframe_id) {
  const cv::Point2f step = median_step_;
  invalidate();
  if (grey.empty() || grey.type() != CV_8UC1) throw std::invalid_argument("klt: expected a non-empty 8-bit grey image");
  const int b = options_.border_px;
  if (grey.cols <= 2 * b + 2 || grey.rows <= 2 * b + 2) return;  // nothing to track: stays inactive
  cv::Mat mask(grey.size(), CV_8UC1, cv::Scalar(0));
  mask(cv::Rect(b, b, grey.cols - 2 * b, grey.rows - 2 * b)).setTo(255);
  std::vector<cv::Point2f> corners;
  cv::goodFeaturesToTrack(grey, corners, options_.max_corners, options_.corner_quality, options_.corner_min_distance_px,
                          mask);
  if (static_cast<int>(corners.size()) < options_.min_tracks) return;
  cv::buildOpticalFlowPyramid(grey, previous_pyramid_, cv::Size(options_.window_px, options_.window_px),
                              options_.pyramid_levels);
  keyframe_px_ = corners;
  previous_px_ = corners;
  step_px_.assign(corners.size(), step);
  keyframe_id_ = keyframe_id;
}

KltTracker::Tracks KltTracker::track(const cv::Mat& grey) {
  Tracks out;
  if (keyframe_id_ < 0) return out;
  if (grey.empty() || grey.type() != CV_8UC1 || grey.size() != previous_pyramid_.front().size()) {
    invalidate();
    return out;
  }
  std::vector<cv::Mat> pyramid;
  const cv::Size window(options_.window_px, options_.window_px);
  cv::buildOpticalFlowPyramid(grey, pyramid, window, options_.pyramid_levels);
  std::vector<cv::Point2f> next(previous_px_.size());
  for (std::size_t i = 0; i < next.size(); ++i) next[i] = previous_px_[i] + step_px_[i];  // constant velocity
  std::vector<unsigned char> status;
  std::vector<float> error;
  cv::calcOpticalFlowPyrLK(
      previous_pyramid_, pyramid, previous_px_, next, status, error, window, options_.pyramid_levels,
      cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 30, 0.01), cv::OPTFLOW_USE_INITIAL_FLOW);
  // Back from the new frame to the previous one, started where each track came from.
  std::vector<unsigned char> back_status;
  std::vector<cv::Point2f> back;
  const bool check = options_.max_forward_backward_px > 0.0 && !next.empty();
  if (check) {
    back = previous_px_;
    std::vector<float> back_error;
    cv::calcOpticalFlowPyrLK(
        pyramid, previous_pyramid_, next, back, back_status, back_error, window, options_.pyramid_levels,
        cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 30, 0.01), cv::OPTFLOW_USE_INITIAL_FLOW);
  }
  const double fb2 = options_.max_forward_backward_px * options_.max_forward_backward_px;
  std::vector<cv::Point2f> kept_keyframe, kept_previous, kept_step;
  const float w = static_cast<float>(grey.cols - 1), h = static_cast<float>(grey.rows - 1);
  for (std::size_t i = 0; i < next.size(); ++i) {
    const cv::Point2f& p = next[i];
    if (!status[i] || !(error[i] <= options_.max_error) || !(p.x >= 0 && p.y >= 0 && p.x <= w && p.y <= h)) continue;
    if (check) {
      const cv::Point2f d = back[i] - previous_px_[i];
      if (!back_status[i] || !(static_cast<double>(d.dot(d)) <= fb2)) continue;
    }
    kept_keyframe.push_back(keyframe_px_[i]);
    kept_previous.push_back(p);
    kept_step.push_back(p - previous_px_[i]);
  }
  if (!kept_step.empty()) {
    std::vector<float> xs, ys;
    for (const cv::Point2f& d : kept_step) {
      xs.push_back(d.x);
      ys.push_back(d.y);
    }
    std::nth_element(xs.begin(), xs.begin() + xs.size() / 2, xs.end());
    std::nth_element(ys.begin(), ys.begin() + ys.size() / 2, ys.end());
    median_step_ = cv::Point2f(xs[xs.size() / 2], ys[ys.size() / 2]);
  }
  keyframe_px_ = std::move(kept_keyframe);
  previous_px_ = std::move(kept_previous);
  step_px_ = std::move(kept_step);
  previous_pyramid_ = std::move(pyramid);
  if (keyframe_px_.empty()) {
    invalidate();
    return out;
  }
  out.keyframe_px = keyframe_px_;
  out.current_px = previous_px_;
  return out;
}

}  // namespace core
}  // namespace uw_multislam
