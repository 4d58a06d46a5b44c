#include "uw_multislam/ros/keyframe_publisher.h"

#include <cv_bridge/cv_bridge.h>

#include <opencv2/features2d.hpp>

#include "uw_multislam/Keyframe.h"
#include "uw_multislam/ros/pipeline_conversions.h"
#include "uw_multislam/ros/topics.h"

namespace uw_multislam {
namespace ros_outputs {

namespace rc = ros_conversions;

KeyframePublisher::KeyframePublisher(ros::NodeHandle nh, image_transport::ImageTransport* it,
                                     const core::SlamConfig& config)
    : store_image_(config.store_image),
      keyframe_pub_(nh.advertise<uw_multislam::Keyframe>(topics::kKeyframes, 50)),
      image_pub_(it->advertise(topics::kKeyframeImage, 1)) {}

int KeyframePublisher::publish(const std::vector<core::StreamKeyframe>& keyframes, int frame_index,
                               const cv::Mat& image, const std_msgs::Header& frame_header) {
  int n = 0;
  for (const core::StreamKeyframe& k : keyframes) {
    rc::KeyframeData data = rc::keyframeData(k);
    const bool own = data.frame_index == frame_index;
    // The store's keyframe image (config store.*), made as offline_slam makes it; a promoted
    // keyframe's image is gone.
    if (own) data.thumbnail = core::encodeKeyframeImage(image, store_image_);
    std_msgs::Header header = frame_header;
    if (!own) header.stamp.fromSec(k.input.stamp_s);  // promoted or held
    keyframe_pub_.publish(boost::make_shared<uw_multislam::Keyframe>(rc::toKeyframeMsg(data, header)));
    ++n;
    if (own && image_pub_.getNumSubscribers() > 0) {
      cv::Mat drawn;
      cv::drawKeypoints(image, data.features.keypoints, drawn, cv::Scalar(0, 255, 0));
      image_pub_.publish(cv_bridge::CvImage(header, "bgr8", drawn).toImageMsg());
    }
  }
  return n;
}

}  // namespace ros_outputs
}  // namespace uw_multislam
