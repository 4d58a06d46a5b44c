// uw_multislam/Odometry: the front end (core::FrameStream, the one offline_slam drives) on live images
// (doc/ros_api.md). Threads: the callbacks pair image, camera_info and altitude under pairing_mutex_
// (core::InputPairing) onto a bounded queue (~queue_size; full: the oldest dropped, counted, its stamp handed on).
// One worker converts each frame (image, camera, mount from tf, the camera's altitude, the nav lookup), feeds the
// stream and publishes what it returns. It takes the newest frame
// core::FrameSkipRule allows (~drop_policy newest: the queue 20x deeper, so the rule, not a full queue,
// passes frames over; without a prediction every frame is processed, as without skipping) or the oldest.
// ~prepare_threads (core::OrderedPrefetch): with newest each frame is handed to the preparing threads as it arrives, a
// free one preparing the newest (conversion, enhancement, features), so the frame the worker takes is often ready; with
// oldest the frames waiting behind the one in progress are prepared. On unload the queue is closed and drained, then
// joined.
#pragma once

#include <diagnostic_updater/diagnostic_updater.h>
#include <image_transport/image_transport.h>
#include <nodelet/nodelet.h>
#include <sensor_msgs/Range.h>

#include <atomic>
#include <chrono>
#include <deque>
#include <memory>
#include <mutex>
#include <optional>
#include <thread>
#include <vector>

#include "uw_multislam/OperatorCommand.h"
#include "uw_multislam/SessionState.h"
#include "uw_multislam/core/common/ordered_prefetch.h"
#include "uw_multislam/core/common/work_queue.h"
#include "uw_multislam/core/frontend/frame_skip.h"
#include "uw_multislam/core/frontend/stream_control.h"
#include "uw_multislam/core/session/frame_stream.h"
#include "uw_multislam/ros/camera_mount.h"
#include "uw_multislam/ros/image_input.h"
#include "uw_multislam/ros/keyframe_publisher.h"
#include "uw_multislam/ros/nav_input.h"
#include "uw_multislam/ros/odometry_counters.h"
#include "uw_multislam/ros/odometry_frame.h"
#include "uw_multislam/ros/odometry_options.h"
#include "uw_multislam/ros/slam_status.h"

namespace uw_multislam {
namespace nodelets {

class OdometryNodelet : public nodelet::Nodelet {
 public:
  ~OdometryNodelet() override;

 private:
  using Pairing = core::InputPairing<ros_inputs::ImageMsg, sensor_msgs::CameraInfoConstPtr>;
  using Frame = ros_inputs::OdometryFrame;
  using Ahead = ros_inputs::PreparedAhead;
  void onInit() override;
  void onCameraInfo(const sensor_msgs::CameraInfoConstPtr& info);
  void onRange(const sensor_msgs::RangeConstPtr& range);
  void onActiveSession(const uw_multislam::SessionStateConstPtr& msg);
  bool setPaused(bool paused, uw_multislam::OperatorCommand::Response* res);
  void handle(Pairing::Decisions decisions);  // pushes the paired frames, logs the skipped; under pairing_mutex_
  void work();
  using Clock = std::chrono::steady_clock;
  void run(Frame& f, Ahead* ahead, Clock::time_point start = Clock::now());  // one frame, timed from `start`
  using Refusal = long ros_diagnostics::OdometryCounters::*;  // convert(): null, or the refusal's counter
  Refusal convert(const Frame& f, core::CameraIntrinsics* camera, cv::Mat* image, std::string* why) const;
  Ahead prepareAhead(const Frame& f) const;
  void process(const Frame& f, Ahead* ahead);
  bool resolveMount(const Frame& f);  // mount_ for the frame's sensors; false: refused (counted, logged)
  ros_diagnostics::OdometryCounters snapshot(ros_diagnostics::OdometryCounters worker);  // + inputs, FIFO, nav
  std::string silentInput(double now);
  void logStats(const std::string& when, const core::Odometry* odometry = nullptr);  // null: the current one's
  void fillDiagnostics(diagnostic_updater::DiagnosticStatusWrapper& stat);
  static double steadyNow() { return ros::SteadyTime::now().toSec(); }  // timeouts, arrivals: never steps

  ros_params::OdometryNodeletOptions options_;
  std::unique_ptr<core::BoundedWorkQueue<Frame>> queue_;  // pushed(): frames paired, popped(): taken
  // ~prepare_threads with newest: every frame submitted on arrival (under pairing_mutex_, in the queue's
  // order), the newest prepared; the worker takes its frame's preparation by Frame::arrival. Thread-safe.
  std::unique_ptr<core::OrderedPrefetch<ros_inputs::PreparedAhead, Frame>> prepare_on_arrival_;
  std::thread worker_;
  core::StreamControl control_;  // pause / resume and the back-end's session requests (thread-safe)
  std::mutex pairing_mutex_;     // guards pairing_ and altimeter_frame_ (the last Range's frame)
  std::unique_ptr<Pairing> pairing_;
  std::string altimeter_frame_;
  std::atomic<long> ranges_refused_{0}, ranges_above_max_{0};  // altitude readings refused, of those above the max
  std::mutex stats_mutex_;  // guards published_ (the worker's counters after each frame) and mount_error_
  ros_diagnostics::OdometryCounters published_;
  std::string mount_error_;                           // why frames are refused, while they are
  core::FrameBudget budget_;                          // thread-safe: arrivals (callbacks), costs (worker), diagnostics
  ros_diagnostics::CounterStatus diagnostic_status_;  // the updater's thread only
  // Worker-only state.
  std::unique_ptr<core::FrameStream> stream_;  // stamps, sessions, odometry, keyframes, nav placement
  std::unique_ptr<ros_frames::SensorMount> sensor_mount_;
  core::CameraMount mount_;  // the sensors' on the vehicle, once tf gave it
  ros_diagnostics::OdometryCounters counts_;
  ros::WallTime last_stats_;
  // ROS handles; the inputs last: destroyed first, so no callback runs into destroyed members.
  std::unique_ptr<diagnostic_updater::Updater> updater_;
  ros::WallTimer watchdog_, pairing_timer_;
  ros::Publisher pose_pub_;
  std::vector<ros::ServiceServer> services_;
  std::unique_ptr<image_transport::ImageTransport> it_;
  std::unique_ptr<ros_outputs::KeyframePublisher> keyframes_;
  std::unique_ptr<ros_status::OdometryStatusPublisher> status_;  // odometry/status: the worker's frames
  std::unique_ptr<ros_inputs::NavInput> nav_;
  std::unique_ptr<ros_inputs::ImageInput> images_;
  ros::Subscriber session_sub_, info_sub_, range_sub_;
};

}  // namespace nodelets
}  // namespace uw_multislam
