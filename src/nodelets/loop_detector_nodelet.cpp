// uw_multislam/LoopDetector: the nodelet's definitions; modes, topics and threading are
// documented with the class in include/uw_multislam/ros/nodelets/loop_detector_nodelet.h.
#include "uw_multislam/ros/nodelets/loop_detector_nodelet.h"

#include <pluginlib/class_list_macros.hpp>

#include <algorithm>

#include "uw_multislam/KeyframeHash.h"
#include "uw_multislam/Loop.h"
#include "uw_multislam/ros/conversions.h"
#include "uw_multislam/ros/slam_params.h"
#include "uw_multislam/ros/topics.h"

namespace uw_multislam {
namespace nodelets {

namespace rc = ros_conversions;

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
  options_ = ros_params::loopDetectorNodeletOptions(getPrivateNodeHandle());
  config_ = ros_params::slamConfigFromParams(getNodeHandle());
  const std::string bad = config_.validate();
  if (!bad.empty()) throw std::invalid_argument(getNodeHandle().resolveName("slam") + ": " + bad);
  config_.loops.local.enabled = config_.loops.local.enabled && options_.mode != "global";
  config_.loops.global.enabled = config_.loops.global.enabled && options_.mode != "local";
}

void LoopDetectorNodelet::onInit() {
  try {
    readParameters();
    queue_ = std::make_unique<ros_work::BoundedWorkQueue<Work>>(static_cast<std::size_t>(options_.queue_size));
    detector_ = std::make_unique<core::LoopDetector>(config_.loops, config_.odometry.matching, config_.odometry.ransac,
                                                     config_.odometry.features.num_features);
    // Always: stored keyframes when paging, and other vehicles' keyframes (foreign_keyframes) in
    // any case, are read through the back-end's keyframe_features when they are candidates.
    detector_->setFeatureLoader([this](int session, int keyframe) { return loadFeatures(session, keyframe); });
    live_paging_ = config_.loops.page_stored && config_.loops.page_live_after > 0;
  } catch (const std::exception& e) {
    NODELET_FATAL("loop detector: invalid parameters, not starting: %s", e.what());
    throw;
  }
  const auto& l = config_.loops;
  NODELET_INFO(
      "loop detector: mode %s (local %s: radius %.2f m up to %.2f m, %d candidates, %d inliers; global %s: "
      "hash %s, best_k %d, %d inliers, seed %llu), queue_size %d (oldest dropped when full), max_keyframe_gap %d, "
      "hashes %s, stored keyframes %s",
      options_.mode.c_str(), l.local.enabled ? "on" : "off", l.local.radius_m, l.local.max_radius_m,
      l.local.max_candidates, l.local.min_inliers, l.global.enabled ? "on" : "off",
      core::hashModeName(l.global.hash_mode).c_str(), l.global.best_k, l.global.min_inliers,
      static_cast<unsigned long long>(l.global.projection_seed), options_.queue_size, options_.max_keyframe_gap,
      options_.publishHashes() ? "published" : "not published",
      l.page_stored ? ("paged (features from the back-end's store through a " + std::to_string(l.feature_cache_mb) +
                       " MiB cache)").c_str()
                    : "kept in RAM with their features");

  ros::NodeHandle& nh = getNodeHandle();
  loop_pub_ = nh.advertise<uw_multislam::Loop>(topics::kLoops, 100);
  if (options_.publishHashes()) hash_pub_ = nh.advertise<uw_multislam::KeyframeHash>(topics::kKeyframeHashes, 100);
  updater_ = std::make_unique<diagnostic_updater::Updater>(nh, getPrivateNodeHandle(), getName());
  updater_->setHardwareID("none");
  updater_->add("loop_detector", this, &LoopDetectorNodelet::fillDiagnostics);
  diagnostic_timer_ = nh.createWallTimer(ros::WallDuration(options_.diagnostic_period_s),
                                         [this](const ros::WallTimerEvent&) { updater_->force_update(); });
  worker_ = std::thread([this] { work(); });
  keyframe_sub_ = nh.subscribe(topics::kKeyframes, 100, &LoopDetectorNodelet::onKeyframe, this);
  trajectory_sub_ = nh.subscribe(topics::kSessionTrajectory, 10, &LoopDetectorNodelet::onTrajectory, this);
  // Unbounded (0), as the back-end's publisher: a store's handover is never dropped; the callback
  // only moves each message onto the work queue (pushPriority, never dropped either).
  reloaded_sub_ = nh.subscribe(topics::kReloadedKeyframes, 0, &LoopDetectorNodelet::onReloaded, this);
  if (config_.loops.global.enabled)  // local loops never involve another vehicle's keyframes
    foreign_sub_ = nh.subscribe<uw_multislam::Keyframe>(topics::kForeignKeyframes, 100,
                                                        [this](const uw_multislam::KeyframeConstPtr& msg) {
                                                          queue_->push(Work{msg, false, true});
                                                        });
}

void LoopDetectorNodelet::onKeyframe(const uw_multislam::KeyframeConstPtr& msg) { queue_->push(Work{msg, false}); }

void LoopDetectorNodelet::onReloaded(const uw_multislam::KeyframeConstPtr& msg) {
  queue_->pushPriority(Work{msg, true});  // never dropped
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
    ++counts_.bad;
    NODELET_WARN_THROTTLE(5, "loop detector: bad reloaded keyframe skipped: %s", why.c_str());
    return;
  }
  if (detector_->has(k.session, k.keyframe)) {  // sent again (the back-end sends every subscriber all it handed over)
    ++counts_.reloaded_again;
    return;
  }
  Session& s = session(k.session);
  const core::CameraIntrinsics* camera = s.camera(k.camera);
  if (k.features.keypoints.empty()) {
    // Paged: its hash and ids only, its features asked for when it is a candidate. Without a hash
    // (or not paging): a keyframe that never arrived live, no candidate.
    if (!config_.loops.page_stored || k.hash.size() == 0) return;
    detector_->addPagedKeyframe(k.session, k.keyframe, k.frame_index, k.altitude_m, camera, k.hash);
    ++counts_.reloaded;
    ++counts_.paged;
    return;
  }
  const Eigen::VectorXf hash = k.hash.size() > 0 ? k.hash : detector_->hasher().hash(k.features.descriptors);
  detector_->addStoredKeyframe(k.session, k.keyframe, k.frame_index, k.altitude_m, camera, k.features, hash);
  ++counts_.reloaded;
}

void LoopDetectorNodelet::processForeign(const uw_multislam::Keyframe& msg) {
  rc::KeyframeData k;
  std::string why;
  if (!rc::fromMsg(msg, &k, &why) || k.hash.size() == 0) {
    ++counts_.bad;
    NODELET_WARN_THROTTLE(5, "loop detector: another vehicle's keyframe skipped: %s",
                          why.empty() ? "no hash" : why.c_str());
    return;
  }
  const auto own = sessions_.find(k.session);
  if (detector_->has(k.session, k.keyframe) || (own != sessions_.end() && own->second.chain.numKeyframes() > 0)) {
    ++counts_.bad;  // held already, or the id is one of our sessions here: never mixed
    NODELET_WARN_THROTTLE(5,
                          "loop detector: another vehicle's keyframe %d of session %d skipped: held already, or "
                          "the id is one of ours here",
                          k.keyframe, k.session);
    return;
  }
  foreign_sessions_.insert(k.session);
  const std::vector<core::Loop> loops = detector_->addForeignKeyframe(
      k.session, k.keyframe, k.frame_index, k.altitude_m, session(k.session).camera(k.camera), k.hash);
  ++counts_.foreign;
  for (const core::Loop& l : loops) {
    loop_pub_.publish(boost::make_shared<uw_multislam::Loop>(rc::toLoopMsg(l, msg.header)));
    ++counts_.global;
    ++counts_.foreign_loops;
  }
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
      } else if (w.foreign) {
        processForeign(*w.msg);
      } else {
        process(*w.msg);
      }
    } catch (const std::exception& e) {
      ++counts_.bad;
      NODELET_ERROR_THROTTLE(5, "loop detector: keyframe %d of session %d skipped: %s", w.msg->keyframe, w.msg->session,
                             e.what());
    }
    const double ms = (ros::WallTime::now() - start).toSec() * 1e3;
    counts_.total_ms += ms;
    counts_.max_ms = std::max(counts_.max_ms, ms);
    counts_.sessions = static_cast<long>(sessions_.size());
    counts_.stored = static_cast<long>(detector_->size());
    counts_.local_candidates = detector_->stats().local_candidates;
    counts_.global_candidates = detector_->stats().global_candidates;
    if (const core::FeatureCache* cache = detector_->featureCache()) {
      counts_.cache_hits = cache->stats().hits;
      counts_.cache_misses = cache->stats().misses;
      counts_.cache_mb = static_cast<double>(cache->bytes()) / (1024.0 * 1024.0);
    }
    counts_.read_failures = detector_->stats().feature_read_failures;
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
  uw_multislam::SessionTrajectoryConstPtr opt;
  {
    std::lock_guard<std::mutex> lock(optimised_mutex_);
    auto it = optimised_.find(session);
    if (it != optimised_.end()) opt = it->second;
  }
  std::vector<core::Pose2> poses;
  if (!opt) return poses;
  poses.reserve(opt->poses.size());
  for (const auto& p : opt->poses) poses.push_back(rc::fromMsg(p));
  return poses;
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
  if (foreign_sessions_.count(k.session)) {  // an id another vehicle's session holds here: never mixed
    ++counts_.bad;
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
      ++counts_.gaps;
      NODELET_WARN_THROTTLE(5, "loop detector: session %d keyframes %d..%d lost, bridged by odometry poses", k.session,
                            before, k.keyframe - 1);
      break;
    case core::SessionChain::Append::kStale:
      ++counts_.bad;
      NODELET_WARN_THROTTLE(5,
                            "loop detector: keyframe %d of session %d skipped: not after keyframe %d (%ld bad so far)",
                            k.keyframe, k.session, before - 1, counts_.bad);
      return;
    case core::SessionChain::Append::kTooFar:
      ++counts_.bad;
      NODELET_WARN_THROTTLE(5,
                            "loop detector: keyframe %d of session %d skipped: the id jumped too far, more than "
                            "~max_keyframe_gap %d keyframes after keyframe %d (a corrupt id?) (%ld bad so far)",
                            k.keyframe, k.session, options_.max_keyframe_gap, before - 1, counts_.bad);
      return;
  }
  const core::Trajectory trajectory = s.chain.candidateTrajectory(optimisedPoses(k.session));
  const std::vector<core::Loop> loops = detector_->addKeyframe(k.session, k.keyframe, k.frame_index, k.altitude_m,
                                                               s.camera(k.camera), k.features, trajectory,
                                                               &k.hash);  // hashed here only when k.hash is empty
  for (const core::Loop& l : loops) {
    loop_pub_.publish(boost::make_shared<uw_multislam::Loop>(rc::toLoopMsg(l, msg.header)));
    ++(l.kind == core::Loop::Kind::kLocal ? counts_.local : counts_.global);
    NODELET_DEBUG("loop detector: %s loop %d/%d -> %d/%d, %d inliers", core::loopKindName(l.kind).c_str(), l.session_a,
                  l.keyframe_a, l.session_b, l.keyframe_b, l.inliers);
  }
  if (options_.publishHashes()) {
    rc::KeyframeHashData h;
    h.session = k.session;
    h.keyframe = k.keyframe;
    h.frame_index = k.frame_index;
    h.mode = config_.loops.global.hash_mode;
    h.projection_seed = config_.loops.global.projection_seed;
    h.num_features = config_.odometry.features.num_features;
    h.features = config_.odometry.features.type;
    h.values = detector_->lastHash();  // the message's hash (or the detector's when it had none)
    hash_pub_.publish(boost::make_shared<uw_multislam::KeyframeHash>(rc::toKeyframeHashMsg(h, msg.header)));
    ++counts_.hashes;
  }
  pageOutBehind(k.session, k.keyframe);  // after publishing: the loops do not wait for it
}

core::FrameFeatures LoopDetectorNodelet::loadFeatures(int session, int keyframe) {
  uw_multislam::KeyframeFeatures srv;
  srv.request.session = session;
  srv.request.keyframe = keyframe;
  if (!callFeatures(&srv)) {
    NODELET_WARN_THROTTLE(5, "loop detector: %s not answering: stored keyframe %d/%d not verified",
                          getNodeHandle().resolveName(topics::kKeyframeFeaturesService).c_str(), session, keyframe);
    throw std::runtime_error("keyframe_features: no answer from the back-end");
  }
  if (srv.response.status.code != uw_multislam::Status::OK) {
    NODELET_WARN_THROTTLE(5, "loop detector: stored keyframe %d/%d not verified: %s", session, keyframe,
                          srv.response.status.message.c_str());
    throw std::runtime_error("keyframe_features: " + srv.response.status.message);
  }
  rc::KeyframeData k;
  std::string why;
  if (!rc::fromMsg(srv.response.keyframe, &k, &why)) throw std::runtime_error("keyframe_features: " + why);
  return k.features;
}

bool LoopDetectorNodelet::callFeatures(uw_multislam::KeyframeFeatures* srv) {
  // A persistent connection (one per call otherwise); made again after a failure (the back-end
  // respawned).
  if (!features_client_.isValid())
    features_client_ =
        getNodeHandle().serviceClient<uw_multislam::KeyframeFeatures>(topics::kKeyframeFeaturesService, true);
  if (features_client_.call(*srv)) return true;
  features_client_.shutdown();
  return false;
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
    uw_multislam::KeyframeFeatures srv;
    srv.request.session = session_id;
    srv.request.keyframe = keyframe;
    srv.request.check_only = true;
    if (!callFeatures(&srv)) return;  // the back-end is not answering: asked again at the next keyframe
    if (srv.response.status.code == uw_multislam::Status::FAILED_PRECONDITION) {
      live_paging_ = false;
      NODELET_INFO("loop detector: the back-end has no session store (%s): live keyframes stay in RAM",
                   srv.response.status.message.c_str());
      return;
    }
    if (srv.response.status.code != uw_multislam::Status::OK) return;  // not written yet: asked again later
    if (detector_->pageOut(session_id, keyframe)) ++counts_.paged_live;
    ++s.next_page_out;
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
  stat.add("mode", options_.mode);
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
                           {"keyframes_reloaded_again", static_cast<double>(c.reloaded_again)},
                           {"sessions_unloaded", static_cast<double>(c.sessions_unloaded)},
                           {"keyframes_unloaded", static_cast<double>(c.keyframes_unloaded)},
                           {"keyframes_paged", static_cast<double>(c.paged)},
                           {"keyframes_paged_live", static_cast<double>(c.paged_live)},
                           {"foreign_keyframes", static_cast<double>(c.foreign)},
                           {"foreign_loops", static_cast<double>(c.foreign_loops)},
                           {"feature_cache_hits", static_cast<double>(c.cache_hits)},
                           {"feature_cache_misses", static_cast<double>(c.cache_misses)},
                           {"feature_cache_mb", c.cache_mb},
                           {"feature_read_failures", static_cast<double>(c.read_failures), true},
                           {"ms_per_keyframe_mean", n > 0 ? c.total_ms / n : 0.0},
                           {"ms_per_keyframe_max", c.max_ms}},
                          ros::WallTime::now().toSec());
}

void LoopDetectorNodelet::logStats(const char* when) {
  const core::LoopStats& s = detector_->stats();
  NODELET_INFO(
      "loop detector (%s) %s: %ld keyframes received, %ld dropped (queue full), %ld bad, %ld id gaps; "
      "%ld local loops (%d candidates), %ld global loops (%d candidates), %ld hashes, %zu keyframes stored",
      options_.mode.c_str(), when, counts_.keyframes, counts_.dropped, counts_.bad, counts_.gaps, counts_.local,
      s.local_candidates, counts_.global, s.global_candidates, counts_.hashes, detector_->size());
}

}  // namespace nodelets
}  // namespace uw_multislam

PLUGINLIB_EXPORT_CLASS(uw_multislam::nodelets::LoopDetectorNodelet, nodelet::Nodelet)
