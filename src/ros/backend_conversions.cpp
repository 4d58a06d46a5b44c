#include "uw_multislam/ros/backend_conversions.h"

#include "uw_multislam/ros/conversions.h"

namespace uw_multislam {
namespace ros_conversions {

uw_multislam::Status statusMsg(std::uint8_t code, const std::string& message) {
  uw_multislam::Status s;
  s.code = code;
  s.message = message;
  return s;
}

uw_multislam::Status toStatusMsg(const core::Status& s) {
  // core::StatusCode takes its values from Status.msg (test_conversions checks each one).
  return statusMsg(static_cast<std::uint8_t>(s.code), s.ok() ? std::string() : s.message);
}

nav_msgs::Path toPathMsg(const std::vector<core::Pose2>& poses, const std::vector<ros::Time>& stamps,
                         const std::string& frame_id, const ros::Time& fallback) {
  nav_msgs::Path path;
  path.header.frame_id = frame_id;
  path.header.stamp = stamps.empty() ? fallback : stamps.back();
  for (std::size_t k = 0; k < poses.size(); ++k) {
    geometry_msgs::PoseStamped p;
    p.header.frame_id = frame_id;
    p.header.stamp = k < stamps.size() ? stamps[k] : path.header.stamp;
    p.pose = toPoseMsg(poses[k]);
    path.poses.push_back(p);
  }
  return path;
}

visualization_msgs::MarkerArray toMarkerArrayMsg(const std::vector<Segment>& segments, const std::string& frame_id,
                                                 const ros::Time& stamp) {
  visualization_msgs::MarkerArray out;
  visualization_msgs::Marker clear;
  clear.header.frame_id = frame_id;
  clear.header.stamp = stamp;
  clear.action = visualization_msgs::Marker::DELETEALL;
  out.markers.push_back(clear);
  struct Style {
    Segment::Kind kind;
    const char* ns;
    float r, g, b, width;
  };
  const Style styles[] = {{Segment::Kind::kLocal, "local_loops", 0.1f, 0.8f, 0.2f, 0.02f},
                          {Segment::Kind::kGlobal, "global_loops", 1.0f, 0.55f, 0.0f, 0.02f},
                          {Segment::Kind::kJoin, "joins", 0.9f, 0.1f, 0.1f, 0.05f}};
  int id = 0;
  for (const Style& st : styles) {
    visualization_msgs::Marker m;
    m.header.frame_id = frame_id;
    m.header.stamp = stamp;
    m.ns = st.ns;
    m.id = id++;
    m.type = visualization_msgs::Marker::LINE_LIST;
    m.action = visualization_msgs::Marker::ADD;
    m.pose.orientation.w = 1.0;
    m.scale.x = st.width;
    m.color.r = st.r;
    m.color.g = st.g;
    m.color.b = st.b;
    m.color.a = 1.0f;
    for (const Segment& s : segments) {
      if (s.kind != st.kind) continue;
      for (const core::Pose2* p : {&s.a, &s.b}) {
        geometry_msgs::Point q;
        q.x = p->x();
        q.y = p->y();
        m.points.push_back(q);
      }
    }
    if (!m.points.empty()) out.markers.push_back(m);
  }
  return out;
}

}  // namespace ros_conversions
}  // namespace uw_multislam
