// uw_multislam/LoopDetector: loop detection of paper 000 §6 (local) and §7 (global) around
// core::LoopDetector. Modes, topics, paging, parameters and bad input: doc/nodes/loop_detector.md;
// counters: doc/diagnostics.md.
//
// Threading: the keyframe callbacks only push the message pointer onto a bounded FIFO
// (~queue_size; when full the OLDEST live keyframe is dropped and counted); reloaded keyframes go
// in as priority items (served first, never dropped). The session_trajectory callback swaps the
// optimised poses in under optimised_mutex_. One worker owns the core::LoopDetector (candidate
// search, RANSAC verification, paging through keyframe_features) and publishes. On unload the FIFO
// is closed and the worker processes what is in it before it is joined.
#pragma once

#include <diagnostic_updater/diagnostic_updater.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>

#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "uw_multislam/Keyframe.h"
#include "uw_multislam/SessionTrajectory.h"
#include "uw_multislam/core/common/work_queue.h"
#include "uw_multislam/core/loops/loop_detector.h"
#include "uw_multislam/core/loops/session_chain.h"
#include "uw_multislam/core/session/slam_config.h"
#include "uw_multislam/ros/keyframe_features_client.h"
#include "uw_multislam/ros/loop_detector_counters.h"
#include "uw_multislam/ros/loop_publisher.h"
#include "uw_multislam/ros/slam_params.h"

namespace uw_multislam {
namespace nodelets {

class LoopDetectorNodelet : public nodelet::Nodelet {
 public:
  ~LoopDetectorNodelet() override;

 private:
  /// What is known of one session: its cameras (the detector keeps pointers: never moved) and
  /// the chain of odometry motions, keyframe id = trajectory index.
  struct Session {
    explicit Session(int max_keyframe_gap) : chain(max_keyframe_gap) {}
    std::deque<core::CameraIntrinsics> cameras;
    core::SessionChain chain;
    /// The camera to hold a keyframe with: the last one, or `c` appended when it differs.
    const core::CameraIntrinsics* camera(const core::CameraIntrinsics& c);
    int next_page_out = 0;  // live paging: the oldest keyframe not yet paged out
  };
  /// A keyframe waiting for the worker.
  struct Work {
    uw_multislam::KeyframeConstPtr msg;
    enum class Kind { kLive, kReloaded, kForeign } kind = Kind::kLive;  // reloaded: stored only; foreign: hash only
  };

  void onInit() override;
  void work();
  void process(const uw_multislam::Keyframe& msg);
  /// A keyframe of a session reloaded from the store (or its unload notice): stored, not searched.
  void processReloaded(const uw_multislam::Keyframe& msg);
  /// Another vehicle's keyframe (hash only): searched against ours, then held paged.
  void processForeign(const uw_multislam::Keyframe& msg);
  Session& session(int id);  // created empty on first use
  /// The optimised poses the back-end last published for `session` (empty: none yet).
  std::vector<core::Pose2> optimisedPoses(int session);
  /// Live paging: pages out the keyframes of `session` page_live_after behind `newest` that the
  /// back-end's store has.
  void pageOutBehind(int session, int newest);
  ros_diagnostics::LoopDetectorCounters snapshot(ros_diagnostics::LoopDetectorCounters c) const;
  void logStats(const std::string& when);

  ros_params::LoopDetectorNodeletOptions options_;
  core::SlamConfig config_;
  std::unique_ptr<core::LoopDetector> detector_;
  std::unique_ptr<core::BoundedWorkQueue<Work>> queue_;
  std::thread worker_;
  std::mutex optimised_mutex_;
  std::map<int, std::vector<core::Pose2>> optimised_;  // guarded by optimised_mutex_: session_trajectory's
  std::mutex stats_mutex_;
  ros_diagnostics::LoopDetectorCounters published_;   // guarded by stats_mutex_: the worker's counters
  ros_diagnostics::CounterStatus diagnostic_status_;  // the timer's thread only
  // Worker-only state.
  std::map<int, Session> sessions_;
  std::set<int> foreign_sessions_;  // ids of other vehicles' sessions
  ros_diagnostics::LoopDetectorCounters counts_;
  ros::WallTime last_stats_;
  std::unique_ptr<ros_inputs::KeyframeFeaturesClient> features_;
  bool live_paging_ = false;  // page_stored, page_live_after > 0 and a store
  // ROS handles; subscribers last: destroyed first.
  std::unique_ptr<diagnostic_updater::Updater> updater_;
  ros::WallTimer diagnostic_timer_;
  std::unique_ptr<ros_outputs::LoopPublisher> loops_;
  ros::Subscriber keyframe_sub_, trajectory_sub_, reloaded_sub_, foreign_sub_;
};

}  // namespace nodelets
}  // namespace uw_multislam
