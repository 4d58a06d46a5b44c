// Lens distortion of feature points, and the ROS calibration YAML (camera_calibration_parsers'
// format) for dataset folders. ROS-free: the ROS side turns a CameraInfo into the same
// CameraIntrinsics with image_geometry (ros/sensor_conversions.h).
//
// The images are never undistorted: the odometry extracts features on the raw image and
// undistorts only their coordinates, into the pixels of the ideal pinhole camera with the same K
// (CameraIntrinsics::pinhole()). Everything after extraction (matching, RANSAC, keyframes, loops,
// the session store) works in that pinhole camera.
#pragma once

#include <opencv2/core.hpp>

#include <string>
#include <vector>

#include "uw_multislam/core/frontend/dataset.h"

namespace uw_multislam {
namespace core {

/// K as a matrix.
cv::Matx33d cameraMatrix(const CameraIntrinsics& camera);

/// Raw (distorted) pixels -> pixels of camera.pinhole() (cv::undistortPointsIter, iterated until
/// the reprojection differs by less than 1e-5 px). Unchanged when the camera is not distorted.
std::vector<cv::Point2f> undistortPixels(const std::vector<cv::Point2f>& raw, const CameraIntrinsics& camera);
/// The same for keypoints, in place (only their positions change).
void undistortKeypoints(std::vector<cv::KeyPoint>* keypoints, const CameraIntrinsics& camera);

/// Parses a ROS calibration YAML: image_width, image_height, camera_matrix, distortion_model,
/// distortion_coefficients and, for rectified images, projection_matrix (matrices as
/// {rows, cols, data}); camera_name and rectification_matrix are optional, other keys ignored.
/// rectified: the images are rectified, so the camera is P's pinhole (fx, fy, cx, cy of P) with
/// no distortion; otherwise K with D. Throws std::invalid_argument starting with `where` and
/// naming the key at fault (missing, wrong size, not a number, unsupported model).
CameraIntrinsics parseRosCalibrationYaml(const std::string& text, const std::string& where, bool rectified = false);
/// The camera as a ROS calibration YAML (P = [K | 0], R = I), readable by
/// camera_calibration_parsers and by parseRosCalibrationYaml.
std::string rosCalibrationYaml(const CameraIntrinsics& camera, const std::string& camera_name = "camera");

}  // namespace core
}  // namespace uw_multislam
