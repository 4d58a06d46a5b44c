// The session manager's answers and state as ROS messages (ros/backend_conversions.h).
#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <map>
#include <tuple>

#include "uw_multislam/ros/backend_conversions.h"

namespace uw_multislam {
namespace ros_conversions {
namespace {

TEST(BackendConversions, EveryCoreStatusCodeIsTheStatusMsgCodeOfTheSameName) {
  using C = core::StatusCode;
  const std::vector<std::pair<C, std::uint8_t>> pairs = {
      {C::kOk, uw_multislam::Status::OK},
      {C::kInvalidArgument, uw_multislam::Status::INVALID_ARGUMENT},
      {C::kNotFound, uw_multislam::Status::NOT_FOUND},
      {C::kAlreadyExists, uw_multislam::Status::ALREADY_EXISTS},
      {C::kFailedPrecondition, uw_multislam::Status::FAILED_PRECONDITION},
      {C::kInternal, uw_multislam::Status::INTERNAL},
      {C::kDataLoss, uw_multislam::Status::DATA_LOSS}};
  for (const auto& [core_code, msg_code] : pairs) {
    const uw_multislam::Status s = toStatusMsg({core_code, "why"});
    EXPECT_EQ(s.code, msg_code) << core::statusCodeName(core_code);
    EXPECT_EQ(s.message, core_code == C::kOk ? "" : "why");
  }
}

TEST(BackendConversions, DetectLoopsAnswerAndItsLogLineCountTheSame) {
  core::StoredLoopSearch f;
  f.queries = 1, f.candidates = 2, f.found = 3, f.duplicates = 4, f.accepted = 5, f.refused = 6;
  const uw_multislam::DetectLoops::Response res = toDetectLoopsResponse(core::Status::Ok(), f, 7);
  EXPECT_EQ(std::make_tuple(res.queries, res.candidates, res.found, res.already_held, res.accepted, res.refused),
            std::make_tuple(1, 2, 3, 4, 5, 6));
  EXPECT_EQ(res.joins, 7);
  EXPECT_EQ(detectLoopsLine(core::Status::Ok(), f, 7),
            "OK; 1 keyframes queried, 2 candidates, 3 loops (4 held already), 5 accepted, 6 refused, 7 joins");
  // Refused: the full message (paths too) for the log; the answer names them by role.
  EXPECT_EQ(detectLoopsLine({core::StatusCode::kNotFound, "no session 'x' in /data/a.db"}, {}, 0),
            "no session 'x' in /data/a.db; 0 keyframes queried, 0 candidates, 0 loops (0 held already), 0 accepted, "
            "0 refused, 0 joins");
}

TEST(BackendConversions, SessionSummaryAsSessionState) {
  core::SessionSummary s;
  s.id = 4;
  s.name = "dive";
  s.state = core::SessionState::kUnloaded;
  s.map = 2;
  s.keyframes = 17;
  s.loops = 3;
  s.first_stamp_s = 10.5;
  s.last_stamp_s = 20.25;
  const uw_multislam::SessionState m = toSessionStateMsg(s);
  EXPECT_EQ(m.session, 4);
  EXPECT_EQ(m.name, "dive");
  EXPECT_EQ(m.state, uw_multislam::SessionState::UNLOADED);
  EXPECT_EQ(m.relocalised_map, -1) << "not relocalised (the message's default 0 would name map 0)";
  EXPECT_EQ(m.map, 2);
  EXPECT_EQ(m.num_keyframes, 17);
  EXPECT_EQ(m.num_loops, 3);
  EXPECT_DOUBLE_EQ(m.first_stamp.toSec(), 10.5);
  EXPECT_DOUBLE_EQ(m.last_stamp.toSec(), 20.25);
  s.state = core::SessionState::kActive;
  EXPECT_EQ(toSessionStateMsg(s).state, uw_multislam::SessionState::ACTIVE);
  s.state = core::SessionState::kFinished;
  EXPECT_EQ(toSessionStateMsg(s).state, uw_multislam::SessionState::FINISHED);
}

TEST(BackendConversions, HistoryEntryAsItsMessageFieldByField) {
  const core::HistoryEntry e{7,
                             "2026-11-25T02:13:04Z",
                             "split",
                             "service",
                             "2+0,1",
                             "0:1>2:1 0:2>2:2",
                             "session 2 split off map 0 (undoes join #6)"};
  const uw_multislam::HistoryEntry m = toHistoryEntryMsg(e);
  EXPECT_EQ(m.id, 7);
  EXPECT_EQ(m.time_utc, e.time_utc);
  EXPECT_EQ(m.kind, "split");
  EXPECT_EQ(m.cause, "service");
  EXPECT_EQ(m.sessions, "2+0,1");
  EXPECT_EQ(m.loops, e.loops);
  EXPECT_EQ(m.message, e.message);
}

TEST(BackendConversions, AddLinkRequestAsTheLoopItAsksForCheckedAsALoopMessage) {
  uw_multislam::AddLink::Request r;
  r.session_a = 2;
  r.keyframe_a = 5;
  r.session_b = 3;
  r.keyframe_b = 7;
  r.pose.x = 0.4;
  r.pose.y = -0.1;
  r.pose.theta = 0.05;
  r.covariance = {1e-4, 0, 0, 0, 2e-4, 0, 0, 0, 3e-4};
  r.inliers = 12;
  core::Loop l;
  std::string why;
  ASSERT_TRUE(fromAddLinkRequest(r, &l, &why)) << why;
  EXPECT_EQ(l.kind, core::Loop::Kind::kGlobal);
  EXPECT_EQ(std::make_tuple(l.session_a, l.keyframe_a, l.session_b, l.keyframe_b, l.inliers),
            std::make_tuple(2, 5, 3, 7, 12));
  EXPECT_DOUBLE_EQ(l.z.mean.x(), 0.4);
  EXPECT_DOUBLE_EQ(l.z.mean.y(), -0.1);
  EXPECT_DOUBLE_EQ(l.z.mean.yaw(), 0.05);
  EXPECT_DOUBLE_EQ(l.z.covariance(1, 1), 2e-4);
  EXPECT_DOUBLE_EQ(l.z.covariance(2, 2), 3e-4);
  r.session_b = 2;
  ASSERT_TRUE(fromAddLinkRequest(r, &l, &why));
  EXPECT_EQ(l.kind, core::Loop::Kind::kLocal);
  r.pose.theta = std::nan("");
  EXPECT_FALSE(fromAddLinkRequest(r, &l, &why));
  EXPECT_NE(why.find("pose"), std::string::npos) << why;
  r.pose.theta = 0.0;
  r.covariance[1] = 5e-5;  // not symmetric
  EXPECT_FALSE(fromAddLinkRequest(r, &l, &why));
  EXPECT_NE(why.find("symmetric"), std::string::npos) << why;
}

TEST(BackendConversions, KeyframeDataAsManagerInput) {
  KeyframeData k;
  k.session = 3;
  k.keyframe = 7;
  k.frame_index = 21;
  k.altitude_m = 1.9;
  k.camera.width = 320;
  k.motion = core::UncertainPose2(core::Pose2(0.1, 0.2, 0.3), Eigen::Matrix3d::Identity() * 2e-4);
  k.odometry_pose = core::Pose2(1, 2, 0.5);
  k.hash = Eigen::VectorXf::LinSpaced(384, 0.0f, 1.0f);
  const core::KeyframeInput in = toKeyframeInput(k, 123.5);
  EXPECT_EQ(in.session, 3);
  EXPECT_EQ(in.keyframe, 7);
  EXPECT_EQ(in.frame_index, 21);
  EXPECT_DOUBLE_EQ(in.stamp_s, 123.5);
  EXPECT_DOUBLE_EQ(in.altitude_m, 1.9);
  EXPECT_EQ(in.camera.width, 320);
  EXPECT_DOUBLE_EQ(in.motion.mean.yaw(), 0.3);
  EXPECT_DOUBLE_EQ(in.motion.covariance(1, 1), 2e-4);
  EXPECT_DOUBLE_EQ(in.odometry_pose.y(), 2.0);
  ASSERT_EQ(in.hash.size(), 384);
  EXPECT_FLOAT_EQ(in.hash(383), 1.0f);
}

TEST(BackendConversions, TrajectoryMarkersForAnyNumberOfSessionsWithUnjoinedMapsSideBySide) {
  // Six sessions, none joined (six maps), each a line of 4 keyframes 0.5 m apart that turns a
  // little; session 5 is recording.
  core::SessionManagerOptions o;
  o.backend.join_min_loops = 0;
  core::SessionManager m(o);
  for (int s = 0; s < 6; ++s) {
    core::Pose2 previous;
    for (int k = 0; k < 4; ++k) {
      core::KeyframeInput in;
      in.session = s;
      in.keyframe = k;
      in.stamp_s = 100.0 * s + k;
      in.odometry_pose = core::Pose2(0.5 * k, 0.1 * s * k, 0.05 * k);
      in.motion = core::UncertainPose2(core::between(previous, in.odometry_pose), Eigen::Matrix3d::Identity() * 1e-4);
      previous = in.odometry_pose;
      ASSERT_TRUE(m.addKeyframe(in).ok());
    }
  }
  ASSERT_EQ(m.view().mapIds().size(), 6u);
  core::CameraMount mount;  // a lever arm: the markers draw the vehicle, not the camera
  mount.base_from_camera = core::Pose2(0.3, -0.2, 0.4);
  const std::map<int, double> offsets = mapOffsets(m.view(), mount);
  ASSERT_EQ(offsets.size(), 6u);
  EXPECT_EQ(offsets.at(m.view().mapOf(5)), 0.0);  // the recording session's map stays where tf has it
  // The maps' x ranges, shifted, do not overlap.
  std::vector<std::pair<double, double>> ranges;
  for (int s = 0; s < 6; ++s) {
    double lo = 1e9, hi = -1e9;
    for (const core::Pose2& p : vehiclePoses(m.view(), s, mount))
      lo = std::min(lo, p.x() + offsets.at(m.view().mapOf(s))),
      hi = std::max(hi, p.x() + offsets.at(m.view().mapOf(s)));
    ranges.emplace_back(lo, hi);
  }
  for (int a = 0; a < 6; ++a)
    for (int b = a + 1; b < 6; ++b)
      EXPECT_TRUE(ranges[a].second < ranges[b].first || ranges[b].second < ranges[a].first) << a << " " << b;

  const visualization_msgs::MarkerArray all = toTrajectoryMarkersMsg(m.view(), mount, offsets, "map", ros::Time(5.0));
  ASSERT_FALSE(all.markers.empty());
  EXPECT_EQ(all.markers.front().action, visualization_msgs::Marker::DELETEALL);
  std::map<int, visualization_msgs::Marker> lines;
  int labels = 0, map_labels = 0;
  for (const visualization_msgs::Marker& k : all.markers) {
    if (k.ns == "trajectories") lines[k.id] = k;
    labels += k.ns == "labels";
    map_labels += k.ns == "maps";
  }
  ASSERT_EQ(lines.size(), 6u);
  EXPECT_EQ(labels, 6);
  EXPECT_EQ(map_labels, 5);  // every map but the active one is drawn shifted, and says so
  for (int s = 0; s < 6; ++s) {
    EXPECT_EQ(lines[s].points.size(), 4u);
    // z-up: (x, -y) of the camera, then the lever arm (core::vehicleFromCamera, tested on its own).
    const core::Pose2 v = core::vehicleFromCamera(m.view().poses(s).back(), mount);
    EXPECT_DOUBLE_EQ(lines[s].points.back().x, v.x() + offsets.at(m.view().mapOf(s)));
    EXPECT_DOUBLE_EQ(lines[s].points.back().y, v.y());
    EXPECT_DOUBLE_EQ(lines[s].scale.x, s == 5 ? 0.06 : 0.03);
    for (int t = s + 1; t < 6; ++t) {  // colours far apart
      const auto &a = lines[s].color, &b = lines[t].color;
      EXPECT_GT(std::abs(a.r - b.r) + std::abs(a.g - b.g) + std::abs(a.b - b.b), 0.15f) << s << " " << t;
    }
  }
  // The loop segments move with their maps.
  EXPECT_TRUE(loopSegments(m.view(), mount, offsets).empty());  // no loops here
  // A local loop that agrees with the odometry, and one 3 m off that the back-end's gate
  // refuses: drawn apart, in a namespace and colour of their own.
  for (const core::Pose2& off : {core::Pose2(), core::Pose2(0.0, 3.0, 0.0)}) {
    core::Loop l;
    l.kind = core::Loop::Kind::kLocal;
    l.session_a = l.session_b = 0;
    l.keyframe_a = 0;
    l.keyframe_b = 3;
    l.z = core::UncertainPose2(
        core::compose(core::between(m.view().odometryPoses(0)[0], m.view().odometryPoses(0)[3]), off),
        Eigen::Matrix3d::Identity() * 1e-4);
    l.inliers = 50;
    ASSERT_TRUE(m.addLoop(l).ok());
  }
  ASSERT_TRUE(m.view().loopRefused(1) && !m.view().loopRefused(0));
  const std::vector<Segment> segments = loopSegments(m.view(), mount, offsets);
  ASSERT_EQ(segments.size(), 2u);
  EXPECT_EQ(segments[0].kind, Segment::Kind::kLocal);
  EXPECT_EQ(segments[1].kind, Segment::Kind::kRefused);
  std::map<std::string, visualization_msgs::Marker> by_ns;
  for (const visualization_msgs::Marker& k : toMarkerArrayMsg(segments, "map", ros::Time(5.0)).markers) by_ns[k.ns] = k;
  ASSERT_TRUE(by_ns.count("local_loops") && by_ns.count("refused_loops"));
  EXPECT_EQ(by_ns["refused_loops"].points.size(), 2u);
  EXPECT_EQ(by_ns["local_loops"].points.size(), 2u);
  const auto &a = by_ns["refused_loops"].color, &b = by_ns["local_loops"].color;
  EXPECT_GT(std::abs(a.r - b.r) + std::abs(a.g - b.g) + std::abs(a.b - b.b), 0.5f);
}

TEST(BackendConversions, MarkersAndPathsGoOutInThePublishedMap) {
  // Heading 0: the core map's x axis points north, so (x, y) in it is (-y, x) in ENU.
  const core::MapFrame north = core::MapFrame::enuAtHeading(0.0);
  const std::vector<core::Pose2> path = toPublished(north, {core::Pose2(2.0, 0.5, 0.0)});
  ASSERT_EQ(path.size(), 1u);
  EXPECT_NEAR(path[0].x(), -0.5, 1e-12);
  EXPECT_NEAR(path[0].y(), 2.0, 1e-12);
  EXPECT_NEAR(path[0].yaw(), M_PI / 2, 1e-12);
  Segment s;
  s.a = core::Pose2(1.0, 0.0, 0.0), s.b = core::Pose2(3.0, 2.0, 0.0);
  const visualization_msgs::MarkerArray core_markers = toMarkerArrayMsg({s}, "map", ros::Time(5.0));
  const visualization_msgs::MarkerArray out = toPublished(north, core_markers);
  ASSERT_EQ(out.markers.size(), core_markers.markers.size());
  EXPECT_EQ(out.markers[0].action, visualization_msgs::Marker::DELETEALL);
  int drawn = 0;
  for (const visualization_msgs::Marker& m : out.markers) {
    if (m.points.empty()) continue;
    ++drawn;
    // Each point as rviz places it: the marker's pose applied to it.
    const Eigen::Quaterniond q(m.pose.orientation.w, m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z);
    const Eigen::Vector3d at(m.pose.position.x, m.pose.position.y, m.pose.position.z);
    ASSERT_EQ(m.points.size(), 2u);
    const Eigen::Vector3d a = q * Eigen::Vector3d(m.points[0].x, m.points[0].y, 0.0) + at;
    const Eigen::Vector3d b = q * Eigen::Vector3d(m.points[1].x, m.points[1].y, 0.0) + at;
    EXPECT_NEAR(a.x(), 0.0, 1e-12);
    EXPECT_NEAR(a.y(), 1.0, 1e-12);
    EXPECT_NEAR(b.x(), -2.0, 1e-12);
    EXPECT_NEAR(b.y(), 3.0, 1e-12);
  }
  EXPECT_EQ(drawn, 1);
  // Without a datum nothing changes.
  EXPECT_EQ(toPublished(core::MapFrame(), core_markers).markers[1].pose.orientation.w, 1.0);
}

}  // namespace
}  // namespace ros_conversions
}  // namespace uw_multislam
