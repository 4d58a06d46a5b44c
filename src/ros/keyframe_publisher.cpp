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
      hasher_(config.loops.global.hash_mode, config.odometry.features.num_features,
              config.loops.global.projection_seed),
      keyframe_pub_(nh.advertise<uw_multislam::Keyframe>(topics::kKeyframes, 50)),
      image_pub_(it->advertise(topics::kKeyframeImage, 1)) {}

int KeyframePublisher::publish(const core::SegmentedOdometry& segmented, const core::OdometryUpdate& u, int session,
                               const cv::Mat& image, const std_msgs::Header& frame_header,
                               const std::optional<core::NavPlacementInput>& placement) {
  const core::Odometry& odometry = *segmented.odometry();
  int n = 0;
  for (const auto& kf : segmented.newKeyframes()) {
    rc::KeyframeData data = rc::keyframeData(odometry, kf, u, session);
    if (kf.id == 0) data.nav_placement = placement;
    data.hash = hasher_.hash(kf.features.descriptors);  // once here; the loop detector and back-end reuse it
    // The store's keyframe image (config store.*), made as offline_slam makes it; a promoted
    // keyframe's image is gone.
    if (data.frame_index == u.index) data.thumbnail = core::encodeKeyframeImage(image, store_image_);
    std_msgs::Header header = frame_header;
    if (data.frame_index != u.index) header.stamp.fromSec(odometry.keyframes()[kf.id].stamp_s);  // promoted or held
    keyframe_pub_.publish(boost::make_shared<uw_multislam::Keyframe>(rc::toKeyframeMsg(data, header)));
    ++n;
    if (data.frame_index == u.index && image_pub_.getNumSubscribers() > 0) {
      cv::Mat drawn;
      cv::drawKeypoints(image, kf.features.keypoints, drawn, cv::Scalar(0, 255, 0));
      image_pub_.publish(cv_bridge::CvImage(header, "bgr8", drawn).toImageMsg());
    }
  }
  return n;
}

}  // namespace ros_outputs
}  // namespace uw_multislam
