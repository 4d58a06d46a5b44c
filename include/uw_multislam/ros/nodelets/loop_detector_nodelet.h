// uw_multislam/LoopDetector: loop detection of paper 000 §6 (local) and §7 (global) around
// core::LoopDetector, which does both in one object.
//
// ~mode selects what this instance does:
//   both   (default) local and global loops in one nodelet: one copy of the stored keyframes.
//   local  only local loops (same session, by pose radius (4), verified (5)).
//   global only global loops (other sessions, by hash (8), verified (9)); publishes the hashes.
// The "local loops" and "global loops" nodelets are this nodelet loaded twice with
// mode local and mode global (launch/slam.launch, arg split_loops:=true); each instance then
// keeps its own copy of the keyframes' features (~66 kB per keyframe). loops.local.enabled and
// loops.global.enabled of the SLAM configuration still apply on top of the mode.
//
// Paging (issue 20; slam/loops/page_stored, default true): stored keyframes arrive on
// reloaded_keyframes with their hash only and are kept as hash + ids (core::LoopDetector's paged
// keyframes, a few kB each); when one is a candidate, its features are asked from the back-end's
// store (service keyframe_features, on the worker thread) through an LRU cache of
// slam/loops/feature_cache_mb. A failed read skips that candidate (counted:
// feature_read_failures). false: stored keyframes come with their features, all kept in RAM.
// With page_stored, a live keyframe slam/loops/page_live_after keyframes behind its session's
// newest is paged out as well once the back-end's store has it (keyframe_features check_only, one
// small call per keyframe; NOT_FOUND: asked again at the next keyframe; FAILED_PRECONDITION, no
// store: live keyframes stay in RAM from then on), so a long session's RSS stays flat.
//
// Inputs:  keyframes (uw_multislam/Keyframe, from the odometry nodelet)
//          session_trajectory (uw_multislam/SessionTrajectory, from the back-end, optional)
// Outputs: loops (uw_multislam/Loop), keyframe_hashes (uw_multislam/KeyframeHash, global/both)
// The keyframe's hash comes with the Keyframe message (computed once by the odometry nodelet);
// only a message without one (an older sender) is hashed here.
//
// Poses for local candidates: each session's core::SessionChain (core/loops/session_chain.h, the
// same code the offline pipeline uses) of the odometry motions carried by the Keyframe messages,
// with the latest optimised poses of the session where the back-end has published them (for the
// keyframes they cover, with the odometry covariances of the motions). Until the back-end
// publishes session_trajectory, the odometry chain is what is used. A gap in the keyframe ids
// (keyframes dropped on the way) is bridged by placeholders that are never loop candidates; a
// keyframe repeated or out of order, or whose id jumps more than ~max_keyframe_gap past the
// chain's end (a corrupt id), is counted as bad and skipped.
//
// Threading model: the keyframe callback only pushes the message pointer onto a bounded FIFO
// (~queue_size keyframes, ros/work_queue.h) and returns; when full the OLDEST keyframe is dropped
// and counted (it is then never a loop candidate; a keyframe id gap is bridged with the next
// keyframe's odometry pose). Reloaded keyframes go into the same FIFO as priority items: served
// first, never dropped. The session_trajectory callback swaps the poses in under a mutex of its
// own. One worker thread owns the core::LoopDetector (candidate search, RANSAC verification)
// and publishes. On unload the FIFO is closed and the worker processes the keyframes still in it
// before it is joined. Counters are logged every ~stats_period_s and at shutdown, and published
// on /diagnostics every ~diagnostic_period s (WARN while drops, bad keyframes or id gaps grow).
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
#include "uw_multislam/KeyframeFeatures.h"
#include "uw_multislam/SessionTrajectory.h"
#include "uw_multislam/core/loops/loop_detector.h"
#include "uw_multislam/core/loops/session_chain.h"
#include "uw_multislam/core/session/slam_config.h"
#include "uw_multislam/ros/diagnostics.h"
#include "uw_multislam/ros/pipeline_conversions.h"
#include "uw_multislam/ros/slam_params.h"
#include "uw_multislam/ros/work_queue.h"

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
    /// The camera to hold a keyframe with: the last one, or `c` appended when it differs (the
    /// detector keeps pointers into the deque, which never moves its elements).
    const core::CameraIntrinsics* camera(const core::CameraIntrinsics& c);
    int next_page_out = 0;  // live paging: the oldest keyframe not yet paged out
  };
  /// A keyframe waiting for the worker: live (searched) or reloaded from the store (stored only).
  struct Work {
    uw_multislam::KeyframeConstPtr msg;
    bool reloaded = false;
    bool foreign = false;  // another vehicle's keyframe (foreign_keyframes), hash only
  };
  struct Counters {
    long keyframes = 0, dropped = 0, bad = 0, gaps = 0, local = 0, global = 0, hashes = 0, reloaded = 0, reloaded_again = 0;
    long sessions = 0, stored = 0, local_candidates = 0, global_candidates = 0;
    long sessions_unloaded = 0, keyframes_unloaded = 0;
    long paged = 0;  // stored keyframes kept as hash + ids (page_stored)
    long foreign = 0, foreign_loops = 0;  // other vehicles' keyframes searched and held, the loops they closed
    long paged_live = 0;  // live keyframes paged out behind their session (page_live_after)
    long cache_hits = 0, cache_misses = 0, read_failures = 0;
    double cache_mb = 0.0;
    double total_ms = 0.0, max_ms = 0.0;
  };

  void onInit() override;
  void readParameters();
  void onKeyframe(const uw_multislam::KeyframeConstPtr& msg);
  void onTrajectory(const uw_multislam::SessionTrajectoryConstPtr& msg);
  void onReloaded(const uw_multislam::KeyframeConstPtr& msg);
  /// A keyframe of a session reloaded from the store: stored as a candidate, not searched.
  void processReloaded(const uw_multislam::Keyframe& msg);
  /// Another vehicle's keyframe (hash only): searched against ours, then held paged
  /// (core::LoopDetector::addForeignKeyframe); the loops it closes are published.
  void processForeign(const uw_multislam::Keyframe& msg);
  void work();
  void process(const uw_multislam::Keyframe& msg);
  /// The session `id`, created empty on first use.
  Session& session(int id);
  /// The optimised poses the back-end last published for `session` (empty: none yet).
  std::vector<core::Pose2> optimisedPoses(int session);
  void logStats(const char* when);
  /// The loader of paged keyframes: keyframe_features from the back-end (the worker's thread).
  /// Throws std::runtime_error with the reason when the call fails or is refused.
  core::FrameFeatures loadFeatures(int session, int keyframe);
  /// keyframe_features through features_client_ (made again after a failure); false: no answer.
  bool callFeatures(uw_multislam::KeyframeFeatures* srv);
  /// Live paging: pages out the keyframes of `session` page_live_after behind `newest` that the
  /// back-end's store has (see above).
  void pageOutBehind(int session, int newest);
  void fillDiagnostics(diagnostic_updater::DiagnosticStatusWrapper& stat);

  ros_params::LoopDetectorNodeletOptions options_;
  core::SlamConfig config_;
  std::unique_ptr<core::LoopDetector> detector_;

  // FIFO between the callbacks and the worker (created once ~queue_size is known).
  std::unique_ptr<ros_work::BoundedWorkQueue<Work>> queue_;
  std::thread worker_;
  std::mutex optimised_mutex_;
  std::map<int, uw_multislam::SessionTrajectoryConstPtr> optimised_;  // guarded by optimised_mutex_

  // Worker-only state.
  std::map<int, Session> sessions_;
  Counters counts_;
  ros::WallTime last_stats_;

  std::mutex stats_mutex_;
  Counters published_;  // guarded by stats_mutex_: the worker's counters for the diagnostics
  std::unique_ptr<diagnostic_updater::Updater> updater_;
  ros_diagnostics::CounterStatus diagnostic_status_;  // the timer's thread only
  ros::WallTimer diagnostic_timer_;

  ros::ServiceClient features_client_;  // the worker's only (page_stored)
  bool live_paging_ = false;            // the worker's: page_stored, page_live_after > 0 and a store
  ros::Publisher loop_pub_, hash_pub_;
  std::set<int> foreign_sessions_;  // ids of other vehicles' sessions (the worker's only)
  ros::Subscriber keyframe_sub_, trajectory_sub_, reloaded_sub_, foreign_sub_;  // last: destroyed first
};

}  // namespace nodelets
}  // namespace uw_multislam
