// uw_multislam/Backend: the back-end and session manager nodelet (paper 000 §8, §9), a thin
// adapter around core::SessionManager (core/session/session_manager.h), which owns the sessions,
// their ids, the back-end, the store, the joins and the splits. This class only translates
// messages and services and publishes what the manager's events say changed.
//
// Inputs:  keyframes (uw_multislam/Keyframe, odometry nodelet): each keyframe's motion from the
//            previous one; a new session id starts a session (the previous one stops recording)
//          loops (uw_multislam/Loop, loop detector nodelet(s)), local and global
//          odometry/pose (geometry_msgs/PoseWithCovarianceStamped, odometry nodelet): for tf, odom
//            and the current pose
// Outputs: session_trajectory (uw_multislam/SessionTrajectory): a session's optimised poses in its
//            own frame, for the loop detector's local candidates
//          paths/session_<id> (nav_msgs/Path, latched): each session's keyframes in its map's frame,
//            advertised with the session's first keyframe (an empty session has none)
//          loop_markers (visualization_msgs/MarkerArray, latched): loops and joins
//          trajectory_markers (visualization_msgs/MarkerArray, latched, built while subscribed):
//            every session in its own colour, labelled; maps not joined drawn side by side
//          pose (geometry_msgs/PoseStamped): the current base_link pose in the map frame
//          odom (nav_msgs/Odometry, with ~publish_odom_tf): the visual odometry in odom
//          keyframe_pose (geometry_msgs/PoseWithCovarianceStamped): the active session's last
//            keyframe in the map frame with its covariance, for a robot_localization EKF
//          active_session (uw_multislam/SessionState, latched): set by start_session
//          tf (ros/frame_publisher.h): map -> odom at ~tf_rate with fresh stamps, odom -> base_link
//            from the visual odometry (unless ~publish_odom_tf is false: the vehicle's), and
//            map -> <session_frame_prefix><id> as static transforms (~publish_session_frames)
//          reloaded_keyframes (uw_multislam/Keyframe): a reloaded session's keyframes, for the
//            loop detector(s) to keep as global-loop candidates; a new subscriber gets every session
//            reloaded so far (~reload_stored: all stored sessions, from start-up)
//          relocalised_pose (geometry_msgs/PoseWithCovarianceStamped): while the active session is
//            relocalised in another map (consistent global loops to it, not joined yet, or never in
//            localisation mode), its last keyframe in that map's frame (map_frame, where that map is
//            drawn); map -> odom and keyframe_pose then follow that map too
//          mosaic (sensor_msgs/Image, latched, only while subscribed): the live mosaic of the active
//            map (core/session/live_mosaic.h), the active keyframe outlined, redrawn at most at
//            ~mosaic_rate (default 0.2 Hz) when keyframes, joins, splits or optimisations changed it
// Hash exchange between vehicles (issue 20, item 5; ~fleet/vehicle set, off by default): each of
//          this vehicle's keyframes goes out on fleet/hashes_out as a KeyframeHash (hash, motion,
//          pose, camera; README "Two vehicles" has its size), and a notice when its session
//          ends; another vehicle's, from fleet/hashes_in, becomes a session of this back-end
//          (SessionManager::addForeignKeyframe: same hash settings or refused, counted) that grows
//          beside ours, and goes to the loop detector(s) on foreign_keyframes. A loop detector asks
//          keyframe_features for such a session's keyframe only when it is a loop candidate; this
//          back-end forwards the request to that vehicle's service (~fleet/peers). The loops then
//          join the two vehicles' maps by the usual rule, on each vehicle (README "Two vehicles").
// Services: join_sessions, split_session, list_sessions, start_session, reload_session, export
// (export_survey's files of a session or its map, from the store, into a folder below
// ~export_root; a folder outside it is refused INVALID_ARGUMENT). Replies
// name the store by its file name only. start_session answers RESOURCE_EXHAUSTED while the newest
// ~max_empty_sessions sessions have no keyframe (core::SessionManagerOptions::max_empty_sessions).
//
// Session store (~store_path, default $ROS_HOME/uw_multislam/sessions.db; "" = none; see
// core/session/session_store.h): every keyframe (features, descriptors, hash), its motion and each loop
// are written as they arrive, one transaction each (WAL), the maps at every join, split and
// session end, so a kill -9 loses at most what was in flight. At start-up the stored sessions,
// loops and maps are put back into the back-end (they take ids 0..k-1; active_session asks the
// odometry to continue from k) and listed UNLOADED: their trajectories are there, but the loop
// detector does not know their keyframes until reload_session publishes them (or, with
// ~reload_stored, all of them at start-up: listed FINISHED).
//
// Maps: every map is drawn in map_frame with its first session's origin at map_frame's origin
// (maps that are not joined are not related, so they overlap in rviz).
//
// Threading model: the keyframe and loop callbacks push the message pointers onto one bounded
// work queue (ros/work_queue.h, ~queue_size; when full the OLDEST is dropped and counted) and
// return, so that loops keep their order relative to keyframes. One worker thread takes them in
// order and calls the core::SessionManager under state_mutex_; the services take the same mutex.
// No request optimises under it: the manager runs with deferred optimisation, so a keyframe, loop
// or service only marks maps due, and the worker then takes each due map's problem out under the
// mutex, solves it WITHOUT the mutex, and applies it under the mutex again (a map changed by a
// service in between is solved again). A service therefore waits for one message's bookkeeping,
// never for an optimisation; one that leaves maps due (join, split, start) wakes the worker.
// A loop that names a keyframe the back-end has not received yet waits (up to
// ~max_waiting_loops, oldest dropped and counted) and is retried after each keyframe. The
// odometry/pose callback never takes state_mutex_: the frame publisher keeps the active session's
// correction, which the worker refreshes after each publication, so the per-frame pose and tf
// never wait for an optimisation. On unload the queue is closed, what is queued is
// processed, and the maps are optimised and saved.
// The live mosaic has its own thread: at most every 1 / ~mosaic_rate seconds, when something
// changed and someone subscribes, it copies the active map's poses out under state_mutex_
// (core::liveMosaicSnapshot: poses only, the images are shared) and warps and draws WITHOUT it.
// The export service takes state_mutex_ only to resolve the session's name; it reads the store
// read-only (SQLite WAL: beside the writer) and writes the files without the mutex, one export at
// a time (another one meanwhile is answered UNAVAILABLE).
#pragma once

#include <diagnostic_updater/diagnostic_updater.h>
#include <geometry_msgs/PoseStamped.h>
#include <geometry_msgs/PoseWithCovarianceStamped.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <thread>
#include <variant>

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
#include "uw_multislam/core/common/bounded_call.h"
#include "uw_multislam/core/session/live_mosaic.h"
#include "uw_multislam/core/session/session_manager.h"
#include "uw_multislam/ros/diagnostics.h"
#include "uw_multislam/ros/frame_publisher.h"
#include "uw_multislam/ros/slam_params.h"
#include "uw_multislam/ros/work_queue.h"

namespace uw_multislam {
namespace nodelets {

class BackendNodelet : public nodelet::Nodelet {
 public:
  ~BackendNodelet() override;

 private:
  /// monostate: a service left maps due, optimise them.
  using Message = std::variant<std::monostate, uw_multislam::KeyframeConstPtr, uw_multislam::LoopConstPtr,
                               uw_multislam::KeyframeHashConstPtr>;
  struct Counters {
    long keyframes = 0, loops = 0, bad = 0, waiting_dropped = 0;
  };

  void onInit() override;
  void work();
  /// Runs `process` under state_mutex_ (a throw is a counted, logged skip), then optimiseDue().
  template <typename F>
  void step(F process);
  /// Solves every due map outside state_mutex_ (see "Threading model").
  void optimiseDue();
  void processKeyframe(const uw_multislam::Keyframe& msg);
  void processLoop(const uw_multislam::LoopConstPtr& msg, bool retry);
  /// Another vehicle's keyframe or session-ended notice (fleet/hashes_in, "Hash exchange").
  void processFleetHash(const uw_multislam::KeyframeHash& msg);
  /// keyframe_features for another vehicle's session: forwarded to that vehicle's service
  /// (~fleet/peers) WITHOUT state_mutex_, its ids put back into ours.
  bool featuresFromPeer(const std::string& vehicle, int remote_session, int local_session,
                        uw_multislam::KeyframeFeatures::Request& req, uw_multislam::KeyframeFeatures::Response& res);
  void onEvent(const core::SessionEvent& e);
  void publishAll(bool all_sessions);
  /// Its path, trajectory and (active) pose and tf; returns its correction map <- session.
  core::Pose2 publishSession(int id);
  /// On active_session: the recording session, else the id the next one gets; `state` ACTIVE, or
  /// FINISHED after finish_session (the odometry then drops frames until start_session or resume).
  void announceNextSession(std::uint8_t state = uw_multislam::SessionState::ACTIVE);
  /// What announceNextSession publishes: the recording session, else the next id, in `state`.
  uw_multislam::SessionState sessionRequest(std::uint8_t state = uw_multislam::SessionState::ACTIVE) const;
  /// On active_session, next_session_only: another vehicle's session took an id, so our
  /// odometry's own next session takes a later one; the last request repeated, not renewed.
  void announceNextId();
  /// ~reload_stored: reloads every stored session (features stay in the store) for the loop detectors.
  void reloadStored();
  /// A new subscriber of reloaded_keyframes (a loop detector, also a respawned one) gets every
  /// stored session handed over so far (hashes only when paging, else with their features read
  /// from the store), one session per state_mutex_ lock; diagnostics handover_*.
  void onReloadedSubscriber(const ros::SingleSubscriberPublisher& pub);
  /// The active session's relocalisation in another map (SessionManager::relocalise): logged when
  /// it changes, on /diagnostics, and its pose on relocalised_pose; nullopt when there is none.
  std::optional<core::SessionManager::Relocalisation> relocalise(int id);
  void onOdometryPose(const geometry_msgs::PoseWithCovarianceStampedConstPtr& msg);
  bool onJoin(uw_multislam::JoinSessions::Request& req, uw_multislam::JoinSessions::Response& res);
  bool onSplit(uw_multislam::SplitSession::Request& req, uw_multislam::SplitSession::Response& res);
  bool onList(uw_multislam::ListSessions::Request& req, uw_multislam::ListSessions::Response& res);
  bool onStart(uw_multislam::StartSession::Request& req, uw_multislam::StartSession::Response& res);
  /// finish_session: ends the recording session; active_session says FINISHED with the next id.
  bool onFinish(uw_multislam::FinishSession::Request& req, uw_multislam::FinishSession::Response& res);
  /// add_link: the operator's loop (SessionManager::addLink); the worker optimises what it left due.
  bool onAddLink(uw_multislam::AddLink::Request& req, uw_multislam::AddLink::Response& res);
  /// optimise: marks the maps whose loops wait due and wakes the worker, which solves them.
  bool onOptimise(uw_multislam::Optimise::Request& req, uw_multislam::Optimise::Response& res);
  /// history: the audit trail (SessionManager::history), the last `last` entries (0: all).
  bool onHistory(uw_multislam::History::Request& req, uw_multislam::History::Response& res);
  /// detect_loops: core::detectStoredLoops under the state lock (the worker waits meanwhile).
  bool onDetectLoops(uw_multislam::DetectLoops::Request& req, uw_multislam::DetectLoops::Response& res);
  /// set_mode: mapping | localisation (SessionManager::setLocalisation).
  bool onSetMode(uw_multislam::SetMode::Request& req, uw_multislam::SetMode::Response& res);
  bool onReload(uw_multislam::ReloadSession::Request& req, uw_multislam::ReloadSession::Response& res);
  /// unload_session (ReloadSession's request and answer): SessionManager::unload, then the loop
  /// detectors are told to forget the session (on reloaded_keyframes, in order) and later
  /// subscribers no longer get it.
  bool onUnload(uw_multislam::ReloadSession::Request& req, uw_multislam::ReloadSession::Response& res);
  /// The loop detectors forget the session (the notice on reloaded_keyframes), later subscribers
  /// do not get it, the live mosaic drops its images (under state_mutex_).
  void forgetSession(int id);
  /// delete_session: SessionManager::deleteSession; the loop detectors forget the session (as at
  /// unload_session) and its latched path topic gets an empty path.
  bool onDelete(uw_multislam::DeleteSession::Request& req, uw_multislam::DeleteSession::Response& res);
  bool onExport(uw_multislam::ExportSurvey::Request& req, uw_multislam::ExportSurvey::Response& res);
  /// keyframe_features: one stored keyframe's features for a loop detector that pages.
  bool onKeyframeFeatures(uw_multislam::KeyframeFeatures::Request& req, uw_multislam::KeyframeFeatures::Response& res);
  /// The live mosaic's thread (see "Threading model").
  void drawMosaics();
  /// Every counter, for /diagnostics and the periodic log line (under state_mutex_).
  std::vector<ros_diagnostics::Counter> counters() const;
  void logStats(const char* when);
  /// One INFO line, also when rosconsole is already shut down (see the .cpp).
  void say(const std::string& line) const;
  void fillDiagnostics(diagnostic_updater::DiagnosticStatusWrapper& stat);

  core::SlamConfig config_;
  ros_params::BackendNodeletOptions options_;
  std::unique_ptr<diagnostic_updater::Updater> updater_;
  ros_diagnostics::CounterStatus diagnostic_status_;  // the timer's thread only
  ros::WallTimer diagnostic_timer_, stats_timer_;

  std::unique_ptr<ros_work::BoundedWorkQueue<Message>> queue_;
  std::thread worker_;

  mutable std::mutex state_mutex_;  // guards everything below, up to frames_
  std::unique_ptr<core::SessionManager> manager_;
  std::deque<uw_multislam::LoopConstPtr> waiting_;
  bool publish_all_ = false;  // an event asked for every session to be published
  Counters counts_;
  core::LiveMosaicImages mosaic_images_;  // each keyframe's image, for the live mosaic
  struct MosaicStats {
    long published = 0;
    int drawn = 0, missing = 0;
    double ms = 0.0, resolution_m = 0.0;
  } mosaic_stats_;

  std::unique_ptr<ros_frames::FramePublisher> frames_;  // thread-safe on its own
  ros_frames::FrameStats frame_stats_;                  // the diagnostics timer's thread only

  std::map<int, double> offsets_;  // where each map is drawn in rviz (under state_mutex_)
  uw_multislam::SessionState announced_;  // the last active_session request (under state_mutex_)
  std::vector<int> handed_;         // stored sessions handed to the loop detectors (under state_mutex_)
  struct Handover {
    long subscribers = 0, total = 0, sent = 0;
    double seconds = 0.0;
  } handover_;  // the newest subscriber's handover of handed_ (under state_mutex_)
  long sessions_unloaded_ = 0;      // unload_session calls answered OK (under state_mutex_)
  long sessions_deleted_ = 0;       // delete_session calls answered OK (under state_mutex_)
  struct RelocalisationState {
    int session = -1, map = -1, loops = 0, keyframe = -1;
    long published = 0;
  } reloc_;  // the active session's (under state_mutex_)
  ros::WallTime markers_sent_;      // the last trajectory_markers
  ros::Publisher trajectory_pub_, markers_pub_, trajectory_markers_pub_, pose_pub_, keyframe_pose_pub_, active_pub_,
      reloaded_pub_, relocalised_pub_;
  std::map<int, ros::Publisher> path_pubs_;
  ros::Publisher mosaic_pub_;
  std::thread mosaic_thread_;
  std::mutex mosaic_wait_mutex_;  // guards mosaic_stop_ (with mosaic_wake_)
  std::condition_variable mosaic_wake_;
  bool mosaic_stop_ = false;
  std::atomic<bool> mosaic_due_{true};  // the active map changed since the last drawing
  std::mutex export_mutex_;             // one export at a time
  // Hash exchange between vehicles (~fleet/vehicle set).
  ros::Publisher fleet_pub_, foreign_pub_;
  struct FleetStats {
    long hashes_sent = 0, hash_bytes_sent = 0;          // ours, on fleet/hashes_out
    long hashes_received = 0, hash_bytes_received = 0;  // theirs taken (foreign keyframes)
    long refused = 0, sessions_ended = 0;               // theirs refused (settings, ids), notices
    long features_requested = 0, feature_bytes_received = 0, feature_failures = 0;  // under peer_mutex_
    long feature_timeouts = 0;     // calls left at ~fleet/peer_timeout_s (peer_mutex_)
  } fleet_;                        // under state_mutex_ except the features_* (peer_mutex_)
  mutable std::mutex peer_mutex_;  // guards peer_clients_ and fleet_.feature*
  std::map<std::string, ros::ServiceClient> peer_clients_;  // persistent, made again after a failure
  core::BoundedCalls peer_calls_;  // each call to another vehicle waited for at most ~fleet/peer_timeout_s
  // A vehicle whose last request timed out is not asked again before this (peer_mutex_).
  std::map<std::string, std::chrono::steady_clock::time_point> peer_quiet_until_;
  ros::Subscriber fleet_sub_;
  ros::ServiceServer join_srv_, split_srv_, list_srv_, start_srv_, reload_srv_, export_srv_, finish_srv_, link_srv_,
      optimise_srv_, detect_srv_, mode_srv_, history_srv_, unload_srv_, delete_srv_, features_srv_;
  ros::Subscriber keyframe_sub_, loop_sub_, pose_sub_;  // last: destroyed first
};

}  // namespace nodelets
}  // namespace uw_multislam
