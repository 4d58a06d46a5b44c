// Tracking between keyframes: the frames between two keyframes only need their
// motion from the last keyframe and the keyframe decision, not SIFT. At each keyframe Shi-Tomasi
// corners are detected on its image (as the turbid-water paper tracks Harris corners with KLT);
// each later frame follows them with OpenCV's pyramidal Lucas-Kanade, frame to frame (small
// steps), so every surviving track links a keyframe pixel to a pixel of the current frame. Each
// search starts where the track's last step predicts it (constant velocity: a survey vehicle's
// frames move by a similar step, often more than LK alone converges from; new tracks at a
// keyframe start with the median step of the tracks before). The
// odometry turns these pairs into metres and runs the same RANSAC as for SIFT matches
// (core/frontend/odometry.h decides when to fall back to extraction).
#pragma once

#include <opencv2/core.hpp>

#include <string>
#include <vector>

namespace uw_multislam {
namespace core {

struct KltOptions {
  /// Track between keyframes (false: SIFT on every frame, as before).
  bool enabled = false;
  /// Shi-Tomasi corners started at each keyframe (cv::goodFeaturesToTrack).
  int max_corners = 400;
  double corner_quality = 0.01;          // relative to the strongest corner, (0, 1)
  double corner_min_distance_px = 10.0;  // spread
  int border_px = 8;                     // corners this close to the border are not started
  /// Lucas-Kanade window side (odd, pixels) and pyramid levels above the image.
  int window_px = 21;
  int pyramid_levels = 4;
  /// A track is dropped when its LK error (mean absolute difference of the window, grey
  /// levels) exceeds this, or when it leaves the image.
  double max_error = 30.0;
  /// Forward-backward check (Kalal et al. 2010): each track is followed back from the new frame to
  /// the previous one and dropped when it lands more than this many pixels from where it started
  /// (0: no check). On repetitive texture LK can lock every track onto one wrong displacement,
  /// which RANSAC would take as a consistent motion (README, front-end options).
  double max_forward_backward_px = 1.0;
  /// Fewer surviving tracks than this: tracking is degraded, the frame is extracted.
  int min_tracks = 40;

  std::string validate() const;
};

class KltTracker {
 public:
  /// Throws std::invalid_argument on bad options.
  explicit KltTracker(const KltOptions& options);

  /// Starts tracks at the corners of `grey` (8-bit, the new keyframe's image), for keyframe `id`.
  void reset(const cv::Mat& grey, int keyframe_id);
  /// No tracks (until the next reset).
  void invalidate();
  /// Tracks exist from keyframe `id`.
  bool active(int keyframe_id) const { return keyframe_id_ >= 0 && keyframe_id_ == keyframe_id; }

  struct Tracks {
    std::vector<cv::Point2f> keyframe_px;  // raw pixels in the keyframe
    std::vector<cv::Point2f> current_px;   // the same points in the current frame, raw pixels
  };
  /// Follows the tracks from the previous image into `grey` (same size) and returns the
  /// survivors; lost tracks are dropped for good. Invalidates when none survive.
  Tracks track(const cv::Mat& grey);
  int tracks() const { return static_cast<int>(keyframe_px_.size()); }

 private:
  KltOptions options_;
  int keyframe_id_ = -1;
  std::vector<cv::Mat> previous_pyramid_;
  std::vector<cv::Point2f> keyframe_px_, previous_px_;
  std::vector<cv::Point2f> step_px_;  // each track's last step (the prediction of the next)
  cv::Point2f median_step_{0, 0};     // of the last tracking, for the tracks of the next keyframe
};

}  // namespace core
}  // namespace uw_multislam
