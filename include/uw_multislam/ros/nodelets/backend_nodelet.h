// uw_multislam/Backend: the back-end and session manager nodelet (paper 000 §8, §9). Glue around
// core::SessionWorker (core/session/session_worker.h), which owns the SessionManager, its work
// queue and the optimisation loop: messages are converted and handed to the worker, services lock
// (through the worker) and delegate, and what the manager's events say changed is published.
// Topics, services and parameters: doc/ros_api.md; behaviour: doc/nodes/backend.md.
//
// Threading: the subscriber callbacks convert and hand each message to the worker's bounded queue
// (oldest dropped, counted); the worker's thread processes them and optimises outside its lock,
// then calls publishAfterItem under it. Services run under the worker's lock (locked()) and never
// wait for an optimisation. The members marked "worker's lock" are touched only inside locked(),
// the worker's callbacks and the manager's events (all under that lock). odometry/pose never
// takes it (the frame publisher keeps the active correction). keyframe_features and the handover
// of stored sessions run on the multi-threaded queue; the live mosaic has its own thread.
#pragma once

#include <diagnostic_updater/diagnostic_updater.h>
#include <geometry_msgs/PoseWithCovarianceStamped.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>

#include <atomic>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "uw_multislam/AddLink.h"
#include "uw_multislam/DeleteSession.h"
#include "uw_multislam/DetectLoops.h"
#include "uw_multislam/ExportSurvey.h"
#include "uw_multislam/FinishSession.h"
#include "uw_multislam/History.h"
#include "uw_multislam/JoinSessions.h"
#include "uw_multislam/Keyframe.h"
#include "uw_multislam/KeyframeFeatures.h"
#include "uw_multislam/KeyframeHash.h"
#include "uw_multislam/ListSessions.h"
#include "uw_multislam/Loop.h"
#include "uw_multislam/Optimise.h"
#include "uw_multislam/ReloadSession.h"
#include "uw_multislam/SessionState.h"
#include "uw_multislam/SetMode.h"
#include "uw_multislam/SplitSession.h"
#include "uw_multislam/StartSession.h"
#include "uw_multislam/core/export/session_export.h"
#include "uw_multislam/core/session/session_worker.h"
#include "uw_multislam/ros/backend_counters.h"
#include "uw_multislam/ros/datum_service.h"
#include "uw_multislam/ros/fix_input.h"
#include "uw_multislam/ros/fleet_hash_exchange.h"
#include "uw_multislam/ros/fleet_peer_client.h"
#include "uw_multislam/ros/frame_publisher.h"
#include "uw_multislam/ros/live_mosaic_publisher.h"
#include "uw_multislam/ros/reloaded_keyframes_publisher.h"
#include "uw_multislam/ros/session_publisher.h"
#include "uw_multislam/ros/slam_params.h"
#include "uw_multislam/ros/slam_status.h"

namespace uw_multislam {
namespace nodelets {

class BackendNodelet : public nodelet::Nodelet {
 public:
  ~BackendNodelet() override;

 private:
  void onInit() override;
  void onKeyframe(const uw_multislam::KeyframeConstPtr& msg);
  void onLoop(const uw_multislam::LoopConstPtr& msg);
  void onEvent(const core::SessionEvent& e);
  void forgetSession(int id);  // worker's lock: off the handover, the loop detectors told, mosaic images dropped
  /// A request that may change the maps (worker's lock; on OK every session published, due maps solved).
  template <typename F>
  uw_multislam::Status change(F request);
  bool onJoin(uw_multislam::JoinSessions::Request& req, uw_multislam::JoinSessions::Response& res);
  bool onSplit(uw_multislam::SplitSession::Request& req, uw_multislam::SplitSession::Response& res);
  bool onList(uw_multislam::ListSessions::Request& req, uw_multislam::ListSessions::Response& res);
  bool onStart(uw_multislam::StartSession::Request& req, uw_multislam::StartSession::Response& res);
  bool onFinish(uw_multislam::FinishSession::Request& req, uw_multislam::FinishSession::Response& res);
  bool onAddLink(uw_multislam::AddLink::Request& req, uw_multislam::AddLink::Response& res);
  bool onOptimise(uw_multislam::Optimise::Request& req, uw_multislam::Optimise::Response& res);
  bool onHistory(uw_multislam::History::Request& req, uw_multislam::History::Response& res);
  bool onDetectLoops(uw_multislam::DetectLoops::Request& req, uw_multislam::DetectLoops::Response& res);
  bool onSetMode(uw_multislam::SetMode::Request& req, uw_multislam::SetMode::Response& res);
  bool onReload(uw_multislam::ReloadSession::Request& req, uw_multislam::ReloadSession::Response& res);
  bool onUnload(uw_multislam::ReloadSession::Request& req, uw_multislam::ReloadSession::Response& res);
  bool onDelete(uw_multislam::DeleteSession::Request& req, uw_multislam::DeleteSession::Response& res);
  bool onExport(uw_multislam::ExportSurvey::Request& req, uw_multislam::ExportSurvey::Response& res);
  bool onKeyframeFeatures(uw_multislam::KeyframeFeatures::Request& req, uw_multislam::KeyframeFeatures::Response& res);
  std::vector<ros_diagnostics::Counter> counters(const core::SessionQueries& m) const;  // worker's lock
  void fillDiagnostics(diagnostic_updater::DiagnosticStatusWrapper& stat);
  void say(const std::string& line) const;  // INFO, also once rosconsole is shut down
  /// A service's answer: `st` with the store's and the export root's paths named by role ("the
  /// store", "the export root"): any caller reads answers; the full message goes to the log (WARN).
  uw_multislam::Status answer(const core::Status& st, const char* service) const;

  core::SlamConfig config_;
  ros_params::BackendNodeletOptions options_;
  std::unique_ptr<core::SessionWorker> worker_;  // the manager and its lock
  std::unique_ptr<core::SessionExporter> exporter_;
  std::unique_ptr<ros_frames::FramePublisher> frames_;  // thread-safe on its own
  std::unique_ptr<ros_geo::DatumService> datum_;        // set_datum: its own mutex, then the worker's lock
  std::unique_ptr<ros_mosaic::LiveMosaicPublisher> mosaic_;
  std::unique_ptr<ros_fleet::PeerClient> peers_;
  std::unique_ptr<ros_sessions::SessionPublisher> sessions_;  // worker's lock
  std::unique_ptr<ros_fleet::HashExchange> fleet_;            // ~fleet/vehicle set
  std::unique_ptr<ros_sessions::ReloadedKeyframesPublisher> reloaded_;
  std::unique_ptr<ros_status::BackendStatusPublisher> status_;  // its own lock, after the worker's
  std::unique_ptr<ros_geo::FixInput> fix_;                      // ~fix/topic set; its own lock, after the worker's
  std::unique_ptr<diagnostic_updater::Updater> updater_;
  ros_diagnostics::CounterStatus diagnostic_status_;  // the diagnostics timer's thread only
  ros::WallTimer diagnostic_timer_, stats_timer_;
  std::atomic<long> received_{0}, bad_keyframes_{0}, bad_loops_{0};  // conversions refused before the worker

  bool publish_all_ = false;                           // worker's lock: an event asked for every session
  long sessions_unloaded_ = 0, sessions_deleted_ = 0;  // worker's lock
  std::vector<ros::ServiceServer> services_;
  ros::Subscriber keyframe_sub_, loop_sub_, pose_sub_;  // last: destroyed first
};

}  // namespace nodelets
}  // namespace uw_multislam
