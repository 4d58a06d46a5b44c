#include "uw_multislam/ros/loop_publisher.h"

#include "uw_multislam/KeyframeHash.h"
#include "uw_multislam/Loop.h"
#include "uw_multislam/ros/topics.h"

namespace uw_multislam {
namespace ros_outputs {

namespace rc = ros_conversions;

LoopPublisher::LoopPublisher(ros::NodeHandle nh, bool hashes, const core::SlamConfig& config)
    : config_(config), loop_pub_(nh.advertise<uw_multislam::Loop>(topics::kLoops, 100)) {
  if (hashes) hash_pub_ = nh.advertise<uw_multislam::KeyframeHash>(topics::kKeyframeHashes, 100);
}

void LoopPublisher::publish(const std::vector<core::Loop>& loops, const std_msgs::Header& header, long* local,
                            long* global) {
  for (const core::Loop& l : loops) {
    loop_pub_.publish(boost::make_shared<uw_multislam::Loop>(rc::toLoopMsg(l, header)));
    ++*(l.kind == core::Loop::Kind::kLocal ? local : global);
    ROS_DEBUG("loop detector: %s loop %d/%d -> %d/%d, %d inliers", core::loopKindName(l.kind).c_str(), l.session_a,
              l.keyframe_a, l.session_b, l.keyframe_b, l.inliers);
  }
}

bool LoopPublisher::publishHash(const rc::KeyframeData& k, const Eigen::VectorXf& values,
                                const std_msgs::Header& header) {
  if (!hash_pub_) return false;
  rc::KeyframeHashData h;
  h.session = k.session;
  h.keyframe = k.keyframe;
  h.frame_index = k.frame_index;
  h.mode = config_.loops.global.hash_mode;
  h.projection_seed = config_.loops.global.projection_seed;
  h.num_features = config_.odometry.features.num_features;
  h.features = config_.odometry.features.type;
  h.values = values;
  hash_pub_.publish(boost::make_shared<uw_multislam::KeyframeHash>(rc::toKeyframeHashMsg(h, header)));
  return true;
}

}  // namespace ros_outputs
}  // namespace uw_multislam
