#include "uw_multislam/ros/keyframe_features_client.h"

#include <stdexcept>

#include "uw_multislam/ros/pipeline_conversions.h"
#include "uw_multislam/ros/topics.h"

namespace uw_multislam {
namespace ros_inputs {

core::FrameFeatures KeyframeFeaturesClient::load(int session, int keyframe) {
  uw_multislam::KeyframeFeatures srv;
  srv.request.session = session;
  srv.request.keyframe = keyframe;
  if (!call(&srv)) {
    ROS_WARN_THROTTLE(5, "loop detector: %s not answering: stored keyframe %d/%d not verified",
                      nh_.resolveName(topics::kKeyframeFeaturesService).c_str(), session, keyframe);
    throw std::runtime_error("keyframe_features: no answer from the back-end");
  }
  if (srv.response.status.code != uw_multislam::Status::OK) {
    ROS_WARN_THROTTLE(5, "loop detector: stored keyframe %d/%d not verified: %s", session, keyframe,
                      srv.response.status.message.c_str());
    throw std::runtime_error("keyframe_features: " + srv.response.status.message);
  }
  ros_conversions::KeyframeData k;
  std::string why;
  if (!ros_conversions::fromMsg(srv.response.keyframe, &k, &why)) throw std::runtime_error("keyframe_features: " + why);
  return k.features;
}

bool KeyframeFeaturesClient::check(int session, int keyframe, std::uint8_t* code, std::string* message) {
  uw_multislam::KeyframeFeatures srv;
  srv.request.session = session;
  srv.request.keyframe = keyframe;
  srv.request.check_only = true;
  if (!call(&srv)) return false;
  *code = srv.response.status.code;
  *message = srv.response.status.message;
  return true;
}

bool KeyframeFeaturesClient::call(uw_multislam::KeyframeFeatures* srv) {
  if (!client_.isValid())
    client_ = nh_.serviceClient<uw_multislam::KeyframeFeatures>(topics::kKeyframeFeaturesService, true);
  if (client_.call(*srv)) return true;
  client_.shutdown();
  return false;
}

}  // namespace ros_inputs
}  // namespace uw_multislam
