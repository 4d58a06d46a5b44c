// The back-end / session manager nodelet: see its header for topics, services and threading.
#include "uw_multislam/ros/nodelets/backend_nodelet.h"

#include <pluginlib/class_list_macros.hpp>

#include <cv_bridge/cv_bridge.h>
#include <sensor_msgs/Image.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <utility>

#include "uw_multislam/SessionState.h"
#include "uw_multislam/SessionTrajectory.h"
#include "uw_multislam/core/session/export_root.h"
#include "uw_multislam/core/session/stored_loops.h"
#include "uw_multislam/core/session/track_files.h"
#include "uw_multislam/ros/backend_conversions.h"
#include "uw_multislam/ros/conversions.h"
#include "uw_multislam/ros/slam_params.h"
#include "uw_multislam/ros/topics.h"

namespace uw_multislam {
namespace nodelets {

namespace rc = ros_conversions;

BackendNodelet::~BackendNodelet() {
  if (mosaic_thread_.joinable()) {  // first: it takes state_mutex_
    {
      std::lock_guard<std::mutex> lock(mosaic_wait_mutex_);
      mosaic_stop_ = true;
    }
    mosaic_wake_.notify_all();
    mosaic_thread_.join();
  }
  diagnostic_timer_.stop();
  stats_timer_.stop();
  keyframe_sub_.shutdown();
  loop_sub_.shutdown();
  pose_sub_.shutdown();
  fleet_sub_.shutdown();
  if (queue_) {
    say("unloading: " + std::to_string(queue_->size()) + " messages queued, processed before the maps are saved");
    queue_->close();  // the worker processes what is queued, then stops
  }
  if (worker_.joinable()) worker_.join();
  if (!manager_) return;
  std::lock_guard<std::mutex> lock(state_mutex_);
  manager_->flush();  // pending optimisation, and the maps saved
  logStats("at shutdown");
  // Now, while every member is alive (onEvent reports them): other vehicles' sessions still
  // recording are finished in the store (the manager's destructor would do it otherwise).
  try {
    manager_->finishForeignSessions();
  } catch (const std::exception& e) {
    say(std::string("back-end: other vehicles' sessions not finished at shutdown: ") + e.what());
  }
}

void BackendNodelet::onInit() {
  // The manager (and the store behind it) first: nothing is advertised before it is usable, and
  // a refused store leaves the nodelet inert instead of throwing out of onInit (which took the
  // whole nodelet manager down with it).
  ros::NodeHandle& nh = getNodeHandle();
  try {
    options_ = ros_params::backendNodeletOptions(nh, getPrivateNodeHandle());
    config_ = ros_params::slamConfigFromParams(nh);
    const std::string bad = config_.validate();
    if (!bad.empty()) throw std::invalid_argument(nh.resolveName("slam") + ": " + bad);
    manager_ = std::make_unique<core::SessionManager>(
        ros_params::sessionManagerOptions(options_, config_), [this](const core::SessionEvent& e) { onEvent(e); },
        [this](const std::string& line) { say(line); });
    manager_->setDeferredOptimisation(true);  // optimised by the worker, outside state_mutex_
    if (options_.localisation) manager_->setLocalisation(true);  // ~mode: nothing written from the start
    frames_ = std::make_unique<ros_frames::FramePublisher>(nh, options_.frames);  // a tilted camera throws
    mosaic_images_ = core::LiveMosaicImages(options_.mosaic.resolution_m);  // kept at the mosaic's resolution
  } catch (const std::exception& e) {
    NODELET_FATAL(
        "back-end: not starting (no topics, no services): %s%s", e.what(),
        options_.store_path.empty() ? "" : " (set ~store_path to another file, or \"\" to run without a store)");
    return;
  }
  if (options_.store_path.empty()) NODELET_WARN("back-end: no session store (~store_path empty): in memory only");
  const auto& b = config_.backend;
  const ros_frames::FrameOptions& f = options_.frames;
  NODELET_INFO(
      "back-end: optimiser %s (optimise %s, every %d pending loops), join after %d global loops (gate %.2f m), "
      "tf %s (%s -> %s at %.0f Hz, %s -> %s from %s), queue_size %d, store %s",
      core::optimizerName(b.optimizer), b.optimise ? "on" : "off", b.optimise_every, b.join_min_loops, b.join_gate_m,
      f.publish_tf ? "on" : "off", f.map_frame.c_str(), f.odom_frame.c_str(), f.tf_rate_hz, f.odom_frame.c_str(),
      f.base_frame.c_str(), f.publish_odom_tf ? "the visual odometry" : "the vehicle (tf)", options_.queue_size,
      options_.store_path.empty() ? "none" : options_.store_path.c_str());
  trajectory_pub_ = nh.advertise<uw_multislam::SessionTrajectory>(topics::kSessionTrajectory, 10);
  markers_pub_ = nh.advertise<visualization_msgs::MarkerArray>(topics::kLoopMarkers, 1, true);
  trajectory_markers_pub_ = nh.advertise<visualization_msgs::MarkerArray>(topics::kTrajectoryMarkers, 1, true);
  pose_pub_ = nh.advertise<geometry_msgs::PoseStamped>(topics::kCurrentPose, 10);
  keyframe_pose_pub_ = nh.advertise<geometry_msgs::PoseWithCovarianceStamped>(topics::kKeyframePoseWithCovariance, 10);
  active_pub_ = nh.advertise<uw_multislam::SessionState>(topics::kActiveSession, 1, true);
  relocalised_pub_ = nh.advertise<geometry_msgs::PoseWithCovarianceStamped>(topics::kRelocalisedPose, 10);
  if (options_.reload_stored) reloadStored();
  // Unbounded (0): a store of a hundred dives hands over more keyframes than any fixed queue holds
  // (10000 was the limit before). The connection callback runs on the multi-threaded queue, so
  // the keyframe callbacks and the services go on while it hands a store over.
  reloaded_pub_ = getMTNodeHandle().advertise<uw_multislam::Keyframe>(
      topics::kReloadedKeyframes, 0, [this](const ros::SingleSubscriberPublisher& pub) { onReloadedSubscriber(pub); });
  mosaic_pub_ = nh.advertise<sensor_msgs::Image>(topics::kLiveMosaic, 1, true);
  if (!options_.export_root.empty()) {
    std::error_code ec;
    std::filesystem::create_directories(options_.export_root, ec);
    if (ec)
      NODELET_WARN("back-end: cannot create ~export_root %s (%s): export answers FAILED_PRECONDITION",
                   options_.export_root.c_str(), ec.message().c_str());
  }
  NODELET_INFO("back-end: live mosaic %s (%.2f Hz, %.3f m/px, at most %d px), exports below %s",
               options_.mosaic_rate_hz > 0 ? "on" : "off", options_.mosaic_rate_hz, options_.mosaic.resolution_m,
               options_.mosaic.max_side_px,
               options_.export_root.empty() ? "(none: off)" : options_.export_root.c_str());
  if (manager_->restoredSessions() > 0) {
    std::lock_guard<std::mutex> lock(state_mutex_);
    publishAll(true);
    announceNextSession();  // stored sessions hold ids 0..k-1: the odometry continues from k
  }
  queue_ = std::make_unique<ros_work::BoundedWorkQueue<Message>>(options_.queue_size);  // services wake it
  join_srv_ = nh.advertiseService(topics::kJoinSessionsService, &BackendNodelet::onJoin, this);
  split_srv_ = nh.advertiseService(topics::kSplitSessionService, &BackendNodelet::onSplit, this);
  list_srv_ = nh.advertiseService(topics::kListSessionsService, &BackendNodelet::onList, this);
  start_srv_ = nh.advertiseService(topics::kStartSessionService, &BackendNodelet::onStart, this);
  finish_srv_ = nh.advertiseService(topics::kFinishSessionService, &BackendNodelet::onFinish, this);
  link_srv_ = nh.advertiseService(topics::kAddLinkService, &BackendNodelet::onAddLink, this);
  optimise_srv_ = nh.advertiseService(topics::kOptimiseService, &BackendNodelet::onOptimise, this);
  detect_srv_ = nh.advertiseService(topics::kDetectLoopsService, &BackendNodelet::onDetectLoops, this);
  mode_srv_ = nh.advertiseService(topics::kSetModeService, &BackendNodelet::onSetMode, this);
  history_srv_ = nh.advertiseService(topics::kHistoryService, &BackendNodelet::onHistory, this);
  reload_srv_ = nh.advertiseService(topics::kReloadSessionService, &BackendNodelet::onReload, this);
  unload_srv_ = nh.advertiseService(topics::kUnloadSessionService, &BackendNodelet::onUnload, this);
  delete_srv_ = nh.advertiseService(topics::kDeleteSessionService, &BackendNodelet::onDelete, this);
  export_srv_ = nh.advertiseService(topics::kExportService, &BackendNodelet::onExport, this);
  // On the multi-threaded queue: a request forwarded to another vehicle waits up to
  // ~fleet/peer_timeout_s, and the keyframes, loops and the other services must not wait with it.
  features_srv_ =
      getMTNodeHandle().advertiseService(topics::kKeyframeFeaturesService, &BackendNodelet::onKeyframeFeatures, this);
  updater_ = std::make_unique<diagnostic_updater::Updater>(nh, getPrivateNodeHandle(), getName());
  updater_->setHardwareID("none");
  updater_->add("backend", this, &BackendNodelet::fillDiagnostics);
  diagnostic_timer_ = nh.createWallTimer(ros::WallDuration(options_.diagnostic_period_s),
                                         [this](const ros::WallTimerEvent&) { updater_->force_update(); });
  stats_timer_ = nh.createWallTimer(ros::WallDuration(options_.stats_period_s), [this](const ros::WallTimerEvent&) {
    std::lock_guard<std::mutex> lock(state_mutex_);
    logStats("so far");
  });
  worker_ = std::thread([this] { work(); });
  if (options_.mosaic_rate_hz > 0) mosaic_thread_ = std::thread([this] { drawMosaics(); });
  auto push = [this](const auto& m) { queue_->push(Message(m)); };  // keyframes and loops keep their order
  // roscpp's own queues as deep as ours: a starved callback thread must not drop uncounted.
  keyframe_sub_ = nh.subscribe<uw_multislam::Keyframe>(topics::kKeyframes, options_.queue_size, push);
  loop_sub_ = nh.subscribe<uw_multislam::Loop>(topics::kLoops, options_.queue_size, push);
  pose_sub_ = nh.subscribe(topics::kOdometryPose, 10, &BackendNodelet::onOdometryPose, this);
  if (!options_.fleet_vehicle.empty()) {
    {
      std::lock_guard<std::mutex> lock(state_mutex_);  // onEvent publishes on fleet_pub_ under it
      fleet_pub_ = nh.advertise<uw_multislam::KeyframeHash>(topics::kFleetHashesOut, options_.queue_size);
    }
    foreign_pub_ = nh.advertise<uw_multislam::Keyframe>(topics::kForeignKeyframes, options_.queue_size);
    // In the work queue with our keyframes and loops: a loop on another vehicle's keyframe finds it.
    fleet_sub_ = nh.subscribe<uw_multislam::KeyframeHash>(topics::kFleetHashesIn, options_.queue_size, push);
    std::string peers;
    for (const auto& [vehicle, service] : options_.fleet_peers) peers += " " + vehicle + " (" + service + ")";
    NODELET_INFO("back-end: hash exchange as vehicle %s: our keyframes on %s, theirs from %s; features of%s",
                 options_.fleet_vehicle.c_str(), nh.resolveName(topics::kFleetHashesOut).c_str(),
                 nh.resolveName(topics::kFleetHashesIn).c_str(),
                 peers.empty() ? " nobody (no ~fleet/peers)" : peers.c_str());
  }
}

void BackendNodelet::work() {
  Message m;
  while (queue_->pop(&m)) {
    const auto* k = std::get_if<uw_multislam::KeyframeConstPtr>(&m);
    const auto* h = std::get_if<uw_multislam::KeyframeHashConstPtr>(&m);
    if (k || h) {  // ours, or another vehicle's: the loops waiting for a keyframe are tried again
      std::deque<uw_multislam::LoopConstPtr> retry;
      step([&] { k ? processKeyframe(**k) : processFleetHash(**h), retry = std::exchange(waiting_, {}); });
      for (const auto& l : retry) step([&] { processLoop(l, true); });  // their keyframe may be here
    } else if (const auto* l = std::get_if<uw_multislam::LoopConstPtr>(&m)) {
      step([&] { processLoop(*l, false); });
    } else {
      optimiseDue();
    }
    std::lock_guard<std::mutex> lock(state_mutex_);
    publishAll(std::exchange(publish_all_, false));
  }
}

template <typename F>
void BackendNodelet::step(F process) {
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    try {
      process();
    } catch (const std::exception& e) {
      ++counts_.bad;
      NODELET_ERROR_THROTTLE(5, "back-end: message skipped: %s", e.what());
    }
  }
  optimiseDue();  // after each keyframe or loop, as offline_slam's synchronous manager does
}

void BackendNodelet::optimiseDue() {
  for (;;) {
    std::optional<core::MapOptimisation> o;
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      o = manager_->nextOptimisation();
    }
    if (!o) return;
    try {
      core::SessionManager::solveOptimisation(&*o);  // without the mutex: services and diagnostics go on
    } catch (const std::exception& e) {              // the map stays due: tried again after the next message
      NODELET_ERROR_THROTTLE(5, "back-end: optimising map %d failed: %s", o->map, e.what());
      return;
    }
    std::lock_guard<std::mutex> lock(state_mutex_);
    manager_->applyOptimisation(*o);
  }
}

void BackendNodelet::processKeyframe(const uw_multislam::Keyframe& msg) {
  rc::KeyframeData k;
  std::string why;
  ++counts_.keyframes;
  const bool ok = rc::fromMsg(msg, &k, &why);
  // A keyframe without a hash (an older sender) is hashed once, here, when the link needs it too:
  // the manager takes this hash instead of computing its own.
  if (ok && fleet_pub_ && k.hash.size() != core::HalocProjections::kHashSize && !k.features.descriptors.empty())
    k.hash = manager_->hasher().hash(k.features.descriptors);
  const core::Status st = ok ? manager_->addKeyframe(rc::toKeyframeInput(k, msg.header.stamp.toSec())) : core::Status();
  if (ok && st.ok() && !k.thumbnail.empty() && options_.mosaic_rate_hz > 0)  // no mosaic: no image kept
    mosaic_images_.add(k.session, k.keyframe, k.altitude_m, k.camera, std::move(k.thumbnail));
  counts_.bad += ok ? 0 : 1;
  if (!ok || !st.ok()) {
    NODELET_WARN_THROTTLE(5, "back-end: keyframe skipped: %s", ok ? st.message.c_str() : why.c_str());
    return;
  }
  if (fleet_pub_ && k.hash.size() == core::HalocProjections::kHashSize) {  // its hash, motion, pose: no features
    const auto& o = manager_->options();
    const auto out = boost::make_shared<uw_multislam::KeyframeHash>(
        rc::toFleetHashMsg(std::move(k), options_.fleet_vehicle, o.hash_mode, o.projection_seed, o.num_features,
                           o.features, msg.header, options_.fleet_hash_codes));
    ++fleet_.hashes_sent;
    fleet_.hash_bytes_sent += static_cast<long>(ros::serialization::serializationLength(*out));
    fleet_pub_.publish(out);
  }
}

void BackendNodelet::processFleetHash(const uw_multislam::KeyframeHash& msg) {
  if (msg.vehicle == options_.fleet_vehicle) return;  // ours, come back through a relay
  if (msg.session_ended) {
    const core::Status st = manager_->endForeignSession(msg.vehicle, msg.session, msg.header.stamp.toSec());
    if (st.ok())
      ++fleet_.sessions_ended;
    else
      NODELET_WARN_THROTTLE(5, "back-end: vehicle %s's session-ended notice: %s", msg.vehicle.c_str(),
                            st.message.c_str());
    return;
  }
  rc::KeyframeData k;
  rc::KeyframeHashData settings;
  std::string why;
  core::Status st;
  if (!rc::fromFleetHashMsg(msg, &k, &settings, &why)) {
    st = {core::StatusCode::kInvalidArgument, why};
  } else if (const auto& o = manager_->options();
             settings.mode != o.hash_mode || settings.projection_seed != o.projection_seed ||
             settings.num_features != o.num_features || settings.features != o.features) {
    st = {core::StatusCode::kFailedPrecondition,
          "hash settings " + core::hashModeName(settings.mode) + " seed " + std::to_string(settings.projection_seed) +
              " n " + std::to_string(settings.num_features) + " " + core::featureTypeName(settings.features) +
              " differ from ours (" + core::hashModeName(o.hash_mode) + " seed " + std::to_string(o.projection_seed) +
              " n " + std::to_string(o.num_features) + " " + core::featureTypeName(o.features) +
              "): its hashes cannot be compared with ours"};
  } else {
    int local = -1;
    const bool opens = manager_->foreignSession(msg.vehicle, msg.session) < 0;
    st = manager_->addForeignKeyframe(msg.vehicle, rc::toKeyframeInput(k, msg.header.stamp.toSec()), &local);
    if (st.ok() && opens) announceNextId();  // it took an id: our next session takes another
    if (st.ok()) {
      ++fleet_.hashes_received;
      fleet_.hash_bytes_received += static_cast<long>(ros::serialization::serializationLength(msg));
      k.session = local;  // in our ids, for the loop detector(s)
      std_msgs::Header header = msg.header;
      header.frame_id = options_.frames.session_frame_prefix + std::to_string(local);
      foreign_pub_.publish(boost::make_shared<uw_multislam::Keyframe>(rc::toKeyframeMsg(k, header)));
      return;
    }
  }
  ++fleet_.refused;
  NODELET_WARN_THROTTLE(5, "back-end: vehicle %s's keyframe %d of session %d refused: %s", msg.vehicle.c_str(),
                        msg.keyframe, msg.session, st.message.c_str());
}

void BackendNodelet::processLoop(const uw_multislam::LoopConstPtr& msg, bool retry) {
  if (!retry) ++counts_.loops;
  core::Loop l;
  std::string why;
  if (!rc::fromMsg(*msg, &l, &why)) {
    ++counts_.bad;
    NODELET_WARN_THROTTLE(5, "back-end: loop skipped: %s", why.c_str());
    return;
  }
  bool waiting = false;
  const core::Status st = manager_->addLoop(l, &waiting);
  if (waiting) {
    const bool full = static_cast<int>(waiting_.size()) >= options_.max_waiting_loops;
    if (full) waiting_.pop_front();  // the oldest, counted
    counts_.waiting_dropped += full ? 1 : 0;
    waiting_.push_back(msg);
  } else if (!st.ok()) {
    NODELET_WARN_THROTTLE(5, "back-end: %s", st.message.c_str());
  }
}

void BackendNodelet::onEvent(const core::SessionEvent& e) {
  using K = core::SessionEvent::Kind;
  if (e.kind == K::kSessionEnded && fleet_pub_ && manager_ && manager_->has(e.session) &&
      manager_->vehicleOf(e.session).empty()) {  // ours ended: the other vehicles can join it now
    fleet_pub_.publish(boost::make_shared<uw_multislam::KeyframeHash>(
        rc::fleetSessionEndedMsg(options_.fleet_vehicle, e.session, ros::Time::now())));
  }
  mosaic_due_ = true;  // a keyframe, a join, a split, an optimisation: the active map may look different
  const bool changed = e.kind != K::kKeyframeAdded && e.kind != K::kLoopAccepted;  // every session to publish
  publish_all_ = publish_all_ || changed;
  if (changed && e.kind != K::kMapOptimised) say(std::string(core::sessionEventName(e.kind)) + ": " + e.message);
}

core::Pose2 BackendNodelet::publishSession(int id) {
  const std::vector<core::Pose2> poses = manager_->poses(id);
  const core::Pose2 correction = manager_->correction(id);
  std::vector<ros::Time> stamps;
  for (double s : manager_->stamps(id)) stamps.emplace_back(std::max(0.0, s));
  const ros::Time now = stamps.empty() ? ros::Time::now() : stamps.back();
  trajectory_pub_.publish(rc::toSessionTrajectoryMsg(id, manager_->mapOf(id), manager_->posesInSessionFrame(id), now,
                                                     options_.frames.session_frame_prefix + std::to_string(id)));
  ros::Publisher& path = path_pubs_[id];  // latched, advertised with the session's first keyframe
  if (!path && manager_->hasKeyframe(id))
    path = getNodeHandle().advertise<nav_msgs::Path>(topics::kSessionPathPrefix + std::to_string(id), 1, true);
  const std::string& map = options_.frames.map_frame;
  if (path) path.publish(rc::toPathMsg(rc::vehiclePoses(*manager_, id, frames_->mount()), stamps, map, now));
  if (id != manager_->activeSession()) return correction;
  const std::optional<core::SessionManager::Relocalisation> reloc = relocalise(id);
  if (!reloc) {
    frames_->setActive(id, correction, poses.back(), now);
    keyframe_pose_pub_.publish(
        rc::toPoseWithCovarianceStampedMsg(frames_->vehicle(manager_->lastKeyframeInMap(id)), map, now));
    return correction;
  }
  // Relocalised in another map: tf and the poses go out in that map's frame (where it is drawn).
  frames_->setActive(id, reloc->correction, reloc->pose.mean, now);
  const auto msg = rc::toPoseWithCovarianceStampedMsg(frames_->vehicle(reloc->pose), map, now);
  keyframe_pose_pub_.publish(msg);
  relocalised_pub_.publish(msg);
  ++reloc_.published;
  return reloc->correction;  // map -> session_<id> as map -> odom: the stored map's
}

void BackendNodelet::publishAll(bool all_sessions) {
  if (all_sessions) offsets_ = rc::mapOffsets(*manager_, frames_->mount());  // maps change only with events
  std::map<int, core::Pose2> corrections;                                    // map -> session_<id>: sent together
  for (int id : all_sessions ? manager_->sessionIds() : std::vector<int>{manager_->activeSession()})
    if (id >= 0) corrections[id] = publishSession(id);
  frames_->setSessionFrames(corrections);
  const ros::WallTime now = ros::WallTime::now();  // every session's markers: on events, else at most 1 Hz
  if (trajectory_markers_pub_.getNumSubscribers() > 0 && (all_sessions || (now - markers_sent_).toSec() >= 1.0)) {
    markers_sent_ = now;
    trajectory_markers_pub_.publish(
        rc::toTrajectoryMarkersMsg(*manager_, frames_->mount(), offsets_, options_.frames.map_frame, ros::Time::now()));
  }
  if (!all_sessions && manager_->loops().empty()) return;
  markers_pub_.publish(rc::toMarkerArrayMsg(rc::loopSegments(*manager_, frames_->mount(), offsets_),
                                            options_.frames.map_frame, ros::Time::now()));
}

uw_multislam::SessionState BackendNodelet::sessionRequest(std::uint8_t state) const {
  uw_multislam::SessionState st;
  st.session = manager_->activeSession() >= 0 ? manager_->activeSession() : manager_->nextId();
  st.name = manager_->has(st.session) ? manager_->name(st.session) : core::defaultSessionName(st.session);
  st.state = state;
  st.map = st.session;
  st.relocalised_map = -1;
  st.next_session = manager_->nextId();
  return st;
}

void BackendNodelet::announceNextSession(std::uint8_t state) {
  announced_ = sessionRequest(state);
  active_pub_.publish(announced_);
}

void BackendNodelet::announceNextId() {
  // The last request, repeated for a late subscriber (none yet: what the odometry would be asked now).
  uw_multislam::SessionState st = announced_.name.empty() ? sessionRequest() : announced_;
  st.next_session = manager_->nextId();
  st.next_session_only = true;
  active_pub_.publish(st);
}

void BackendNodelet::onOdometryPose(const geometry_msgs::PoseWithCovarianceStampedConstPtr& msg) {
  core::UncertainPose2 odo;
  if (!rc::fromMsg(msg->pose, &odo)) return;
  const int session = rc::sessionOfFrame(msg->header.frame_id, options_.frames.session_frame_prefix);
  const std::optional<core::Pose2> in_map = frames_->onOdometry(session, odo, msg->header.stamp);  // never waits
  if (!in_map) return;
  geometry_msgs::PoseStamped p;
  p.header.stamp = msg->header.stamp;
  p.header.frame_id = options_.frames.map_frame;
  p.pose = rc::toPoseMsg(*in_map);
  pose_pub_.publish(p);
}

bool BackendNodelet::onJoin(uw_multislam::JoinSessions::Request& req, uw_multislam::JoinSessions::Response& res) {
  std::lock_guard<std::mutex> lock(state_mutex_);
  const core::Status st = manager_->join(req.session_a, req.session_b, req.min_loops);
  res.status = rc::toStatusMsg(st);
  res.map = manager_->has(req.session_a) ? manager_->mapOf(req.session_a) : -1;
  if (st.ok()) publishAll(true);
  queue_->pushPriority(Message());  // the worker optimises what the join left due
  return true;
}

bool BackendNodelet::onSplit(uw_multislam::SplitSession::Request& req, uw_multislam::SplitSession::Response& res) {
  std::lock_guard<std::mutex> lock(state_mutex_);
  const core::Status st = manager_->split(req.session);
  res.status = rc::toStatusMsg(st);
  if (st.ok()) publishAll(true);
  queue_->pushPriority(Message());
  return true;
}

bool BackendNodelet::onList(uw_multislam::ListSessions::Request&, uw_multislam::ListSessions::Response& res) {
  std::lock_guard<std::mutex> lock(state_mutex_);
  for (const core::SessionSummary& s : manager_->list()) {
    res.sessions.push_back(rc::toSessionStateMsg(s));
    if (s.id < manager_->restoredSessions()) continue;  // stored sessions: only this run's relocalise
    if (const auto r = manager_->relocalise(s.id)) res.sessions.back().relocalised_map = r->map;
  }
  res.status = rc::toStatusMsg(core::Status::Ok());
  return true;
}

bool BackendNodelet::onStart(uw_multislam::StartSession::Request& req, uw_multislam::StartSession::Response& res) {
  std::lock_guard<std::mutex> lock(state_mutex_);
  int id = -1;
  const core::Status st = manager_->startSession(req.name, ros::Time::now().toSec(), -1, &id);
  res.status = rc::toStatusMsg(st);
  res.session = id;
  if (!st.ok()) return true;
  queue_->pushPriority(Message());  // the ended session's map may be due
  announceNextSession();
  NODELET_INFO("back-end: start_session: session %d '%s' started; the odometry's next keyframe is its origin", id,
               manager_->name(id).c_str());
  publishAll(true);
  return true;
}

bool BackendNodelet::onFinish(uw_multislam::FinishSession::Request&, uw_multislam::FinishSession::Response& res) {
  std::lock_guard<std::mutex> lock(state_mutex_);
  const int id = manager_->activeSession();
  const core::Status st = manager_->endSession(ros::Time::now().toSec());
  res.status = rc::toStatusMsg(st);
  res.session = st.ok() ? id : -1;
  if (!st.ok()) return true;
  queue_->pushPriority(Message());  // the ended session's map may be due
  // No session records now: the odometry drops frames until start_session or resume, then
  // starts the session with the next id.
  announceNextSession(uw_multislam::SessionState::FINISHED);
  reloc_ = RelocalisationState();  // no active session: nothing relocalised (diagnostics)
  NODELET_INFO("back-end: finish_session: session %d '%s' finished; the odometry waits for start_session or resume",
               id, manager_->name(id).c_str());
  publishAll(true);
  return true;
}

bool BackendNodelet::onAddLink(uw_multislam::AddLink::Request& req, uw_multislam::AddLink::Response& res) {
  core::Loop l;  // checked as a detector's loop is, then by the manager
  std::string why;
  std::lock_guard<std::mutex> lock(state_mutex_);
  core::Status st = rc::fromAddLinkRequest(req, &l, &why)
                        ? core::Status::Ok()
                        : core::Status{core::StatusCode::kInvalidArgument, "add_link: " + why};
  if (st.ok() && req.find) st = core::findStoredLink(*manager_, config_, &l);  // RANSAC on the stored features
  if (st.ok()) st = manager_->addLink(l);
  res.status = rc::toStatusMsg(st);
  if (!st.ok()) return true;
  res.pose = rc::toPose2DMsg(l.z.mean);
  res.inliers = l.inliers;
  publishAll(true);
  queue_->pushPriority(Message());  // the link's map may be due
  return true;
}

bool BackendNodelet::onOptimise(uw_multislam::Optimise::Request&, uw_multislam::Optimise::Response& res) {
  std::lock_guard<std::mutex> lock(state_mutex_);
  int maps = 0;
  const core::Status st = manager_->optimisePending(&maps);
  res.status = rc::toStatusMsg(st);
  res.maps = maps;
  if (st.ok() && maps > 0) queue_->pushPriority(Message());  // the worker solves the due maps
  return true;
}

bool BackendNodelet::onHistory(uw_multislam::History::Request& req, uw_multislam::History::Response& res) {
  if (req.last < 0) {
    res.status = rc::toStatusMsg({core::StatusCode::kInvalidArgument, "history: last must be >= 0 (0: all entries)"});
    return true;
  }
  std::lock_guard<std::mutex> lock(state_mutex_);
  const std::vector<core::HistoryEntry>& h = manager_->history();
  const std::size_t from = req.last == 0 ? 0 : h.size() - std::min(h.size(), static_cast<std::size_t>(req.last));
  for (std::size_t i = from; i < h.size(); ++i) res.entries.push_back(rc::toHistoryEntryMsg(h[i]));
  res.status = rc::toStatusMsg(core::Status::Ok());
  return true;
}

bool BackendNodelet::onDetectLoops(uw_multislam::DetectLoops::Request& req, uw_multislam::DetectLoops::Response& res) {
  std::lock_guard<std::mutex> lock(state_mutex_);
  const int joins = manager_->backendStats().joins;
  core::StoredLoopSearch f;
  const core::Status st = core::detectStoredLoops(manager_.get(), config_, req.sessions, &f,
                                                  [this](const std::string& line) { say(line); });
  res.status = rc::toStatusMsg(st);
  res.queries = f.queries;
  res.candidates = f.candidates;
  res.found = f.found;
  res.already_held = f.duplicates;
  res.accepted = f.accepted;
  res.refused = f.refused;
  res.joins = manager_->backendStats().joins - joins;
  NODELET_INFO("back-end: detect_loops: %s; %d keyframes queried, %d candidates, %d loops (%d held already), "
               "%d accepted, %d refused, %d joins",
               st.ok() ? "OK" : st.message.c_str(), f.queries, f.candidates, f.found, f.duplicates, f.accepted,
               f.refused, res.joins);
  if (f.accepted > 0) {
    publishAll(true);
    queue_->pushPriority(Message());  // the maps the loops touched may be due
  }
  return true;
}

bool BackendNodelet::onSetMode(uw_multislam::SetMode::Request& req, uw_multislam::SetMode::Response& res) {
  std::lock_guard<std::mutex> lock(state_mutex_);
  core::Status st;
  if (req.mode == "mapping" || req.mode == "localisation")
    st = manager_->setLocalisation(req.mode == "localisation");
  else
    st = {core::StatusCode::kInvalidArgument, "set_mode: mode '" + req.mode.substr(0, 64) +
                                                  "' is neither 'mapping' nor 'localisation'"};
  res.status = rc::toStatusMsg(st);
  res.mode = manager_->localising() ? "localisation" : "mapping";
  if (st.ok()) NODELET_INFO("back-end: set_mode %s: %s", res.mode.c_str(), st.message.c_str());
  return true;
}

void BackendNodelet::reloadStored() {
  std::lock_guard<std::mutex> lock(state_mutex_);
  int keyframes = 0;
  for (const core::SessionSummary& s : manager_->list()) {
    if (s.state != core::SessionState::kUnloaded) continue;
    core::ReloadedSession r;
    // Nothing read here: the handover reads each session's hashes when a loop detector subscribes,
    // one session per lock, so the back-end maps from its start (reading the hashes here held
    // onInit for 9.4 s at 100 k keyframes from a cold disk, 2 s warm). Features (and thumbnails:
    // the live mosaic lacks these keyframes) stay in the store.
    const core::Status st = manager_->reload(std::to_string(s.id), &r, core::SessionManager::ReloadRead::kNothing);
    if (!st.ok()) {
      NODELET_ERROR("back-end: ~reload_stored: session %d '%s' not reloaded: %s", s.id, s.name.c_str(),
                    st.message.c_str());
      continue;
    }
    handed_.push_back(r.id);
    keyframes += s.keyframes;
  }
  NODELET_INFO("back-end: ~reload_stored: %zu stored sessions (%d keyframes) go to every loop detector that subscribes",
               handed_.size(), keyframes);
}

void BackendNodelet::onReloadedSubscriber(const ros::SingleSubscriberPublisher& pub) {
  // Session by session, each read and published under state_mutex_ (an unload_session cannot come
  // between a session's keyframes and its notice), so the worker maps between them: the vehicle
  // does not wait for a large store to be handed over.
  std::vector<int> ids;
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    ids = handed_;
    handover_.total = 0;
    for (int id : ids) handover_.total += static_cast<long>(manager_->frames(id).size());
    handover_.sent = 0;
    ++handover_.subscribers;
  }
  const ros::WallTime start = ros::WallTime::now();
  long sent = 0, failed = 0;
  for (int id : ids) {
    std::lock_guard<std::mutex> lock(state_mutex_);
    if (std::find(handed_.begin(), handed_.end(), id) == handed_.end()) continue;  // unloaded meanwhile
    core::ReloadedSession r;
    r.id = id;
    r.camera = manager_->camera(id);
    const std::string frame = options_.frames.session_frame_prefix + std::to_string(id);
    try {
      r.keyframes = manager_->storedHashes(id);
    } catch (const std::exception& e) {
      ++failed;
      NODELET_ERROR("back-end: stored session %d not sent to %s: %s", id, pub.getSubscriberName().c_str(), e.what());
      continue;
    }
    for (core::StoredKeyframe& k : r.keyframes) {
      // Paging (slam/loops/page_stored): hashes only; the loop detector asks keyframe_features.
      if (!config_.loops.page_stored) {
        try {
          const core::StoredKeyframe f = manager_->storedFeatures(id, k.keyframe);
          k.points = f.points;
          k.descriptors = f.descriptors;
          k.image_size = f.image_size;
        } catch (const std::exception& e) {  // sent without features: no candidate, as a keyframe never received
          ++failed;
          NODELET_WARN_THROTTLE(5, "back-end: stored keyframe %d/%d sent without features: %s", id, k.keyframe,
                                e.what());
        }
      }
      pub.publish(rc::reloadedKeyframeMsg(r, k, frame));
      ++sent;
    }
    handover_.sent = sent;
  }
  std::lock_guard<std::mutex> lock(state_mutex_);
  handover_.seconds = (ros::WallTime::now() - start).toSec();
  if (!ids.empty())
    NODELET_INFO("back-end: %ld stored keyframes of %zu sessions sent to %s in %.1f s (%ld without features)", sent,
                 ids.size(), pub.getSubscriberName().c_str(), handover_.seconds, failed);
}

std::optional<core::SessionManager::Relocalisation> BackendNodelet::relocalise(int id) {
  std::optional<core::SessionManager::Relocalisation> r = manager_->relocalise(id);
  const int map = r ? r->map : -1;
  if (id != reloc_.session || map != reloc_.map) {
    if (r)
      say("session " + std::to_string(id) + " relocalised in map " + std::to_string(map) + " at its keyframe " +
          std::to_string(r->keyframe) + " from " + std::to_string(r->loops) + " consistent global loops (" +
          std::to_string(r->inliers) + " inliers)");
    else if (id == reloc_.session && reloc_.map >= 0 && manager_->mapOf(id) != reloc_.map)  // not by a join
      say("session " + std::to_string(id) + " no longer relocalised in map " + std::to_string(reloc_.map));
  }
  if (id != reloc_.session) reloc_.published = 0;
  reloc_.session = id;
  reloc_.map = map;
  reloc_.loops = r ? r->loops : 0;
  reloc_.keyframe = r ? r->keyframe : -1;
  return r;
}

bool BackendNodelet::onReload(uw_multislam::ReloadSession::Request& req, uw_multislam::ReloadSession::Response& res) {
  std::lock_guard<std::mutex> lock(state_mutex_);
  core::ReloadedSession r;
  const core::Status st = manager_->reload(req.name, &r);
  res.status = rc::toStatusMsg(st);
  res.session = r.id;
  if (!st.ok()) return true;
  const std::string frame = options_.frames.session_frame_prefix + std::to_string(r.id);
  for (const core::StoredKeyframe& k : r.keyframes)
    if (!k.thumbnail.empty() && options_.mosaic_rate_hz > 0)
      mosaic_images_.add(r.id, k.keyframe, k.altitude_m, r.camera, k.thumbnail);
  mosaic_due_ = true;
  handed_.push_back(r.id);  // and to every loop detector that subscribes later
  for (core::StoredKeyframe& k : r.keyframes) {
    if (config_.loops.page_stored) {  // the loop detector reads them again when needed (keyframe_features)
      k.points.clear();
      k.descriptors.release();
    }
    reloaded_pub_.publish(boost::make_shared<uw_multislam::Keyframe>(rc::reloadedKeyframeMsg(r, k, frame)));
  }
  NODELET_INFO("back-end: reload_session '%s': session %d, %zu keyframes handed to the loop detector", req.name.c_str(),
               r.id, r.keyframes.size());
  return true;
}

bool BackendNodelet::onKeyframeFeatures(uw_multislam::KeyframeFeatures::Request& req,
                                        uw_multislam::KeyframeFeatures::Response& res) {
  if (req.session < 0 || req.session > core::kMaxSessionId || req.keyframe < 0) {
    res.status = rc::toStatusMsg({core::StatusCode::kInvalidArgument, "session " + std::to_string(req.session) +
                                                                          ", keyframe " + std::to_string(req.keyframe) +
                                                                          ": ids must be >= 0"});
    return true;
  }
  std::unique_lock<std::mutex> lock(state_mutex_);
  if (manager_->has(req.session) && !manager_->vehicleOf(req.session).empty()) {  // another vehicle's
    const std::string vehicle = manager_->vehicleOf(req.session);
    const int remote = manager_->remoteIdOf(req.session);
    lock.unlock();  // a call over the link: keyframes, loops and services go on meanwhile
    return featuresFromPeer(vehicle, remote, req.session, req, res);
  }
  if (req.check_only) {  // whether it is there: a loop detector about to page a live keyframe out
    const bool store = !manager_->options().store_path.empty();
    res.status = rc::toStatusMsg(!store ? core::Status{core::StatusCode::kFailedPrecondition, "no session store"}
                                 : manager_->inStore(req.session, req.keyframe)
                                     ? core::Status::Ok()
                                     : core::Status{core::StatusCode::kNotFound,
                                                    "keyframe " + std::to_string(req.keyframe) + " of session " +
                                                        std::to_string(req.session) + " is not in the store (yet)"});
    return true;
  }
  core::ReloadedSession r;
  r.id = req.session;
  core::StoredKeyframe k;
  try {
    if (!manager_->has(req.session))
      throw std::out_of_range("no session " + std::to_string(req.session) + " (see list_sessions)");
    r.camera = manager_->camera(req.session);
    k = manager_->storedFeatures(req.session, req.keyframe);
  } catch (const std::out_of_range& e) {
    res.status = rc::toStatusMsg({core::StatusCode::kNotFound, e.what()});
    return true;
  } catch (const std::exception& e) {
    // No store; a keyframe not (yet) in it; an unreadable record.
    const bool no_store = manager_->options().store_path.empty();
    const bool stored = !no_store && manager_->inStore(req.session, req.keyframe);
    res.status = rc::toStatusMsg({no_store ? core::StatusCode::kFailedPrecondition
                                  : stored ? core::StatusCode::kDataLoss
                                           : core::StatusCode::kNotFound,
                                  e.what()});
    return true;
  }
  k.thumbnail.clear();
  res.keyframe = rc::reloadedKeyframeMsg(r, k, options_.frames.session_frame_prefix + std::to_string(req.session));
  res.status = rc::toStatusMsg(core::Status::Ok());
  return true;
}

bool BackendNodelet::featuresFromPeer(const std::string& vehicle, int remote_session, int local_session,
                                      uw_multislam::KeyframeFeatures::Request& req,
                                      uw_multislam::KeyframeFeatures::Response& res) {
  const auto peer = options_.fleet_peers.find(vehicle);
  if (peer == options_.fleet_peers.end()) {
    {
      std::lock_guard<std::mutex> lock(peer_mutex_);
      ++fleet_.features_requested;
      ++fleet_.feature_failures;
    }
    res.status = rc::toStatusMsg(
        {core::StatusCode::kFailedPrecondition, "session " + std::to_string(local_session) + " is vehicle " + vehicle +
                                                    "'s, and ~fleet/peers names no keyframe_features service for it"});
    return true;
  }
  const std::string who = "vehicle " + vehicle + "'s " + peer->second;
  char limit[64];
  std::snprintf(limit, sizeof limit, "%.1f s (~fleet/peer_timeout_s)", options_.fleet_peer_timeout_s);
  const auto now = std::chrono::steady_clock::now();
  std::unique_lock<std::mutex> lock(peer_mutex_);
  if (const auto quiet = peer_quiet_until_.find(vehicle); quiet != peer_quiet_until_.end() && now < quiet->second) {
    // It did not answer lately: not asked again for a while, so that a vehicle out of reach
    // costs our loop detector one wait, not one per candidate.
    ++fleet_.features_requested;
    ++fleet_.feature_failures;
    res.status = rc::toStatusMsg({core::StatusCode::kUnavailable, who + " did not answer its last request within " +
                                                                      limit + ": not asked again for as long"});
    return true;
  }
  uw_multislam::KeyframeFeatures there;
  there.request = req;
  there.request.session = remote_session;
  ros::ServiceClient& client = peer_clients_[vehicle];
  if (!client.isValid()) client = getNodeHandle().serviceClient<uw_multislam::KeyframeFeatures>(peer->second, true);
  ros::ServiceClient call = client;  // a copy: the call itself runs without the lock
  lock.unlock();
  // On a thread of its own, waited for at most ~fleet/peer_timeout_s (core::BoundedCalls; it
  // owns copies of what it touches): a link gone quiet holds this request that long, no longer.
  auto exchange = std::make_shared<uw_multislam::KeyframeFeatures>(there);
  auto answered = std::make_shared<bool>(false);
  std::string error;
  const core::BoundedCalls::Outcome outcome = peer_calls_.call(
      vehicle, [call, exchange, answered]() mutable { *answered = call.call(*exchange); },
      options_.fleet_peer_timeout_s, &error);
  lock.lock();
  ++fleet_.features_requested;
  if (outcome != core::BoundedCalls::Outcome::kDone || !*answered) {
    ++fleet_.feature_failures;
    std::string why = who + " did not answer";
    if (outcome == core::BoundedCalls::Outcome::kTimedOut) {
      ++fleet_.feature_timeouts;
      why += std::string(" within ") + limit;
      peer_quiet_until_[vehicle] =
          std::chrono::steady_clock::now() + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                                 std::chrono::duration<double>(options_.fleet_peer_timeout_s));
      // Our persistent link to it dropped: roscpp then fails the hung call (its thread and the
      // key are freed; BoundedCalls refuses the key until then); the next request makes a new one.
      call.shutdown();
      peer_clients_[vehicle] = ros::ServiceClient();
    } else {
      if (outcome == core::BoundedCalls::Outcome::kBusy) why = who + " has not returned an earlier request yet";
      if (outcome == core::BoundedCalls::Outcome::kThrew) why += ": " + error;
      peer_clients_[vehicle].shutdown();  // made again at the next request
    }
    res.status = rc::toStatusMsg({core::StatusCode::kUnavailable, why});
    return true;
  }
  const uw_multislam::KeyframeFeatures::Response& answer = exchange->response;
  if (answer.status.code != uw_multislam::Status::OK) ++fleet_.feature_failures;
  fleet_.feature_bytes_received += static_cast<long>(ros::serialization::serializationLength(answer));
  res = answer;
  res.keyframe.session = local_session;  // in our ids
  res.keyframe.header.frame_id = options_.frames.session_frame_prefix + std::to_string(local_session);
  return true;
}

void BackendNodelet::forgetSession(int id) {
  handed_.erase(std::remove(handed_.begin(), handed_.end(), id), handed_.end());  // no later subscriber gets it
  reloaded_pub_.publish(boost::make_shared<uw_multislam::Keyframe>(rc::unloadSessionMsg(id)));
  mosaic_images_.removeSession(id);
  mosaic_due_ = true;
}

bool BackendNodelet::onUnload(uw_multislam::ReloadSession::Request& req, uw_multislam::ReloadSession::Response& res) {
  std::lock_guard<std::mutex> lock(state_mutex_);
  int id = -1;
  const core::Status st = manager_->unload(req.name, &id);
  res.status = rc::toStatusMsg(st);
  res.session = id;
  if (!st.ok()) {
    NODELET_WARN("back-end: unload_session '%s' refused: %s", req.name.c_str(), st.message.c_str());
    return true;
  }
  forgetSession(id);
  ++sessions_unloaded_;
  NODELET_INFO("back-end: unload_session '%s': session %d UNLOADED, the loop detectors forget its keyframes",
               req.name.c_str(), id);
  publishAll(true);  // list and active_session states
  return true;
}

bool BackendNodelet::onDelete(uw_multislam::DeleteSession::Request& req, uw_multislam::DeleteSession::Response& res) {
  std::lock_guard<std::mutex> lock(state_mutex_);
  int id = -1;
  const core::Status st = manager_->deleteSession(req.name, req.confirm, &id);
  res.status = rc::toStatusMsg(st);
  res.session = id;
  if (!st.ok()) {
    NODELET_WARN("back-end: delete_session '%s' refused: %s", req.name.c_str(), st.message.c_str());
    return true;
  }
  forgetSession(id);
  const auto path = path_pubs_.find(id);
  if (path != path_pubs_.end() && path->second) {  // latched: an empty path, or rviz would go on drawing it
    nav_msgs::Path empty;
    empty.header.stamp = ros::Time::now();
    empty.header.frame_id = options_.frames.map_frame;
    path->second.publish(empty);
  }
  ++sessions_deleted_;
  NODELET_WARN("back-end: delete_session '%s': session %d deleted from the store and from memory", req.name.c_str(), id);
  publishAll(true);
  return true;
}

void BackendNodelet::drawMosaics() {
  const auto period = std::chrono::duration<double>(1.0 / options_.mosaic_rate_hz);
  std::unique_lock<std::mutex> wait(mosaic_wait_mutex_);
  while (!mosaic_wake_.wait_for(wait, period, [this] { return mosaic_stop_; })) {
    if (!mosaic_due_ || mosaic_pub_.getNumSubscribers() == 0) continue;  // latched: the last one stays
    wait.unlock();
    core::LiveMosaicSnapshot snapshot;
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      mosaic_due_ = false;
      snapshot = core::liveMosaicSnapshot(*manager_, mosaic_images_);  // poses copied, images shared
    }
    const core::LiveMosaicImage m = core::drawLiveMosaic(snapshot, options_.mosaic);  // without state_mutex_
    if (!m.bgr.empty()) {
      std_msgs::Header header;
      header.stamp = ros::Time::now();
      header.frame_id = options_.frames.map_frame;
      mosaic_pub_.publish(cv_bridge::CvImage(header, "bgr8", m.bgr).toImageMsg());
    }
    {
      std::lock_guard<std::mutex> lock(state_mutex_);
      mosaic_stats_.published += m.bgr.empty() ? 0 : 1;
      mosaic_stats_.drawn = m.drawn;
      mosaic_stats_.missing = m.missing;
      mosaic_stats_.ms = m.ms;
      mosaic_stats_.resolution_m = m.resolution_m;
    }
    if (!m.bgr.empty())
      NODELET_DEBUG("back-end: live mosaic of map %d: %d x %d px at %.4f m/px, %d keyframes drawn, %d missing, %.1f ms",
                    snapshot.map, m.bgr.cols, m.bgr.rows, m.resolution_m, m.drawn, m.missing, m.ms);
    wait.lock();
  }
}

bool BackendNodelet::onExport(uw_multislam::ExportSurvey::Request& req, uw_multislam::ExportSurvey::Response& res) {
  auto answer = [&](core::Status st) {
    res.status = rc::toStatusMsg(st);
    if (!st.ok()) NODELET_WARN("back-end: export '%s' refused: %s", req.session.c_str(), st.message.c_str());
    return true;
  };
  using C = core::StatusCode;
  auto refuse = [&](C code, const std::string& message) { return answer(core::Status{code, message}); };
  std::unique_lock<std::mutex> one(export_mutex_, std::try_to_lock);
  if (!one.owns_lock()) return refuse(C::kUnavailable, "another export is running: try again when it has answered");
  core::TrackFilesOptions o;
  core::GeoOrigin origin;
  std::string why;
  if (!req.origin.empty() && !core::parseGeoOrigin(req.origin, &origin, &why))
    return refuse(C::kInvalidArgument, "bad origin '" + req.origin + "': " + why);
  if (!req.origin.empty()) o.origin = &origin;
  if (!std::isfinite(req.resolution_m) || req.resolution_m < 0.0 || req.resolution_m > 100.0)
    return refuse(C::kInvalidArgument, "resolution_m " + std::to_string(req.resolution_m) +
                                           ": metres per pixel in (0, 100], or 0 for automatic");
  o.mosaic = !req.no_mosaic;
  o.mosaic_options.resolution_m = req.resolution_m;
  if (options_.export_root.empty())
    return refuse(C::kFailedPrecondition, "no export root (~export_root is empty): exports are off");
  std::string directory;
  if (!core::resolveExportFolder(options_.export_root, req.folder, &directory, &why))
    return refuse(C::kInvalidArgument, why);
  std::string name, label, store;
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    int id = manager_->idOfName(req.session);
    if (id < 0 && !req.session.empty() && req.session.find_first_not_of("0123456789") == std::string::npos &&
        req.session.size() < 8 && manager_->has(std::stoi(req.session)))
      id = std::stoi(req.session);
    if (id < 0)
      return refuse(C::kNotFound, "no session named or numbered '" + req.session + "' (list_sessions shows them)");
    if (!manager_->hasStore())
      return refuse(C::kFailedPrecondition, "no session store (~store_path is empty): nothing to export from");
    name = manager_->name(id);
    label = req.map ? "map_" + std::to_string(manager_->mapOf(id)) : "session_" + std::to_string(id);
    store = manager_->storePath();
  }
  try {  // without state_mutex_: the store read-only, the files written
    const core::SurveyExport survey = core::loadSurveyExport(store);
    const core::ExportTrack* session = nullptr;
    for (const core::ExportTrack& t : survey.sessions)
      if (t.name == name) session = &t;
    if (!session) return refuse(C::kFailedPrecondition, "session '" + name + "' has no keyframe in the store yet");
    core::ExportTrack track = *session;
    if (req.map)
      for (const core::ExportTrack& m : survey.maps)
        for (std::int64_t s : m.sessions)
          if (s == session->sessions.front()) track = m;
    track.label = label;  // the ids the services use (the store's own ids differ)
    std::error_code ec;
    std::filesystem::create_directories(directory, ec);
    if (ec) return refuse(C::kInternal, "cannot create " + directory + ": " + ec.message());
    const core::TrackFiles written = core::writeTrackFiles(track, survey, core::MosaicImages(), directory, o);
    res.directory = directory;
    res.files = written.files;
    NODELET_INFO("back-end: export: %s (%s, %zu keyframes) written to %s: %zu files", label.c_str(), track.name.c_str(),
                 track.keyframes.size(), directory.c_str(), written.files.size());
    return answer(core::Status::Ok());
  } catch (const std::exception& e) {
    return refuse(C::kInternal, std::string("export failed: ") + e.what());
  }
}

std::vector<ros_diagnostics::Counter> BackendNodelet::counters() const {
  auto d = [](auto v) { return static_cast<double>(v); };
  std::vector<ros_diagnostics::Counter> c = {{"messages_received", d(queue_ ? queue_->pushed() : 0)},
                                             {"keyframes_received", d(counts_.keyframes)},
                                             {"loops_received", d(counts_.loops)},
                                             {"loops_waiting", d(waiting_.size())},
                                             {"loops_dropped_waiting", d(counts_.waiting_dropped), true},
                                             {"dropped_queue_full", d(queue_ ? queue_->dropped() : 0), true},
                                             {"queue_length", d(queue_ ? queue_->size() : 0)},
                                             {"bad_messages", d(counts_.bad), true}};
  const ros_frames::FrameStats f = frames_->stats();
  c.push_back({"map_to_odom_published", d(f.map_to_odom_published)});
  c.push_back({"map_to_odom_rate_hz", f.map_to_odom_rate_hz});
  c.push_back({"odom_lookup_failures", d(f.odom_lookup_failures), true});
  c.push_back({"sessions_unloaded", d(sessions_unloaded_)});
  // The newest handover of the stored keyframes to a loop detector (reloaded_keyframes): its
  // progress while it runs (sent of total), then how long it took.
  c.push_back({"handover_subscribers", d(handover_.subscribers)});
  c.push_back({"handover_keyframes_total", d(handover_.total)});
  c.push_back({"handover_keyframes_sent", d(handover_.sent)});
  c.push_back({"handover_s", handover_.seconds});
  c.push_back({"sessions_deleted", d(sessions_deleted_)});
  c.push_back({"relocalised_map", d(reloc_.map)});
  c.push_back({"relocalised_loops", d(reloc_.loops)});
  c.push_back({"relocalised_poses_published", d(reloc_.published)});
  c.push_back({"mosaic_published", d(mosaic_stats_.published)});
  c.push_back({"mosaic_keyframes_drawn", d(mosaic_stats_.drawn)});
  c.push_back({"mosaic_keyframes_missing", d(mosaic_stats_.missing)});
  c.push_back({"mosaic_draw_ms", mosaic_stats_.ms});
  c.push_back({"mosaic_resolution_m", mosaic_stats_.resolution_m});
  c.push_back({"mosaic_images_kB", d(mosaic_images_.bytes()) / 1024.0});
  if (fleet_pub_) {  // the hash exchange: what crossed the link, per direction (README "Two vehicles")
    c.push_back({"fleet_hashes_sent", d(fleet_.hashes_sent)});
    c.push_back({"fleet_hash_bytes_sent", d(fleet_.hash_bytes_sent)});
    c.push_back({"fleet_hashes_received", d(fleet_.hashes_received)});
    c.push_back({"fleet_hash_bytes_received", d(fleet_.hash_bytes_received)});
    c.push_back({"fleet_refused", d(fleet_.refused), true});
    c.push_back({"fleet_sessions_ended", d(fleet_.sessions_ended)});
    std::lock_guard<std::mutex> lock(peer_mutex_);
    c.push_back({"fleet_features_requested", d(fleet_.features_requested)});
    c.push_back({"fleet_feature_bytes_received", d(fleet_.feature_bytes_received)});
    c.push_back({"fleet_feature_failures", d(fleet_.feature_failures), true});
    c.push_back({"fleet_feature_timeouts", d(fleet_.feature_timeouts), true});
  }
  for (ros_diagnostics::Counter& m : rc::managerCounters(*manager_)) c.push_back(std::move(m));
  return c;
}

void BackendNodelet::fillDiagnostics(diagnostic_updater::DiagnosticStatusWrapper& stat) {
  std::lock_guard<std::mutex> lock(state_mutex_);
  stat.add("optimizer", core::optimizerName(config_.backend.optimizer));
  stat.add("store", manager_->hasStore() ? options_.store_path : std::string("none"));
  stat.add("mode", manager_->localising() ? "localisation" : "mapping");
  stat.add("relocalised", reloc_.map >= 0 ? "session " + std::to_string(reloc_.session) + " in map " +
                                                std::to_string(reloc_.map)
                                          : std::string("no"));
  diagnostic_status_.fill(stat, counters(), ros::WallTime::now().toSec());
}

void BackendNodelet::logStats(const char* when) {
  say(ros_diagnostics::countersLine(std::string("counters ") + when + ":", counters()));
}

void BackendNodelet::say(const std::string& line) const {
  // After ros::shutdown() (SIGINT of a standalone node) rosconsole is shut down and drops every
  // line: the unload's own report then goes to stderr, so the operator sees what was saved.
  if (ros::isShuttingDown() || !ros::ok())
    std::fprintf(stderr, "[ INFO] back-end: %s\n", line.c_str());
  else
    NODELET_INFO("back-end: %s", line.c_str());
}

}  // namespace nodelets
}  // namespace uw_multislam

PLUGINLIB_EXPORT_CLASS(uw_multislam::nodelets::BackendNodelet, nodelet::Nodelet)
