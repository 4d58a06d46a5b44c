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
// Inputs:  keyframes (uw_multislam/Keyframe, from the odometry nodelet)
//          session_trajectory (uw_multislam/SessionTrajectory, from the back-end, optional)
// Outputs: loops (uw_multislam/Loop), keyframe_hashes (uw_multislam/KeyframeHash, global/both)
//
// Poses for local candidates: the latest optimised poses of the session when the back-end has
// published them (for the keyframes they cover, with the odometry covariances of the motions),
// else the chain of odometry motions carried by the Keyframe messages. Until the back-end
// publishes session_trajectory, the odometry chain is what is used.
//
// Threading model: the keyframe callback only pushes the message pointer onto a bounded FIFO
// (~queue_size keyframes, ros/work_queue.h) and returns; when full the OLDEST keyframe is dropped
// and counted (it is then never a loop candidate; a keyframe id gap is bridged with the next
// keyframe's odometry pose). Reloaded keyframes go into the same FIFO as priority items: served
// first, never dropped. The session_trajectory callback swaps the poses in under a mutex of its
// own. One worker thread owns the core::LoopDetector (hashing, candidate search, RANSAC
// verification) and publishes. On unload the FIFO is closed and the worker processes the
// keyframes still in it before it is joined. Counters are logged every ~stats_period_s and at shutdown, and published on
// /diagnostics every ~diagnostic_period s (WARN while drops, bad keyframes or id gaps grow).
#include <diagnostic_updater/diagnostic_updater.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>

#include <pluginlib/class_list_macros.hpp>

#include <algorithm>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#include "uw_multislam/Keyframe.h"
#include "uw_multislam/KeyframeHash.h"
#include "uw_multislam/Loop.h"
#include "uw_multislam/SessionTrajectory.h"
#include "uw_multislam/core/loops/loop_detector.h"
#include "uw_multislam/core/session/slam_config.h"
#include "uw_multislam/ros/conversions.h"
#include "uw_multislam/ros/diagnostics.h"
#include "uw_multislam/ros/pipeline_conversions.h"
#include "uw_multislam/ros/slam_params.h"
#include "uw_multislam/ros/topics.h"
#include "uw_multislam/ros/work_queue.h"

namespace uw_multislam {
namespace nodelets {

namespace rc = ros_conversions;

class LoopDetectorNodelet : public nodelet::Nodelet {
 public:
  ~LoopDetectorNodelet() override;

 private:
  /// What is known of one session: its cameras (the detector keeps pointers: never moved) and
  /// the chain of odometry motions, keyframe id = trajectory index.
  struct Session {
    std::deque<core::CameraIntrinsics> cameras;
    core::Trajectory odometry;
    std::vector<core::Pose2> odometry_poses;  // per keyframe id, as the messages said
  };
  /// A keyframe waiting for the worker: live (searched) or reloaded from the store (stored only).
  struct Work {
    uw_multislam::KeyframeConstPtr msg;
    bool reloaded = false;
  };
  struct Counters {
    long keyframes = 0, dropped = 0, bad = 0, gaps = 0, local = 0, global = 0, hashes = 0, reloaded = 0;
    long sessions = 0, stored = 0, local_candidates = 0, global_candidates = 0;
    double total_ms = 0.0, max_ms = 0.0;
  };

  void onInit() override;
  void readParameters();
  void onKeyframe(const uw_multislam::KeyframeConstPtr& msg);
  void onTrajectory(const uw_multislam::SessionTrajectoryConstPtr& msg);
  void onReloaded(const uw_multislam::KeyframeConstPtr& msg);
  /// A keyframe of a session reloaded from the store: stored as a candidate, not searched.
  void processReloaded(const uw_multislam::Keyframe& msg);
  void work();
  void process(const uw_multislam::Keyframe& msg);
  /// Appends keyframe k's motion to its session's chain (bridging lost keyframes); false if k
  /// is not after the chain's last keyframe.
  bool extendChain(Session* s, const rc::KeyframeData& k);
  /// The poses used for local candidates: optimised where the back-end has them.
  core::Trajectory candidateTrajectory(int session, const Session& s);
  void logStats(const char* when);
  void fillDiagnostics(diagnostic_updater::DiagnosticStatusWrapper& stat);

  std::string mode_ = "both";
  int queue_size_ = 100;
  double stats_period_s_ = 30.0;
  double diagnostic_period_s_ = 1.0;
  bool publish_hashes_ = true;
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

  ros::Publisher loop_pub_, hash_pub_;
  ros::Subscriber keyframe_sub_, trajectory_sub_, reloaded_sub_;  // last: destroyed first
};

LoopDetectorNodelet::~LoopDetectorNodelet() {
  diagnostic_timer_.stop();
  keyframe_sub_.shutdown();
  trajectory_sub_.shutdown();
  reloaded_sub_.shutdown();
  if (queue_) queue_->close();  // the worker processes what is queued, then returns
  if (worker_.joinable()) worker_.join();
  if (detector_) logStats("at shutdown");
}

void LoopDetectorNodelet::readParameters() {
  ros::NodeHandle& pnh = getPrivateNodeHandle();
  using ros_params::param;
  mode_ = param(pnh, "mode", std::string("both"),
                [](const std::string& m) { return m == "both" || m == "local" || m == "global"; },
                "one of both, local, global");
  queue_size_ = param(pnh, "queue_size", 100, [](int v) { return v >= 1 && v <= 100000; }, "in [1, 100000]");
  stats_period_s_ = param(pnh, "stats_period_s", 30.0, [](double v) { return v > 0; }, "positive");
  diagnostic_period_s_ = param(pnh, "diagnostic_period", 1.0, [](double v) { return v > 0; }, "positive");
  config_ = ros_params::slamConfigFromParams(getNodeHandle());
  const std::string bad = config_.validate();
  if (!bad.empty()) throw std::invalid_argument(getNodeHandle().resolveName("slam") + ": " + bad);
  config_.loops.local.enabled = config_.loops.local.enabled && mode_ != "global";
  config_.loops.global.enabled = config_.loops.global.enabled && mode_ != "local";
  publish_hashes_ = mode_ != "local";
}

void LoopDetectorNodelet::onInit() {
  try {
    readParameters();
    queue_ = std::make_unique<ros_work::BoundedWorkQueue<Work>>(static_cast<std::size_t>(queue_size_));
    detector_ = std::make_unique<core::LoopDetector>(config_.loops, config_.odometry.matching, config_.odometry.ransac,
                                                     config_.odometry.features.num_features);
  } catch (const std::exception& e) {
    NODELET_FATAL("loop detector: invalid parameters, not starting: %s", e.what());
    throw;
  }
  const auto& l = config_.loops;
  NODELET_INFO(
      "loop detector: mode %s (local %s: radius %.2f m up to %.2f m, %d candidates, %d inliers; global %s: "
      "hash %s, best_k %d, %d inliers, seed %llu), queue_size %d (oldest dropped when full), hashes %s",
      mode_.c_str(), l.local.enabled ? "on" : "off", l.local.radius_m, l.local.max_radius_m, l.local.max_candidates,
      l.local.min_inliers, l.global.enabled ? "on" : "off", core::hashModeName(l.global.hash_mode).c_str(),
      l.global.best_k, l.global.min_inliers, static_cast<unsigned long long>(l.global.projection_seed), queue_size_,
      publish_hashes_ ? "published" : "not published");

  ros::NodeHandle& nh = getNodeHandle();
  loop_pub_ = nh.advertise<uw_multislam::Loop>(topics::kLoops, 100);
  if (publish_hashes_) hash_pub_ = nh.advertise<uw_multislam::KeyframeHash>(topics::kKeyframeHashes, 100);
  updater_ = std::make_unique<diagnostic_updater::Updater>(nh, getPrivateNodeHandle(), getName());
  updater_->setHardwareID("none");
  updater_->add("loop_detector", this, &LoopDetectorNodelet::fillDiagnostics);
  diagnostic_timer_ = nh.createWallTimer(ros::WallDuration(diagnostic_period_s_),
                                         [this](const ros::WallTimerEvent&) { updater_->force_update(); });
  worker_ = std::thread([this] { work(); });
  keyframe_sub_ = nh.subscribe(topics::kKeyframes, 100, &LoopDetectorNodelet::onKeyframe, this);
  trajectory_sub_ = nh.subscribe(topics::kSessionTrajectory, 10, &LoopDetectorNodelet::onTrajectory, this);
  reloaded_sub_ = nh.subscribe(topics::kReloadedKeyframes, 10000, &LoopDetectorNodelet::onReloaded, this);
}

void LoopDetectorNodelet::onKeyframe(const uw_multislam::KeyframeConstPtr& msg) { queue_->push(Work{msg, false}); }

void LoopDetectorNodelet::onReloaded(const uw_multislam::KeyframeConstPtr& msg) {
  queue_->pushPriority(Work{msg, true});  // never dropped
}

void LoopDetectorNodelet::processReloaded(const uw_multislam::Keyframe& msg) {
  rc::KeyframeData k;
  std::string why;
  if (!rc::fromMsg(msg, &k, &why)) {
    ++counts_.bad;
    NODELET_WARN_THROTTLE(5, "loop detector: bad reloaded keyframe skipped: %s", why.c_str());
    return;
  }
  Session& s = sessions_[k.session];
  if (s.cameras.empty() || s.cameras.back().fx != k.camera.fx || s.cameras.back().width != k.camera.width)
    s.cameras.push_back(k.camera);
  if (k.features.keypoints.empty()) return;  // a keyframe that never arrived live: no candidate
  detector_->addStoredKeyframe(k.session, k.keyframe, k.frame_index, k.altitude_m, &s.cameras.back(), k.features,
                               detector_->hasher().hash(k.features.descriptors));
  ++counts_.reloaded;
}

void LoopDetectorNodelet::onTrajectory(const uw_multislam::SessionTrajectoryConstPtr& msg) {
  if (msg->session < 0) return;
  std::lock_guard<std::mutex> lock(optimised_mutex_);
  optimised_[msg->session] = msg;
}

void LoopDetectorNodelet::work() {
  last_stats_ = ros::WallTime::now();
  Work w;
  while (queue_->pop(&w)) {  // false once closed and drained
    counts_.dropped = queue_->dropped();
    const ros::WallTime start = ros::WallTime::now();
    try {
      if (w.reloaded) {
        processReloaded(*w.msg);
      } else {
        process(*w.msg);
      }
    } catch (const std::exception& e) {
      ++counts_.bad;
      NODELET_ERROR_THROTTLE(5, "loop detector: keyframe %d of session %d skipped: %s", w.msg->keyframe,
                             w.msg->session, e.what());
    }
    const double ms = (ros::WallTime::now() - start).toSec() * 1e3;
    counts_.total_ms += ms;
    counts_.max_ms = std::max(counts_.max_ms, ms);
    counts_.sessions = static_cast<long>(sessions_.size());
    counts_.stored = static_cast<long>(detector_->size());
    counts_.local_candidates = detector_->stats().local_candidates;
    counts_.global_candidates = detector_->stats().global_candidates;
    {
      std::lock_guard<std::mutex> lock(stats_mutex_);
      published_ = counts_;
    }
    if ((ros::WallTime::now() - last_stats_).toSec() >= stats_period_s_) {
      logStats("so far");
      last_stats_ = ros::WallTime::now();
    }
  }
}

bool LoopDetectorNodelet::extendChain(Session* s, const rc::KeyframeData& k) {
  const int next = static_cast<int>(s->odometry.numKeyframes());
  if (s->odometry_poses.empty()) {
    s->odometry_poses.push_back(core::Pose2());  // keyframe 0 is the session's origin
    if (k.keyframe == 0) return true;
  } else if (k.keyframe < next) {
    return false;  // repeated or out of order
  }
  if (k.keyframe > next) {
    // Lost keyframes: placeholders at the last known pose (never candidates: not stored in the
    // detector), then one motion from there to this keyframe by the odometry poses.
    ++counts_.gaps;
    NODELET_WARN_THROTTLE(5, "loop detector: session %d keyframes %d..%d lost, bridged by odometry poses", k.session,
                          next, k.keyframe - 1);
    const core::Pose2 last = s->odometry_poses.back();
    while (static_cast<int>(s->odometry.numKeyframes()) < k.keyframe) {
      s->odometry.append(core::UncertainPose2::exact(core::Pose2()));
      s->odometry_poses.push_back(last);
    }
    s->odometry.append(core::UncertainPose2(core::between(last, k.odometry_pose), k.motion.covariance));
  } else {
    s->odometry.append(k.motion);
  }
  s->odometry_poses.push_back(k.odometry_pose);
  return true;
}

core::Trajectory LoopDetectorNodelet::candidateTrajectory(int session, const Session& s) {
  uw_multislam::SessionTrajectoryConstPtr opt;
  {
    std::lock_guard<std::mutex> lock(optimised_mutex_);
    auto it = optimised_.find(session);
    if (it != optimised_.end()) opt = it->second;
  }
  if (!opt || opt->poses.size() < 2) return s.odometry;
  core::Trajectory t;
  const std::size_t n = s.odometry.numKeyframes();
  const std::size_t m = std::min(opt->poses.size(), n);
  for (std::size_t k = 1; k < n; ++k) {
    const core::UncertainPose2& odo = s.odometry.motion(k);
    if (k < m) {
      t.append(core::UncertainPose2(core::between(rc::fromMsg(opt->poses[k - 1]), rc::fromMsg(opt->poses[k])),
                                    odo.covariance));
    } else {
      t.append(odo);
    }
  }
  return t;
}

void LoopDetectorNodelet::process(const uw_multislam::Keyframe& msg) {
  ++counts_.keyframes;
  rc::KeyframeData k;
  std::string why;
  if (!rc::fromMsg(msg, &k, &why)) {
    ++counts_.bad;
    NODELET_WARN_THROTTLE(5, "loop detector: bad keyframe skipped: %s (%ld so far)", why.c_str(), counts_.bad);
    return;
  }
  Session& s = sessions_[k.session];
  if (!extendChain(&s, k)) {
    ++counts_.bad;
    NODELET_WARN_THROTTLE(5, "loop detector: keyframe %d of session %d skipped: not after keyframe %zu", k.keyframe,
                          k.session, s.odometry.numKeyframes() - 1);
    return;
  }
  if (s.cameras.empty() || s.cameras.back().width != k.camera.width || s.cameras.back().fx != k.camera.fx ||
      s.cameras.back().fy != k.camera.fy || s.cameras.back().cx != k.camera.cx ||
      s.cameras.back().cy != k.camera.cy || s.cameras.back().height != k.camera.height) {
    s.cameras.push_back(k.camera);
  }
  const core::Trajectory trajectory = candidateTrajectory(k.session, s);
  const std::vector<core::Loop> loops = detector_->addKeyframe(k.session, k.keyframe, k.frame_index, k.altitude_m,
                                                               &s.cameras.back(), k.features, trajectory);
  for (const core::Loop& l : loops) {
    loop_pub_.publish(boost::make_shared<uw_multislam::Loop>(rc::toLoopMsg(l, msg.header)));
    ++(l.kind == core::Loop::Kind::kLocal ? counts_.local : counts_.global);
    NODELET_DEBUG("loop detector: %s loop %d/%d -> %d/%d, %d inliers", core::loopKindName(l.kind).c_str(),
                  l.session_a, l.keyframe_a, l.session_b, l.keyframe_b, l.inliers);
  }
  if (publish_hashes_) {
    rc::KeyframeHashData h;
    h.session = k.session;
    h.keyframe = k.keyframe;
    h.frame_index = k.frame_index;
    h.mode = config_.loops.global.hash_mode;
    h.projection_seed = config_.loops.global.projection_seed;
    h.num_features = config_.odometry.features.num_features;
    h.values = detector_->hasher().hash(k.features.descriptors);  // the detector's own hash, recomputed
    hash_pub_.publish(boost::make_shared<uw_multislam::KeyframeHash>(rc::toKeyframeHashMsg(h, msg.header)));
    ++counts_.hashes;
  }
}

void LoopDetectorNodelet::fillDiagnostics(diagnostic_updater::DiagnosticStatusWrapper& stat) {
  Counters c;
  {
    std::lock_guard<std::mutex> lock(stats_mutex_);
    c = published_;
  }
  const long dropped = queue_->dropped(), queued = static_cast<long>(queue_->size());
  const double n = static_cast<double>(c.keyframes);
  stat.add("mode", mode_);
  diagnostic_status_.fill(stat,
                          {{"keyframes_received", n},
                           {"dropped_queue_full", static_cast<double>(dropped), true},
                           {"queue_length", static_cast<double>(queued)},
                           {"skipped_bad_keyframe", static_cast<double>(c.bad), true},
                           {"keyframe_id_gaps", static_cast<double>(c.gaps), true},
                           {"sessions", static_cast<double>(c.sessions)},
                           {"keyframes_stored", static_cast<double>(c.stored)},
                           {"local_candidates", static_cast<double>(c.local_candidates)},
                           {"global_candidates", static_cast<double>(c.global_candidates)},
                           {"local_loops", static_cast<double>(c.local)},
                           {"global_loops", static_cast<double>(c.global)},
                           {"hashes", static_cast<double>(c.hashes)},
                           {"keyframes_reloaded", static_cast<double>(c.reloaded)},
                           {"ms_per_keyframe_mean", n > 0 ? c.total_ms / n : 0.0},
                           {"ms_per_keyframe_max", c.max_ms}},
                          ros::WallTime::now().toSec());
}

void LoopDetectorNodelet::logStats(const char* when) {
  const core::LoopStats& s = detector_->stats();
  NODELET_INFO(
      "loop detector (%s) %s: %ld keyframes received, %ld dropped (queue full), %ld bad, %ld id gaps; "
      "%ld local loops (%d candidates), %ld global loops (%d candidates), %ld hashes, %zu keyframes stored",
      mode_.c_str(), when, counts_.keyframes, counts_.dropped, counts_.bad, counts_.gaps, counts_.local,
      s.local_candidates, counts_.global, s.global_candidates, counts_.hashes, detector_->size());
}

}  // namespace nodelets
}  // namespace uw_multislam

PLUGINLIB_EXPORT_CLASS(uw_multislam::nodelets::LoopDetectorNodelet, nodelet::Nodelet)
