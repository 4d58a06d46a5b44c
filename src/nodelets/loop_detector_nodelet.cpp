// uw_multislam/LoopDetector: wiring, conversions and the worker's loop (doc/nodes/loop_detector.md, doc/ros_api.md).
#include "uw_multislam/ros/nodelets/loop_detector_nodelet.h"

#include <pluginlib/class_list_macros.hpp>

#include <algorithm>

#include "uw_multislam/core/common/thread_priority.h"
#include "uw_multislam/ros/conversions.h"
#include "uw_multislam/ros/pipeline_conversions.h"
#include "uw_multislam/ros/topics.h"

namespace uw_multislam {
namespace nodelets {

namespace rc = ros_conversions;
using ros_diagnostics::LoopDetectorCounters;

LoopDetectorNodelet::~LoopDetectorNodelet() {
  diagnostic_timer_.stop();
  keyframe_sub_.shutdown();
  trajectory_sub_.shutdown();
  reloaded_sub_.shutdown();
  if (queue_) queue_->close();  // the worker processes what is queued, then returns
  if (worker_.joinable()) worker_.join();
  if (detector_) logStats("at shutdown");
}

void LoopDetectorNodelet::onInit() {
  ros::NodeHandle& nh = getNodeHandle();
  try {
    options_ = ros_params::loopDetectorNodeletOptions(getPrivateNodeHandle());
    config_ = ros_params::loopDetectorConfig(nh, options_);
    queue_ = std::make_unique<core::BoundedWorkQueue<Work>>(static_cast<std::size_t>(options_.queue_size));
    detector_ = std::make_unique<core::LoopDetector>(config_.loops, config_.odometry.matching, config_.odometry.ransac,
                                                     config_.odometry.features.num_features);
    // Always: stored keyframes when paging, and other vehicles' keyframes (foreign_keyframes) in
    // any case, are read through the back-end's keyframe_features when they are candidates.
    features_ = std::make_unique<ros_inputs::KeyframeFeaturesClient>(nh);
    detector_->setFeatureLoader([this](int session, int keyframe) { return features_->load(session, keyframe); });
    live_paging_ = config_.loops.page_stored && config_.loops.page_live_after > 0;
  } catch (const std::exception& e) {
    NODELET_FATAL("loop detector: invalid parameters, not starting: %s", e.what());
    throw;
  }
  NODELET_INFO("loop detector: %s", ros_params::describe(options_, config_).c_str());
  loops_ = std::make_unique<ros_outputs::LoopPublisher>(nh, options_.publishHashes(), config_);
  updater_ = std::make_unique<diagnostic_updater::Updater>(nh, getPrivateNodeHandle(), getName());
  updater_->setHardwareID("none");
  updater_->add("loop_detector", [this](diagnostic_updater::DiagnosticStatusWrapper& stat) {
    LoopDetectorCounters c;
    {
      std::lock_guard<std::mutex> lock(stats_mutex_);
      c = published_;
    }
    stat.add("mode", options_.mode);
    diagnostic_status_.fill(stat, ros_diagnostics::loopDetectorCounterTable().counters(snapshot(c)),
                            ros::WallTime::now().toSec());
  });
  diagnostic_timer_ = nh.createWallTimer(ros::WallDuration(options_.diagnostic_period_s),
                                         [this](const ros::WallTimerEvent&) { updater_->force_update(); });
  worker_ = std::thread([this] { work(); });
  using K = Work::Kind;
  keyframe_sub_ =
      nh.subscribe<uw_multislam::Keyframe>(topics::kKeyframes, 100, [this](const uw_multislam::KeyframeConstPtr& m) {
        queue_->push({m, K::kLive});
      });
  trajectory_sub_ = nh.subscribe<uw_multislam::SessionTrajectory>(
      topics::kSessionTrajectory, 10, [this](const uw_multislam::SessionTrajectoryConstPtr& msg) {
        if (msg->session < 0) return;
        std::vector<core::Pose2> poses;
        for (const auto& p : msg->poses) poses.push_back(rc::fromMsg(p));
        std::lock_guard<std::mutex> lock(optimised_mutex_);
        optimised_[msg->session] = std::move(poses);
      });
  // Unbounded (0), as the back-end's publisher: a store's handover is never dropped; the callback
  // only moves each message onto the work queue (pushPriority, never dropped either).
  reloaded_sub_ = nh.subscribe<uw_multislam::Keyframe>(topics::kReloadedKeyframes, 0,
                                                       [this](const uw_multislam::KeyframeConstPtr& m) {
                                                         queue_->pushPriority({m, K::kReloaded});
                                                       });
  if (config_.loops.global.enabled)  // local loops never involve another vehicle's keyframes
    foreign_sub_ = nh.subscribe<uw_multislam::Keyframe>(topics::kForeignKeyframes, 100,
                                                        [this](const uw_multislam::KeyframeConstPtr& m) {
                                                          queue_->push({m, K::kForeign});
                                                        });
}

void LoopDetectorNodelet::processReloaded(const uw_multislam::Keyframe& msg) {
  if (rc::isUnloadSessionMsg(msg)) {  // unload_session: forget the session
    const int n = detector_->dropSession(msg.session);
    sessions_.erase(msg.session);
    ++counts_.sessions_unloaded;
    counts_.keyframes_unloaded += n;
    NODELET_INFO("loop detector: session %d unloaded: %d keyframes forgotten, %zu held", msg.session, n,
                 detector_->size());
    return;
  }
  rc::KeyframeData k;
  std::string why;
  if (!rc::fromMsg(msg, &k, &why)) {
    ++counts_.skipped_bad_keyframe;
    NODELET_WARN_THROTTLE(5, "loop detector: bad reloaded keyframe skipped: %s", why.c_str());
    return;
  }
  if (detector_->has(k.session, k.keyframe)) {  // sent again (the back-end sends every subscriber all it handed over)
    ++counts_.keyframes_reloaded_again;
    return;
  }
  const core::CameraIntrinsics* camera = session(k.session).camera(k.camera);
  if (k.features.keypoints.empty()) {
    // Paged: its hash and ids only, its features asked for when it is a candidate. Without a hash
    // (or not paging): a keyframe that never arrived live, no candidate.
    if (!config_.loops.page_stored || k.hash.size() == 0) return;
    detector_->addPagedKeyframe(k.session, k.keyframe, k.frame_index, k.altitude_m, camera, k.hash);
    ++counts_.keyframes_reloaded;
    ++counts_.keyframes_paged;
    return;
  }
  const Eigen::VectorXf hash = k.hash.size() > 0 ? k.hash : detector_->hasher().hash(k.features.descriptors);
  detector_->addStoredKeyframe(k.session, k.keyframe, k.frame_index, k.altitude_m, camera, k.features, hash);
  ++counts_.keyframes_reloaded;
}

void LoopDetectorNodelet::processForeign(const uw_multislam::Keyframe& msg) {
  rc::KeyframeData k;
  std::string why;
  if (!rc::fromMsg(msg, &k, &why) || k.hash.size() == 0) {
    ++counts_.skipped_bad_keyframe;
    NODELET_WARN_THROTTLE(5, "loop detector: another vehicle's keyframe skipped: %s",
                          why.empty() ? "no hash" : why.c_str());
    return;
  }
  const auto own = sessions_.find(k.session);
  if (detector_->has(k.session, k.keyframe) || (own != sessions_.end() && own->second.chain.numKeyframes() > 0)) {
    ++counts_.skipped_bad_keyframe;  // held already, or the id is one of our sessions here: never mixed
    NODELET_WARN_THROTTLE(5,
                          "loop detector: another vehicle's keyframe %d of session %d skipped: held already, or "
                          "the id is one of ours here",
                          k.keyframe, k.session);
    return;
  }
  foreign_sessions_.insert(k.session);
  const std::vector<core::Loop> loops = detector_->addForeignKeyframe(
      k.session, k.keyframe, k.frame_index, k.altitude_m, session(k.session).camera(k.camera), k.hash);
  ++counts_.foreign_keyframes;
  long local = 0, global = 0;  // all global: another vehicle's keyframes close no local loop
  loops_->publish(loops, msg.header, &local, &global);
  counts_.global_loops += global, counts_.foreign_loops += global;
}

void LoopDetectorNodelet::work() {
  last_stats_ = ros::WallTime::now();
  std::string why;
  if (!core::setThisThreadNice(options_.worker_nice, &why)) NODELET_WARN("loop detector: worker_nice: %s", why.c_str());
  Work w;
  while (queue_->pop(&w)) {  // false once closed and drained
    const ros::WallTime start = ros::WallTime::now();
    try {
      if (w.kind == Work::Kind::kReloaded)
        processReloaded(*w.msg);
      else if (w.kind == Work::Kind::kForeign)
        processForeign(*w.msg);
      else
        process(*w.msg);
    } catch (const std::exception& e) {
      ++counts_.skipped_bad_keyframe;
      NODELET_ERROR_THROTTLE(5, "loop detector: keyframe %d of session %d skipped: %s", w.msg->keyframe, w.msg->session,
                             e.what());
    }
    const double ms = (ros::WallTime::now() - start).toSec() * 1e3;
    counts_.total_ms += ms;
    counts_.ms_per_keyframe_max = std::max(counts_.ms_per_keyframe_max, ms);
    counts_.sessions = static_cast<long>(sessions_.size());
    ros_diagnostics::setDetectorCounters(*detector_, &counts_);  // the worker's only
    {
      std::lock_guard<std::mutex> lock(stats_mutex_);
      published_ = counts_;
    }
    if ((ros::WallTime::now() - last_stats_).toSec() >= options_.stats_period_s) {
      logStats("so far");
      last_stats_ = ros::WallTime::now();
    }
  }
}

const core::CameraIntrinsics* LoopDetectorNodelet::Session::camera(const core::CameraIntrinsics& c) {
  const core::CameraIntrinsics* last = cameras.empty() ? nullptr : &cameras.back();
  if (!last || last->width != c.width || last->height != c.height || last->fx != c.fx || last->fy != c.fy ||
      last->cx != c.cx || last->cy != c.cy)
    cameras.push_back(c);
  return &cameras.back();
}

LoopDetectorNodelet::Session& LoopDetectorNodelet::session(int id) {
  return sessions_.try_emplace(id, options_.max_keyframe_gap).first->second;
}

std::vector<core::Pose2> LoopDetectorNodelet::optimisedPoses(int session) {
  std::lock_guard<std::mutex> lock(optimised_mutex_);
  const auto it = optimised_.find(session);
  return it == optimised_.end() ? std::vector<core::Pose2>() : it->second;
}

void LoopDetectorNodelet::process(const uw_multislam::Keyframe& msg) {
  ++counts_.keyframes_received;
  rc::KeyframeData k;
  std::string why;
  long& bad = counts_.skipped_bad_keyframe;
  if (!rc::fromMsg(msg, &k, &why)) {
    ++bad;
    NODELET_WARN_THROTTLE(5, "loop detector: bad keyframe skipped: %s (%ld so far)", why.c_str(), bad);
    return;
  }
  if (foreign_sessions_.count(k.session)) {  // an id another vehicle's session holds here: never mixed
    ++bad;
    NODELET_WARN_THROTTLE(5,
                          "loop detector: keyframe %d of session %d skipped: that id is another vehicle's session "
                          "here (the odometry's next session takes active_session's next_session)",
                          k.keyframe, k.session);
    return;
  }
  Session& s = session(k.session);
  const int before = s.chain.numKeyframes();
  switch (s.chain.append(k.keyframe, k.motion, k.odometry_pose)) {
    case core::SessionChain::Append::kAppended:
      break;
    case core::SessionChain::Append::kBridged:
      ++counts_.keyframe_id_gaps;
      NODELET_WARN_THROTTLE(5, "loop detector: session %d keyframes %d..%d lost, bridged by odometry poses", k.session,
                            before, k.keyframe - 1);
      break;
    case core::SessionChain::Append::kStale:
      ++bad;
      NODELET_WARN_THROTTLE(5,
                            "loop detector: keyframe %d of session %d skipped: not after keyframe %d (%ld bad so far)",
                            k.keyframe, k.session, before - 1, bad);
      return;
    case core::SessionChain::Append::kTooFar:
      ++bad;
      NODELET_WARN_THROTTLE(5,
                            "loop detector: keyframe %d of session %d skipped: the id jumped too far, more than "
                            "~max_keyframe_gap %d keyframes after keyframe %d (a corrupt id?) (%ld bad so far)",
                            k.keyframe, k.session, options_.max_keyframe_gap, before - 1, bad);
      return;
  }
  const core::Trajectory trajectory = s.chain.candidateTrajectory(optimisedPoses(k.session));
  const std::vector<core::Loop> loops = detector_->addKeyframe(k.session, k.keyframe, k.frame_index, k.altitude_m,
                                                               s.camera(k.camera), k.features, trajectory,
                                                               &k.hash);  // hashed here only when k.hash is empty
  loops_->publish(loops, msg.header, &counts_.local_loops, &counts_.global_loops);
  // The message's hash (or the detector's when it had none).
  counts_.hashes += loops_->publishHash(k, detector_->lastHash(), msg.header);
  pageOutBehind(k.session, k.keyframe);  // after publishing: the loops do not wait for it
}

void LoopDetectorNodelet::pageOutBehind(int session_id, int newest) {
  if (!live_paging_) return;
  Session& s = session(session_id);
  while (s.next_page_out <= newest - config_.loops.page_live_after) {
    const int keyframe = s.next_page_out;
    if (!detector_->has(session_id, keyframe)) {  // an id gap (a lost keyframe): nothing held
      ++s.next_page_out;
      continue;
    }
    std::uint8_t code = 0;
    std::string message;
    if (!features_->check(session_id, keyframe, &code, &message)) return;  // no answer: asked at the next keyframe
    if (code == uw_multislam::Status::FAILED_PRECONDITION) {
      live_paging_ = false;
      NODELET_INFO("loop detector: the back-end has no session store (%s): live keyframes stay in RAM",
                   message.c_str());
      return;
    }
    if (code != uw_multislam::Status::OK) return;  // not written yet: asked again later
    if (detector_->pageOut(session_id, keyframe)) ++counts_.keyframes_paged_live;
    ++s.next_page_out;
  }
}

LoopDetectorCounters LoopDetectorNodelet::snapshot(LoopDetectorCounters c) const {
  c.dropped_queue_full = queue_->dropped();
  c.queue_length = static_cast<long>(queue_->size());
  const double n = static_cast<double>(c.keyframes_received);
  c.ms_per_keyframe_mean = n > 0 ? c.total_ms / n : 0.0;
  return c;
}

void LoopDetectorNodelet::logStats(const std::string& when) {  // the worker's thread, or after it was joined
  NODELET_INFO("%s",
               ros_diagnostics::countersLine("loop detector (" + options_.mode + ") counters " + when + ":",
                                             ros_diagnostics::loopDetectorCounterTable().counters(snapshot(counts_)))
                   .c_str());
}

}  // namespace nodelets
}  // namespace uw_multislam

PLUGINLIB_EXPORT_CLASS(uw_multislam::nodelets::LoopDetectorNodelet, nodelet::Nodelet)
