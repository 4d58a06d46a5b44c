// Default topic names and frame ids of uw_multislam, declared once. Nodelets, tools and
// launch files use these; users change them by remapping (topics) or by parameters (frame ids).
//
// Topic names are relative: a node resolves them in its own namespace and launch
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
constexpr char kNavOdometry[] = "nav/odom";
/// nav_msgs/Odometry: ground-truth pose of the camera, for evaluation only (never fed to SLAM).
constexpr char kGroundTruthOdom[] = "ground_truth/odom";
/// nav_msgs/Odometry: the vehicle's dead-reckoned navigation (DVL/INS), base_link in odom, with
/// its covariance (a dataset's nav.csv in a bag): the odometry's navigation prior.
constexpr char kNavOdom[] = "nav/odom";

// --- The pipeline (doc/design.md): odometry -> keyframes -> loop detection -> back-end ------------

/// uw_multislam/Keyframe: each new keyframe with its features (odometry nodelet).
constexpr char kKeyframes[] = "keyframes";
// The back-end's NavSatFix input (~fix/topic's default): fixes used as absolute position priors.
constexpr char kFix[] = "fix";
/// Default of frames/session_frame_prefix: session `id`'s frame is "<prefix><id>" (ros_params::
/// readFrames reads it for every nodelet).
constexpr char kDefaultSessionFramePrefix[] = "session_";
/// geometry_msgs/PoseWithCovarianceStamped: the odometry-only pose of the latest frame (base_link)
/// in its session's z-up frame with its covariance (odometry nodelet; frame_id =
/// frames/session_frame_prefix + session id).
constexpr char kOdometryPose[] = "odometry/pose";
/// nav_msgs/Odometry (back-end, while it publishes odom -> base_link): the visual odometry in
/// the continuous odom frame, child base_link, with the pose covariance of odometry/pose.
constexpr char kOdometry[] = "odom";
/// sensor_msgs/Image: the latest keyframe's image with its features drawn (odometry nodelet,
/// only while someone subscribes).
constexpr char kKeyframeImage[] = "odometry/keyframe_image";
/// uw_multislam/SlamStatus, latched (odometry nodelet): the odometry's part of the status
/// (tracking, lost, paused; frame time, skips), which the back-end completes on kStatus.
constexpr char kOdometryStatus[] = "odometry/status";
/// uw_multislam/Loop: verified loops, local and global (loop detector nodelet(s)).
constexpr char kLoops[] = "loops";
/// uw_multislam/KeyframeHash: each keyframe's compact hash (loop detector in global/both mode).
constexpr char kKeyframeHashes[] = "keyframe_hashes";

// --- Back-end / session manager (published by it; the front-end nodelets consume these) ------

/// uw_multislam/SessionTrajectory: optimised keyframe poses of a session after each
/// optimisation. The loop detector takes local-loop candidates from them when they arrive, else
/// from the odometry motions of the Keyframe messages.
constexpr char kSessionTrajectory[] = "session_trajectory";
/// uw_multislam/SessionState, latched: the session keyframes go to now. When its id differs
/// from the odometry's current one, the odometry closes its session and starts this one. State
/// FINISHED (after finish_session): no session records; the odometry drops frames (as paused)
/// until an ACTIVE one or resume, then starts the session with this id.
constexpr char kActiveSession[] = "active_session";
/// Suggested names for the back-end's outputs (one place, so rviz and launch files agree):
/// nav_msgs/Path per session "paths/session_<id>", visualization_msgs/MarkerArray of loops and
/// joins, uw_multislam/SessionState[] via the list_sessions service.
constexpr char kSessionPathPrefix[] = "paths/session_";
constexpr char kLoopMarkers[] = "loop_markers";
/// visualization_msgs/MarkerArray (back-end, latched): every session's trajectory in its own
/// colour with labels, maps that are not joined drawn side by side (ros_conversions::mapOffsets).
constexpr char kTrajectoryMarkers[] = "trajectory_markers";
/// uw_multislam/Keyframe: the keyframes of a session reload_session brought back from the session
/// store (back-end), for the loop detector(s) to store as candidates without searching.
constexpr char kReloadedKeyframes[] = "reloaded_keyframes";
/// Hash exchange between vehicles (with the back-end's ~fleet/vehicle set):
/// uw_multislam/KeyframeHash, this vehicle's keyframes (hash, motion, pose, camera; no features)
/// and session-ended notices, for the other vehicles' back-ends (a relay carries them across).
constexpr char kFleetHashesOut[] = "fleet/hashes_out";
/// uw_multislam/KeyframeHash: the other vehicles' fleet/hashes_out (own ones are ignored).
constexpr char kFleetHashesIn[] = "fleet/hashes_in";
/// uw_multislam/Keyframe: another vehicle's keyframe as the back-end took it (its session in this
/// back-end's ids, hash only), for the loop detector(s): searched against this vehicle's keyframes
/// and held paged (its features asked for through keyframe_features, which the back-end forwards
/// to that vehicle's).
constexpr char kForeignKeyframes[] = "foreign_keyframes";
/// geometry_msgs/PoseStamped: the current base_link pose in the map frame (back-end: the odometry
/// pose corrected by the active session's optimisation).
constexpr char kCurrentPose[] = "pose";
/// geometry_msgs/PoseWithCovarianceStamped (back-end): the active session's last keyframe in the
/// map frame with its covariance (6x6, z / roll / pitch unknown), at each keyframe and optimisation.
constexpr char kKeyframePoseWithCovariance[] = "keyframe_pose";
/// sensor_msgs/NavSatFix (back-end, advertised only with a datum): keyframe_pose's position on
/// WGS84 (core::fixFromMap), its east/north covariance from keyframe_pose's, frame base_link.
constexpr char kKeyframeFix[] = "keyframe_fix";
constexpr char kRelocalisedPose[] = "relocalised_pose";
/// sensor_msgs/Image (back-end, latched, bgr8, drawn only while subscribed): the live mosaic of the
/// active map (core/export/live_mosaic.h), the active keyframe outlined in red; rows along the
/// map's image-axes y, redrawn at most at ~mosaic_rate after keyframes, joins, splits and optimisations.
constexpr char kLiveMosaic[] = "mosaic";
/// uw_multislam/SlamStatus (back-end, latched): the SLAM at a glance (ros/slam_status.h), at each
/// keyframe, when the odometry's state changes and at least once a second.
constexpr char kStatus[] = "status";
/// visualization_msgs/Marker (back-end, latched, only while subscribed): the status as a text
/// beside the vehicle (TEXT_VIEW_FACING in frames/base_frame) for rviz.
constexpr char kStatusMarker[] = "status_marker";

// --- Services of the session manager (uw_multislam/srv) ---------------------------------------
constexpr char kJoinSessionsService[] = "join_sessions";
constexpr char kSplitSessionService[] = "split_session";
constexpr char kReloadSessionService[] = "reload_session";
constexpr char kUnloadSessionService[] = "unload_session";
constexpr char kDeleteSessionService[] = "delete_session";
constexpr char kListSessionsService[] = "list_sessions";
constexpr char kStartSessionService[] = "start_session";
constexpr char kFinishSessionService[] = "finish_session";
constexpr char kAddLinkService[] = "add_link";
constexpr char kOptimiseService[] = "optimise";
constexpr char kDetectLoopsService[] = "detect_loops";
constexpr char kSetModeService[] = "set_mode";
constexpr char kHistoryService[] = "history";
constexpr char kExportService[] = "export";
constexpr char kSetDatumService[] = "set_datum";
// One stored keyframe's features for a loop detector that pages (slam/loops/page_stored).
constexpr char kKeyframeFeaturesService[] = "keyframe_features";
// --- Services of the odometry (uw_multislam/srv/OperatorCommand) ---------------------------------
/// Frames are dropped (counted, their stamps seen: no time gap) until resume; the session goes on.
constexpr char kPauseService[] = "pause";
constexpr char kResumeService[] = "resume";

/// The absolute form of a relative name ("camera/image_raw" -> "/camera/image_raw").
inline std::string globalName(const std::string& relative) {
  return (!relative.empty() && relative.front() == '/') ? relative : "/" + relative;
}

}  // namespace topics

namespace frames {

/// The frames/ parameters' defaults (REP-105 names; config/default.yaml): every options struct
/// that holds one of these frames starts from these.
constexpr char kDefaultMapFrame[] = "map";
constexpr char kDefaultOdomFrame[] = "odom";
constexpr char kDefaultBaseFrame[] = "base_link";
/// ~datum/earth_frame's default (REP-105 earth).
constexpr char kDefaultEarthFrame[] = "earth";

/// The camera's frame, optical convention: x along image columns (u, right), y along rows
/// (v, down), z = x × y along the optical axis, towards the seabed for a bottom-looking camera.
constexpr char kCamera[] = "camera";
/// The altimeter's frame (its beam along +x, as sensor_msgs/Range defines).
constexpr char kAltimeter[] = "altimeter";
/// The ground-truth frame of a dataset folder: the first frame's image axes in metres, origin at
/// its image centre (doc/dataset_format.md). Same axis convention as kCamera.
constexpr char kGroundTruthOrigin[] = "gt_origin";

}  // namespace frames
}  // namespace uw_multislam
