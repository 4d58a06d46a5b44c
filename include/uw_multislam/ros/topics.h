// Default topic names and frame ids of uw_multislam, declared once (STYLE.md). Nodelets, tools and
// launch files use these; users change them by remapping (topics) or by parameters (frame ids).
//
// Topic names are relative (DESIGN.md): a node resolves them in its own namespace and launch
// files remap them. Bags store absolute names, so tools that write bags prefix them with "/"
// (see globalName), e.g. "/camera/image_raw".
#pragma once

#include <string>

namespace uw_multislam {
namespace topics {

/// sensor_msgs/Image from the bottom-looking camera (image_transport's "image_raw").
constexpr char kImage[] = "camera/image_raw";
/// sensor_msgs/CameraInfo beside the image, as image_transport::CameraSubscriber expects.
constexpr char kCameraInfo[] = "camera/camera_info";
/// sensor_msgs/Range: altitude of the camera above the seabed, metres.
constexpr char kAltitude[] = "altitude";
/// nav_msgs/Odometry: ground-truth pose of the camera, for evaluation only (never fed to SLAM).
constexpr char kGroundTruthOdom[] = "ground_truth/odom";

/// The absolute form of a relative name ("camera/image_raw" -> "/camera/image_raw").
inline std::string globalName(const std::string& relative) {
  return (!relative.empty() && relative.front() == '/') ? relative : "/" + relative;
}

}  // namespace topics

namespace frames {

/// The camera's frame, optical convention: x along image columns (u, right), y along rows
/// (v, down), z = x × y along the optical axis, towards the seabed for a bottom-looking camera.
constexpr char kCamera[] = "camera";
/// The altimeter's frame (its beam along +x, as sensor_msgs/Range defines).
constexpr char kAltimeter[] = "altimeter";
/// The ground-truth frame of a dataset folder: the first frame's image axes in metres, origin at
/// its image centre (../shared/data/README.md). Same axis convention as kCamera.
constexpr char kGroundTruthOrigin[] = "gt_origin";

}  // namespace frames
}  // namespace uw_multislam
