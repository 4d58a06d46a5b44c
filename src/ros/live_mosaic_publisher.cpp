#include "uw_multislam/ros/live_mosaic_publisher.h"

#include <cv_bridge/cv_bridge.h>
#include <ros/console.h>
#include <sensor_msgs/Image.h>

#include <chrono>
#include <utility>

#include "uw_multislam/ros/topics.h"

namespace uw_multislam {
namespace ros_mosaic {

LiveMosaicPublisher::LiveMosaicPublisher(ros::NodeHandle& nh, const core::SessionWorker& worker, double rate_hz,
                                         const core::LiveMosaicOptions& options, std::string frame_id,
                                         std::function<core::MapFrame()> map_frame)
    : worker_(worker),
      map_frame_(std::move(map_frame)),
      rate_hz_(rate_hz),
      options_(options),
      frame_id_(std::move(frame_id)),
      images_(options.resolution_m) {  // kept at the mosaic's resolution
  pub_ = nh.advertise<sensor_msgs::Image>(topics::kLiveMosaic, 1, true);
  if (on()) thread_ = std::thread([this] { run(); });
}

LiveMosaicPublisher::~LiveMosaicPublisher() {
  if (!thread_.joinable()) return;
  {
    std::lock_guard<std::mutex> lock(wait_mutex_);
    stop_ = true;
  }
  wake_.notify_all();
  thread_.join();
}

void LiveMosaicPublisher::add(int session, int keyframe, double altitude_m, const core::CameraIntrinsics& camera,
                              std::vector<std::uint8_t> jpeg) {
  if (!on() || jpeg.empty()) return;  // no mosaic: no image kept
  std::lock_guard<std::mutex> lock(mutex_);
  images_.add(session, keyframe, altitude_m, camera, std::move(jpeg));
}

void LiveMosaicPublisher::add(const core::ReloadedSession& r) {
  for (const core::StoredKeyframe& k : r.keyframes) add(r.id, k.keyframe, k.altitude_m, r.camera, k.thumbnail);
  due_ = true;
}

void LiveMosaicPublisher::removeSession(int session) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    images_.removeSession(session);
  }
  due_ = true;
}

MosaicStats LiveMosaicPublisher::stats() const {
  std::lock_guard<std::mutex> lock(mutex_);
  MosaicStats s = stats_;
  s.images_kB = static_cast<double>(images_.bytes()) / 1024.0;
  return s;
}

void LiveMosaicPublisher::run() {
  const auto period = std::chrono::duration<double>(1.0 / rate_hz_);
  std::unique_lock<std::mutex> wait(wait_mutex_);
  while (!wake_.wait_for(wait, period, [this] { return stop_; })) {
    if (!due_ || pub_.getNumSubscribers() == 0) continue;  // latched: the last one stays
    wait.unlock();
    core::LiveMosaicSnapshot snapshot = worker_.locked([this](const core::SessionQueries& m) {
      due_ = false;
      std::lock_guard<std::mutex> lock(mutex_);
      return core::liveMosaicSnapshot(m, images_);  // poses copied, images shared
    });
    if (map_frame_) core::turnLiveMosaic(&snapshot, map_frame_());
    const core::LiveMosaicImage image = core::drawLiveMosaic(snapshot, options_);  // without any lock
    if (!image.bgr.empty()) {
      std_msgs::Header header;
      header.stamp = ros::Time::now();
      header.frame_id = frame_id_;
      pub_.publish(cv_bridge::CvImage(header, "bgr8", image.bgr).toImageMsg());
      ROS_DEBUG("back-end: live mosaic of map %d: %d x %d px at %.4f m/px, %d keyframes drawn, %d missing, %.1f ms",
                snapshot.map, image.bgr.cols, image.bgr.rows, image.resolution_m, image.drawn, image.missing, image.ms);
    }
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stats_.published += image.bgr.empty() ? 0 : 1;
      stats_.drawn = image.drawn;
      stats_.missing = image.missing;
      stats_.ms = image.ms;
      stats_.resolution_m = image.resolution_m;
    }
    wait.lock();
  }
}

}  // namespace ros_mosaic
}  // namespace uw_multislam
