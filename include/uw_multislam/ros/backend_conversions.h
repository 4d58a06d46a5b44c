// Conversions between the back-end (core/backend/backend.h) and its ROS messages: service statuses,
// session states, paths and the loop / join markers. One place for them, each tested in
// test/ros/test_backend_conversions.cpp.
#pragma once

#include <nav_msgs/Path.h>
#include <ros/time.h>
#include <std_msgs/ColorRGBA.h>
#include <visualization_msgs/MarkerArray.h>

#include <map>
#include <string>
#include <vector>

#include "uw_multislam/AddLink.h"
#include "uw_multislam/DetectLoops.h"
#include "uw_multislam/History.h"
#include "uw_multislam/HistoryEntry.h"
#include "uw_multislam/SessionState.h"
#include "uw_multislam/SessionTrajectory.h"
#include "uw_multislam/Status.h"
#include "uw_multislam/core/backend/backend.h"
#include "uw_multislam/core/geometry/map_frame.h"
#include "uw_multislam/core/geometry/vehicle_frame.h"
#include "uw_multislam/core/session/session_manager.h"
#include "uw_multislam/core/session/stored_loops.h"
#include "uw_multislam/ros/pipeline_conversions.h"

namespace uw_multislam {
namespace ros_conversions {

/// The core's status as the services' Status (the same codes: OK, NOT_FOUND, ...).
uw_multislam::Status toStatusMsg(const core::Status& s);
uw_multislam::Status statusMsg(std::uint8_t code, const std::string& message);

/// A Keyframe message's content as the session manager takes it (stamp in seconds).
core::KeyframeInput toKeyframeInput(const KeyframeData& k, double stamp_s);
/// add_link's request as the loop it asks for, checked as a detector's Loop message is (ids, a
/// finite pose, a covariance): false with the reason in `why`. The kind follows the sessions.
bool fromAddLinkRequest(const uw_multislam::AddLink::Request& r, core::Loop* out, std::string* why);
/// A stored keyframe handed back by reload_session, as the loop detector(s) take it: features,
/// camera and altitude; its motion is not needed (an exact identity, quality MATCHED).
KeyframeData reloadedKeyframe(const core::ReloadedSession& session, const core::StoredKeyframe& k);
/// The same as the Keyframe message reload_session publishes: stamped with the keyframe's stamp,
/// in `frame_id` (the session's frame).
uw_multislam::Keyframe reloadedKeyframeMsg(const core::ReloadedSession& session, const core::StoredKeyframe& k,
                                           const std::string& frame_id);
/// detect_loops' answer: the search's counts and the joins it brought about.
uw_multislam::DetectLoops::Response toDetectLoopsResponse(const core::Status& st, const core::StoredLoopSearch& f,
                                                          int joins);
/// The same counts as the back-end's log line: the status ("OK" or its full message) and each count named.
std::string detectLoopsLine(const core::Status& st, const core::StoredLoopSearch& f, int joins);
/// One session of list_sessions.
uw_multislam::SessionState toSessionStateMsg(const core::SessionSummary& s);
/// One entry of the audit trail (history service).
uw_multislam::HistoryEntry toHistoryEntryMsg(const core::HistoryEntry& e);
/// The history service's answer: the last `last` entries (0: all); INVALID_ARGUMENT when negative.
uw_multislam::History::Response toHistoryResponse(const std::vector<core::HistoryEntry>& history, int last);

/// set_mode's request: "mapping", or "localisation" with its other spelling "localization" (the
/// ROS world's); another word is INVALID_ARGUMENT and changes nothing.
core::Status setMode(core::SessionManager* m, const std::string& mode);

/// A session's keyframe poses (in its map's frame) as a Path in `frame_id`; stamps[k] per pose
/// (missing stamps: the last one given, or `fallback`).
nav_msgs::Path toPathMsg(const std::vector<core::Pose2>& poses, const std::vector<ros::Time>& stamps,
                         const std::string& frame_id, const ros::Time& fallback);

/// A session's keyframe poses in its map's frame as the vehicle's (z-up, base_link; the core's are
/// the camera's: core/geometry/vehicle_frame.h), as every output in the map frame gives them.
std::vector<core::Pose2> vehiclePoses(const core::SessionQueries& manager, int id, const core::CameraMount& mount);

/// One segment to draw: two vehicle positions in a map's frame.
struct Segment {
  core::Pose2 a, b;
  enum class Kind { kLocal, kGlobal, kJoin, kRefused } kind = Kind::kLocal;
};
/// Where each map is drawn along the map frame's x axis (metres added to x): the active session's
/// map (else the lowest id) where it is, so that it agrees with tf and the pose; every other map
/// after it in id order, shifted to start 1 m past the previous one's extent, so that maps that
/// are not joined (not related) do not sit on top of each other in rviz.
std::map<int, double> mapOffsets(const core::SessionQueries& manager, const core::CameraMount& mount);
/// The segments to draw for a manager's state: its loops inside a map (those the back-end refused
/// as kRefused), and its links, each map shifted by its offset (missing: 0).
std::vector<Segment> loopSegments(const core::SessionQueries& manager, const core::CameraMount& mount,
                                  const std::map<int, double>& offsets = {});
/// rviz markers for any number of sessions: each session's keyframes as a LINE_STRIP (namespace
/// "trajectories", id = session id, a colour of its own; the active session twice as wide) with a
/// text label "session <id>" at its last keyframe (namespace "labels"), and a label "map <id>"
/// over each shifted map (namespace "maps"), maps shifted by `offsets`, after a DELETEALL.
visualization_msgs::MarkerArray toTrajectoryMarkersMsg(const core::SessionQueries& manager,
                                                       const core::CameraMount& mount,
                                                       const std::map<int, double>& offsets,
                                                       const std::string& frame_id, const ros::Time& stamp);
/// A distinct, saturated colour for session `id` (hues spread by the golden ratio).
std_msgs::ColorRGBA sessionColour(int id);
/// A session's poses in its own frame, for the loop detectors' local candidates.
uw_multislam::SessionTrajectory toSessionTrajectoryMsg(int session, int map, const std::vector<core::Pose2>& poses,
                                                       const ros::Time& stamp, const std::string& frame_id);
/// LINE_LIST markers in `frame_id`, one per kind (namespaces "local_loops", "global_loops",
/// "joins"; green, orange, red), each with a DELETEALL first so removed segments disappear.
visualization_msgs::MarkerArray toMarkerArrayMsg(const std::vector<Segment>& segments, const std::string& frame_id,
                                                 const ros::Time& stamp);

/// What the back-end publishes in `map`, from the core's z-up map to the published one
/// (core::MapFrame: ENU at a datum): poses one by one; markers by turning each one's pose (its
/// points are in it), the DELETEALLs as they are.
std::vector<core::Pose2> toPublished(const core::MapFrame& out, const std::vector<core::Pose2>& in_core_map);
visualization_msgs::MarkerArray toPublished(const core::MapFrame& out, visualization_msgs::MarkerArray markers);

}  // namespace ros_conversions
}  // namespace uw_multislam
