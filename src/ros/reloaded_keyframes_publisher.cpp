#include "uw_multislam/ros/reloaded_keyframes_publisher.h"

#include <ros/single_subscriber_publisher.h>

#include <utility>

#include "uw_multislam/Keyframe.h"
#include "uw_multislam/ros/backend_conversions.h"
#include "uw_multislam/ros/topics.h"

namespace uw_multislam {
namespace ros_sessions {

namespace rc = ros_conversions;

ReloadedKeyframesPublisher::ReloadedKeyframesPublisher(ros::NodeHandle& mt, core::SessionWorker* worker,
                                                       std::string session_frame_prefix)
    : worker_(worker), prefix_(std::move(session_frame_prefix)) {
  // Unbounded (0): a store of a hundred dives hands over more keyframes than any fixed queue holds.
  pub_ = mt.advertise<uw_multislam::Keyframe>(
      topics::kReloadedKeyframes, 0, [this](const ros::SingleSubscriberPublisher& pub) {
        worker_->handOver(pub.getSubscriberName(), [&](const core::ReloadedSession& r, const core::StoredKeyframe& k) {
          pub.publish(rc::reloadedKeyframeMsg(r, k, frameOf(r.id)));
        });
      });
}

core::Status ReloadedKeyframesPublisher::reload(const std::string& name_or_id, core::ReloadedSession* out) {
  return worker_->reloadSession(name_or_id, out, [this](const core::ReloadedSession& r, const core::StoredKeyframe& k) {
    pub_.publish(boost::make_shared<uw_multislam::Keyframe>(rc::reloadedKeyframeMsg(r, k, frameOf(r.id))));
  });
}

void ReloadedKeyframesPublisher::forget(int session) {
  worker_->forgetHandedOver(session);  // no later subscriber gets it
  pub_.publish(boost::make_shared<uw_multislam::Keyframe>(rc::unloadSessionMsg(session)));
}

}  // namespace ros_sessions
}  // namespace uw_multislam
