// uw_multislam/Backend: the back-end and session manager (paper 000 §8, §9) around
// core::MultiSessionBackend, which does the optimisation, the joins and the splits.
//
// Inputs:  keyframes (uw_multislam/Keyframe, odometry nodelet): each keyframe's motion from the
//            previous one; a new session id starts a session (the previous one stops recording)
//          loops (uw_multislam/Loop, loop detector nodelet(s)), local and global
//          odometry/pose (geometry_msgs/PoseStamped, odometry nodelet): for tf and the current pose
// Outputs: session_trajectory (uw_multislam/SessionTrajectory): a session's optimised poses in its
//            own frame, for the loop detector's local candidates
//          paths/session_<id> (nav_msgs/Path, latched): each session's keyframes in its map's frame
//          loop_markers (visualization_msgs/MarkerArray, latched): loops and joins
//          pose (geometry_msgs/PoseStamped): the current camera pose in the map frame
//          active_session (uw_multislam/SessionState, latched): set by start_session
//          tf: map_frame -> <session_frame_prefix><id> (the correction optimisation applied to that
//            session's odometry) and <session_frame_prefix><active> -> base_frame (the odometry)
//          reloaded_keyframes (uw_multislam/Keyframe): a reloaded session's keyframes, for the
//            loop detector(s) to keep as global-loop candidates
// Services: join_sessions, split_session, list_sessions, start_session, reload_session.
//
// Session store (~store_path, default $ROS_HOME/uw_multislam/sessions.db; "" = none; see
// core/session/session_store.h): every keyframe (features, descriptors, hash), its motion and each loop
// are written as they arrive, one transaction each (WAL), the maps at every join, split and
// session end, so a kill -9 loses at most what was in flight. At start-up the stored sessions,
// loops and maps are put back into the back-end (they take ids 0..k-1; active_session asks the
// odometry to continue from k) and listed UNLOADED: their trajectories are there, but the loop
// detector does not know their keyframes until reload_session publishes them.
//
// Maps: every map is drawn in map_frame with its first session's origin at map_frame's origin
// (maps that are not joined are not related, so they overlap in rviz).
//
// Threading model: the keyframe and loop callbacks push the message pointers onto one bounded
// FIFO (~queue_size; when full the OLDEST is dropped and counted) and return, so that loops keep
// their order relative to keyframes. One worker thread takes them in order and calls the core
// under state_mutex_; the services take the same mutex, so they wait for at most one message's
// processing (an optimisation: ~0.6 s at 10 k keyframes). A loop that names a keyframe the
// back-end has not received yet waits (up to ~max_waiting_loops, oldest dropped and counted) and is
// retried after each keyframe. The odometry/pose callback only reads the active session's
// correction under the mutex and publishes.
#include <diagnostic_updater/diagnostic_updater.h>
#include <geometry_msgs/PoseStamped.h>
#include <geometry_msgs/TransformStamped.h>
#include <nodelet/nodelet.h>
#include <ros/ros.h>
#include <tf2_ros/transform_broadcaster.h>

#include <pluginlib/class_list_macros.hpp>

#include <condition_variable>
#include <cstdlib>
#include <deque>
#include <filesystem>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <thread>
#include <variant>
#include <vector>

#include "uw_multislam/JoinSessions.h"
#include "uw_multislam/Keyframe.h"
#include "uw_multislam/ListSessions.h"
#include "uw_multislam/Loop.h"
#include "uw_multislam/ReloadSession.h"
#include "uw_multislam/SessionState.h"
#include "uw_multislam/SessionTrajectory.h"
#include "uw_multislam/SplitSession.h"
#include "uw_multislam/StartSession.h"
#include "uw_multislam/core/backend/backend.h"
#include "uw_multislam/core/loops/haloc.h"
#include "uw_multislam/core/session/map_persistence.h"
#include "uw_multislam/core/session/session_store.h"
#include "uw_multislam/core/session/slam_config.h"
#include "uw_multislam/ros/backend_conversions.h"
#include "uw_multislam/ros/conversions.h"
#include "uw_multislam/ros/diagnostics.h"
#include "uw_multislam/ros/pipeline_conversions.h"
#include "uw_multislam/ros/slam_params.h"
#include "uw_multislam/ros/topics.h"

namespace uw_multislam {
namespace nodelets {

namespace rc = ros_conversions;

class BackendNodelet : public nodelet::Nodelet {
 public:
  ~BackendNodelet() override;

 private:
  using Message = std::variant<uw_multislam::KeyframeConstPtr, uw_multislam::LoopConstPtr>;
  /// What the nodelet keeps of a session beside the core: ids, stamps and odometry poses.
  struct Session {
    int internal = 0;                      // the core's id
    std::string name;
    std::vector<ros::Time> stamps;         // per keyframe
    std::vector<core::Pose2> odometry;     // X_k^0 of the odometry, per keyframe
    std::set<int> phantoms;                // keyframes never received (bridged)
    int loops = 0;
  };
  struct Counters {
    long keyframes = 0, loops = 0, dropped = 0, bad = 0, stale = 0, gaps = 0, refused = 0, waiting_dropped = 0;
  };

  void onInit() override;
  void readParameters();
  void enqueue(Message m);
  void work();
  void processKeyframe(const uw_multislam::Keyframe& msg);
  /// Adds a loop to the core; false when one of its keyframes has not arrived yet.
  bool processLoop(const uw_multislam::Loop& msg);
  void retryWaitingLoops();
  void publishAll(bool all_sessions);
  /// Publishes a session's trajectory, path and tf from its poses in its map's frame.
  void publishSession(int ext, const std::vector<core::Pose2>& poses);
  int externalOf(int internal) const;
  void onOdometryPose(const geometry_msgs::PoseStampedConstPtr& msg);
  bool onJoin(uw_multislam::JoinSessions::Request& req, uw_multislam::JoinSessions::Response& res);
  bool onSplit(uw_multislam::SplitSession::Request& req, uw_multislam::SplitSession::Response& res);
  bool onList(uw_multislam::ListSessions::Request& req, uw_multislam::ListSessions::Response& res);
  bool onStart(uw_multislam::StartSession::Request& req, uw_multislam::StartSession::Response& res);
  bool onReload(uw_multislam::ReloadSession::Request& req, uw_multislam::ReloadSession::Response& res);
  void logStats(const char* when);
  void openStore();
  /// Runs a store write; a failure (disk full, I/O error) is counted and logged, never fatal:
  /// the map lives on in memory.
  template <typename F>
  void storeWrite(const char* what, F write);
  void storeKeyframe(int ext, int keyframe, const rc::KeyframeData* k, const core::UncertainPose2* motion,
                     const ros::Time& stamp);
  void saveMaps();
  /// Stops the recording session in the back-end and the store (its map may be optimised).
  void endActiveSession();
  void fillDiagnostics(diagnostic_updater::DiagnosticStatusWrapper& stat);

  core::SlamConfig config_;
  double diagnostic_period_s_ = 1.0;
  std::unique_ptr<diagnostic_updater::Updater> updater_;
  ros_diagnostics::CounterStatus diagnostic_status_;  // the timer's thread only
  ros::WallTimer diagnostic_timer_;
  std::string store_path_;
  std::unique_ptr<core::SessionStore> store_;
  std::unique_ptr<core::ImageHasher> hasher_;
  std::vector<std::int64_t> store_sessions_;  // back-end session -> store id (-1: not yet)
  std::vector<std::int64_t> store_loops_;     // back-end loop -> store id
  std::set<int> unloaded_;                    // stored sessions the loop detector does not know
  long store_errors_ = 0;
  std::string map_frame_ = "map", session_prefix_ = "session_", base_frame_ = "base_link";
  int queue_size_ = 1000, max_waiting_loops_ = 1000;
  bool publish_tf_ = true;
  double stats_period_s_ = 30.0;

  std::mutex queue_mutex_;
  std::condition_variable wake_;
  std::deque<Message> queue_;  // guarded by queue_mutex_
  bool stopping_ = false;      // guarded by queue_mutex_
  long dropped_ = 0;           // guarded by queue_mutex_
  std::thread worker_;

  mutable std::mutex state_mutex_;  // guards everything below
  std::unique_ptr<core::MultiSessionBackend> backend_;
  std::map<int, Session> sessions_;  // by external (odometry) id
  int active_ = -1;                  // external id of the recording session
  std::optional<core::Pose2> active_correction_;  // its map <- odometry correction, as last published
  std::deque<uw_multislam::LoopConstPtr> waiting_;
  std::vector<core::Loop> accepted_;  // for the markers (external session ids)
  int last_optimisations_ = 0, last_joins_ = 0, last_splits_ = 0;
  Counters counts_;
  ros::WallTime last_stats_;

  ros::Publisher trajectory_pub_, markers_pub_, pose_pub_, active_pub_, reloaded_pub_;
  std::map<int, ros::Publisher> path_pubs_;
  std::unique_ptr<tf2_ros::TransformBroadcaster> tf_;
  ros::ServiceServer join_srv_, split_srv_, list_srv_, start_srv_, reload_srv_;
  ros::Subscriber keyframe_sub_, loop_sub_, pose_sub_;  // last: destroyed first
};

BackendNodelet::~BackendNodelet() {
  diagnostic_timer_.stop();
  keyframe_sub_.shutdown();
  loop_sub_.shutdown();
  pose_sub_.shutdown();
  {
    std::lock_guard<std::mutex> lock(queue_mutex_);
    stopping_ = true;
  }
  wake_.notify_all();
  if (worker_.joinable()) worker_.join();
  if (backend_) logStats("at shutdown");
}

void BackendNodelet::readParameters() {
  ros::NodeHandle& pnh = getPrivateNodeHandle();
  ros::NodeHandle& nh = getNodeHandle();
  using ros_params::param;
  auto nonempty = [](const std::string& s) { return !s.empty(); };
  map_frame_ = param(nh, "frames/map_frame", std::string("map"), nonempty, "a frame id");
  session_prefix_ = param(nh, "frames/session_frame_prefix", std::string("session_"), nonempty, "a frame id prefix");
  base_frame_ = param(nh, "frames/base_frame", std::string("base_link"), nonempty, "a frame id");
  queue_size_ = param(pnh, "queue_size", 1000, [](int v) { return v >= 1 && v <= 1000000; }, "in [1, 1000000]");
  max_waiting_loops_ =
      param(pnh, "max_waiting_loops", 1000, [](int v) { return v >= 1 && v <= 1000000; }, "in [1, 1000000]");
  publish_tf_ = param(pnh, "publish_tf", true, [](bool) { return true; }, "a bool");
  stats_period_s_ = param(pnh, "stats_period_s", 30.0, [](double v) { return v > 0; }, "positive");
  diagnostic_period_s_ = param(pnh, "diagnostic_period", 1.0, [](double v) { return v > 0; }, "positive");
  const char* ros_home = std::getenv("ROS_HOME");
  const char* home = std::getenv("HOME");
  const std::string default_store =
      (ros_home ? std::string(ros_home) : std::string(home ? home : ".") + "/.ros") + "/uw_multislam/sessions.db";
  store_path_ = param(pnh, "store_path", default_store, [](const std::string&) { return true; }, "a path");
  config_ = ros_params::slamConfigFromParams(nh);
  const std::string bad = config_.validate();
  if (!bad.empty()) throw std::invalid_argument(nh.resolveName("slam") + ": " + bad);
}

void BackendNodelet::onInit() {
  try {
    readParameters();
    backend_ = std::make_unique<core::MultiSessionBackend>(
        config_.backend, [this](const std::string& line) { NODELET_INFO("back-end: %s", line.c_str()); });
  } catch (const std::exception& e) {
    NODELET_FATAL("back-end: invalid parameters, not starting: %s", e.what());
    throw;
  }
  const auto& b = config_.backend;
  NODELET_INFO(
      "back-end: optimiser %s (optimise %s, every %d pending loops), join after %d global loops (gate %.2f m), "
      "frames %s -> %s<id> -> %s, tf %s, queue_size %d",
      core::optimizerName(b.optimizer), b.optimise ? "on" : "off", b.optimise_every, b.join_min_loops, b.join_gate_m,
      map_frame_.c_str(), session_prefix_.c_str(), base_frame_.c_str(), publish_tf_ ? "on" : "off", queue_size_);

  ros::NodeHandle& nh = getNodeHandle();
  trajectory_pub_ = nh.advertise<uw_multislam::SessionTrajectory>(topics::kSessionTrajectory, 10);
  markers_pub_ = nh.advertise<visualization_msgs::MarkerArray>(topics::kLoopMarkers, 1, true);
  pose_pub_ = nh.advertise<geometry_msgs::PoseStamped>(topics::kCurrentPose, 10);
  active_pub_ = nh.advertise<uw_multislam::SessionState>(topics::kActiveSession, 1, true);
  if (publish_tf_) tf_ = std::make_unique<tf2_ros::TransformBroadcaster>();
  join_srv_ = nh.advertiseService(topics::kJoinSessionsService, &BackendNodelet::onJoin, this);
  split_srv_ = nh.advertiseService(topics::kSplitSessionService, &BackendNodelet::onSplit, this);
  list_srv_ = nh.advertiseService(topics::kListSessionsService, &BackendNodelet::onList, this);
  start_srv_ = nh.advertiseService(topics::kStartSessionService, &BackendNodelet::onStart, this);
  reload_srv_ = nh.advertiseService(topics::kReloadSessionService, &BackendNodelet::onReload, this);
  reloaded_pub_ = nh.advertise<uw_multislam::Keyframe>(topics::kReloadedKeyframes, 10000);
  try {
    openStore();
  } catch (const std::exception& e) {
    NODELET_FATAL("back-end: session store: %s (set ~store_path to another file, or \"\" to run without a store)",
                  e.what());
    throw;
  }
  updater_ = std::make_unique<diagnostic_updater::Updater>(nh, getPrivateNodeHandle(), getName());
  updater_->setHardwareID("none");
  updater_->add("backend", this, &BackendNodelet::fillDiagnostics);
  diagnostic_timer_ = nh.createWallTimer(ros::WallDuration(diagnostic_period_s_),
                                         [this](const ros::WallTimerEvent&) { updater_->force_update(); });
  if (!sessions_.empty()) {
    // Stored sessions hold ids 0..k-1: the odometry continues from k.
    uw_multislam::SessionState st;
    st.session = sessions_.rbegin()->first + 1;
    st.name = "session_" + std::to_string(st.session);
    st.state = uw_multislam::SessionState::ACTIVE;
    st.map = st.session;
    active_pub_.publish(st);
  }
  worker_ = std::thread([this] { work(); });
  keyframe_sub_ = nh.subscribe<uw_multislam::Keyframe>(topics::kKeyframes, 100,
                                                       [this](const uw_multislam::KeyframeConstPtr& m) { enqueue(m); });
  loop_sub_ = nh.subscribe<uw_multislam::Loop>(topics::kLoops, 100,
                                               [this](const uw_multislam::LoopConstPtr& m) { enqueue(m); });
  pose_sub_ = nh.subscribe(topics::kOdometryPose, 10, &BackendNodelet::onOdometryPose, this);
}

void BackendNodelet::openStore() {
  const auto& g = config_.loops.global;
  hasher_ = std::make_unique<core::ImageHasher>(g.hash_mode, config_.odometry.features.num_features, g.projection_seed);
  if (store_path_.empty()) {
    NODELET_WARN("back-end: no session store (~store_path is empty): sessions live in memory only");
    return;
  }
  const std::filesystem::path dir = std::filesystem::path(store_path_).parent_path();
  std::error_code ec;
  if (!dir.empty()) std::filesystem::create_directories(dir, ec);  // a failure shows in the open below
  store_ = std::make_unique<core::SessionStore>(store_path_);
  store_->checkHashSettings(
      {g.hash_mode, g.projection_seed, config_.odometry.features.num_features, hasher_->projections().toText()});
  std::vector<std::unique_ptr<core::CameraIntrinsics>> no_cameras;
  const core::RestoredStore restored = core::restoreStore(*store_, backend_.get(), nullptr, &no_cameras);
  store_sessions_ = restored.session_ids;
  store_loops_ = restored.loop_ids;
  for (int s = 0; s < backend_->numSessions(); ++s) {
    Session x;
    x.internal = s;
    x.name = backend_->session(s).name;
    const std::vector<core::StoredKeyframe> kfs = store_->keyframes(store_sessions_[s], false);
    for (const auto& k : kfs) x.stamps.push_back(ros::Time(std::max(0.0, k.stamp_s)));
    x.odometry.push_back(core::Pose2());
    for (const core::UncertainPose2& m : store_->odometry(store_sessions_[s]))
      x.odometry.push_back(core::compose(x.odometry.back(), m.mean));
    sessions_[s] = std::move(x);
    unloaded_.insert(s);
  }
  for (std::size_t i = 0; i < restored.loops.size(); ++i) {
    const core::BackendLoop l = backend_->loopRecord(static_cast<int>(i)).loop;
    core::Loop loop;
    loop.kind = restored.loops[i].global ? core::Loop::Kind::kGlobal : core::Loop::Kind::kLocal;
    loop.session_a = l.session_a;
    loop.keyframe_a = l.keyframe_a;
    loop.session_b = l.session_b;
    loop.keyframe_b = l.keyframe_b;
    loop.z = l.z;
    loop.inliers = restored.loops[i].inliers;
    accepted_.push_back(loop);
    ++sessions_[l.session_a].loops;
    if (l.session_b != l.session_a) ++sessions_[l.session_b].loops;
  }
  last_joins_ = backend_->stats().joins;
  NODELET_INFO("back-end: session store %s: %d stored sessions (%d keyframes, %zu loops, %zu maps) listed UNLOADED",
               store_path_.c_str(), backend_->numSessions(), restored.keyframes, restored.loops.size(),
               backend_->mapIds().size());
  if (!sessions_.empty()) publishAll(true);
}

template <typename F>
void BackendNodelet::storeWrite(const char* what, F write) {
  if (!store_) return;
  try {
    write();
  } catch (const std::exception& e) {
    ++store_errors_;
    NODELET_ERROR_THROTTLE(5, "back-end: session store %s: %s failed (%ld failures so far; the map lives on in memory): %s",
                           store_path_.c_str(), what, store_errors_, e.what());
  }
}

void BackendNodelet::storeKeyframe(int ext, int keyframe, const rc::KeyframeData* k, const core::UncertainPose2* motion,
                                   const ros::Time& stamp) {
  if (!store_) return;
  const Session& s = sessions_.at(ext);
  if (store_sessions_.size() <= static_cast<std::size_t>(s.internal)) store_sessions_.resize(s.internal + 1, -1);
  storeWrite("writing a keyframe", [&] {
    if (store_sessions_[s.internal] < 0) {
      store_sessions_[s.internal] = store_->addSession(s.name, k ? k->camera : core::CameraIntrinsics(), stamp.toSec());
    }
    core::StoredKeyframe sk;
    sk.session = store_sessions_[s.internal];
    sk.keyframe = keyframe;
    sk.stamp_s = stamp.toSec();
    sk.hash = Eigen::VectorXf::Zero(core::HalocProjections::kHashSize);
    if (k) {  // else a keyframe that never arrived: no features
      sk.frame_index = k->frame_index;
      sk.altitude_m = k->altitude_m;
      sk.image_size = cv::Size(k->camera.width, k->camera.height);
      for (const cv::KeyPoint& p : k->features.keypoints) sk.points.push_back(p.pt);
      sk.descriptors = k->features.descriptors;
      if (!k->features.descriptors.empty()) sk.hash = hasher_->hash(k->features.descriptors);
    }
    store_->addKeyframe(sk, motion, nullptr);
  });
}

void BackendNodelet::endActiveSession() {
  if (active_ < 0) return;
  const Session& s = sessions_.at(active_);
  backend_->endSession(s.internal);
  storeWrite("ending a session", [&] {
    const std::int64_t id = store_sessions_.at(s.internal);
    if (id >= 0) store_->endSession(id, s.stamps.back().toSec());
  });
  saveMaps();
}

void BackendNodelet::saveMaps() {
  storeWrite("saving the maps", [&] {
    std::vector<std::int64_t> ids = store_sessions_;
    ids.resize(backend_->numSessions(), -1);
    for (std::int64_t id : ids)
      if (id < 0) return;  // a session without a keyframe yet: saved at the next change
    core::saveBackendMaps(store_.get(), *backend_, ids, store_loops_);
  });
}

void BackendNodelet::enqueue(Message m) {
  {
    std::lock_guard<std::mutex> lock(queue_mutex_);
    if (static_cast<int>(queue_.size()) >= queue_size_) {
      queue_.pop_front();
      ++dropped_;
    }
    queue_.push_back(std::move(m));
  }
  wake_.notify_one();
}

void BackendNodelet::work() {
  last_stats_ = ros::WallTime::now();
  for (;;) {
    Message m;
    long dropped = 0;
    {
      std::unique_lock<std::mutex> lock(queue_mutex_);
      wake_.wait(lock, [this] { return stopping_ || !queue_.empty(); });
      if (stopping_) return;
      m = std::move(queue_.front());
      queue_.pop_front();
      dropped = dropped_;
    }
    std::lock_guard<std::mutex> lock(state_mutex_);
    counts_.dropped = dropped;
    try {
      if (const auto* k = std::get_if<uw_multislam::KeyframeConstPtr>(&m)) {
        processKeyframe(**k);
        retryWaitingLoops();
      } else {
        const auto& l = std::get<uw_multislam::LoopConstPtr>(m);
        ++counts_.loops;
        if (!processLoop(*l)) {
          if (static_cast<int>(waiting_.size()) >= max_waiting_loops_) {
            waiting_.pop_front();
            ++counts_.waiting_dropped;
          }
          waiting_.push_back(l);
        }
      }
      const core::BackendStats& st = backend_->stats();
      const bool changed =
          st.optimisations != last_optimisations_ || st.joins != last_joins_ || st.splits != last_splits_;
      if (st.joins != last_joins_ || st.splits != last_splits_) saveMaps();
      last_optimisations_ = st.optimisations;
      last_joins_ = st.joins;
      last_splits_ = st.splits;
      publishAll(changed);
    } catch (const std::exception& e) {
      ++counts_.bad;
      NODELET_ERROR_THROTTLE(5, "back-end: message skipped: %s", e.what());
    }
    if ((ros::WallTime::now() - last_stats_).toSec() > stats_period_s_) {
      logStats("so far");
      last_stats_ = ros::WallTime::now();
    }
  }
}

void BackendNodelet::processKeyframe(const uw_multislam::Keyframe& msg) {
  rc::KeyframeData k;
  std::string why;
  if (!rc::fromMsg(msg, &k, &why)) {
    ++counts_.bad;
    NODELET_WARN_THROTTLE(5, "back-end: keyframe skipped: %s", why.c_str());
    return;
  }
  ++counts_.keyframes;
  auto it = sessions_.find(k.session);
  if (it == sessions_.end()) {
    if (k.session < active_) {
      ++counts_.stale;
      NODELET_WARN_THROTTLE(5, "back-end: keyframe of old session %d skipped (session %d is recording)", k.session,
                            active_);
      return;
    }
    endActiveSession();
    Session s;
    s.name = "session_" + std::to_string(k.session);
    s.internal = backend_->startSession(s.name);
    s.stamps.push_back(msg.header.stamp);
    s.odometry.push_back(core::Pose2());
    it = sessions_.emplace(k.session, std::move(s)).first;
    active_ = k.session;
    NODELET_INFO("back-end: session %d started", k.session);
    storeKeyframe(k.session, 0, k.keyframe == 0 ? &k : nullptr, nullptr, msg.header.stamp);
    if (k.keyframe == 0) return;
  }
  Session& s = it->second;
  if (k.session != active_) {
    ++counts_.stale;
    NODELET_WARN_THROTTLE(5, "back-end: keyframe of finished session %d skipped", k.session);
    return;
  }
  const int expected = static_cast<int>(s.stamps.size());
  if (k.keyframe == 0 && expected == 1) {  // the origin of a session opened by start_session
    s.stamps[0] = msg.header.stamp;
    storeKeyframe(k.session, 0, &k, nullptr, msg.header.stamp);
    return;
  }
  if (k.keyframe < expected) {
    ++counts_.stale;
    NODELET_WARN_THROTTLE(5, "back-end: keyframe %d of session %d received twice or out of order, skipped", k.keyframe,
                          k.session);
    return;
  }
  core::UncertainPose2 motion = k.motion;
  if (k.keyframe > expected) {
    // Keyframes lost on the way (queue overflow): they stay where the last one received is
    // (phantoms, no loop may use them), and this one gets the odometry's motion across the gap.
    ++counts_.gaps;
    NODELET_WARN_THROTTLE(5, "back-end: session %d keyframes %d..%d never arrived, bridged by the odometry", k.session,
                          expected, k.keyframe - 1);
    const core::Pose2 last = s.odometry.back();
    for (int g = expected; g < k.keyframe; ++g) {
      const core::UncertainPose2 still(core::Pose2(), Eigen::Matrix3d::Identity() * 1e-8);
      backend_->addMotion(s.internal, still);
      s.phantoms.insert(g);
      s.stamps.push_back(msg.header.stamp);
      s.odometry.push_back(last);
      storeKeyframe(k.session, g, nullptr, &still, msg.header.stamp);
    }
    motion = core::UncertainPose2(core::between(last, k.odometry_pose),
                                  k.motion.covariance * static_cast<double>(k.keyframe - expected + 1));
  }
  backend_->addMotion(s.internal, motion);
  s.stamps.push_back(msg.header.stamp);
  s.odometry.push_back(k.odometry_pose);
  storeKeyframe(k.session, k.keyframe, &k, &motion, msg.header.stamp);
}

bool BackendNodelet::processLoop(const uw_multislam::Loop& msg) {
  core::Loop l;
  std::string why;
  if (!rc::fromMsg(msg, &l, &why)) {
    ++counts_.refused;
    NODELET_WARN_THROTTLE(5, "back-end: loop skipped: %s", why.c_str());
    return true;
  }
  const auto a = sessions_.find(l.session_a), b = sessions_.find(l.session_b);
  if (a == sessions_.end() || b == sessions_.end() || l.keyframe_a >= static_cast<int>(a->second.stamps.size()) ||
      l.keyframe_b >= static_cast<int>(b->second.stamps.size())) {
    return false;  // a keyframe still on its way
  }
  if (a->second.phantoms.count(l.keyframe_a) || b->second.phantoms.count(l.keyframe_b)) {
    ++counts_.refused;
    NODELET_WARN_THROTTLE(5, "back-end: loop on a keyframe that never arrived, skipped");
    return true;
  }
  try {
    backend_->addLoop({a->second.internal, l.keyframe_a, b->second.internal, l.keyframe_b, l.z});
  } catch (const std::invalid_argument& e) {
    ++counts_.refused;
    NODELET_WARN_THROTTLE(5, "back-end: loop refused: %s", e.what());
    return true;
  }
  ++a->second.loops;
  if (l.session_b != l.session_a) ++b->second.loops;
  accepted_.push_back(l);
  std::int64_t stored = -1;
  storeWrite("writing a loop", [&] {
    std::vector<core::StoredLoop> one(1);
    core::StoredLoop& sl = one[0];
    sl.session_a = store_sessions_.at(a->second.internal);
    sl.session_b = store_sessions_.at(b->second.internal);
    sl.keyframe_a = l.keyframe_a;
    sl.keyframe_b = l.keyframe_b;
    sl.global = l.kind == core::Loop::Kind::kGlobal;
    sl.inliers = l.inliers;
    sl.z = l.z;
    store_->addLoops(&one);
    stored = sl.id;
  });
  if (store_) store_loops_.push_back(stored);
  return true;
}

void BackendNodelet::retryWaitingLoops() {
  std::deque<uw_multislam::LoopConstPtr> still;
  for (const auto& l : waiting_)
    if (!processLoop(*l)) still.push_back(l);
  waiting_.swap(still);
}

int BackendNodelet::externalOf(int internal) const {
  for (const auto& [ext, s] : sessions_)
    if (s.internal == internal) return ext;
  return -1;
}

void BackendNodelet::publishSession(int ext, const std::vector<core::Pose2>& poses) {
  const Session& s = sessions_.at(ext);
  // The correction optimisation applied to the session's odometry (map -> session frame).
  const core::Pose2 correction = core::compose(poses.back(), core::invert(s.odometry.back()));
  if (ext == active_) active_correction_ = correction;
  const ros::Time now = s.stamps.empty() ? ros::Time::now() : s.stamps.back();
  uw_multislam::SessionTrajectory t;
  t.header.stamp = now;
  t.header.frame_id = session_prefix_ + std::to_string(ext);
  t.session = ext;
  t.map = externalOf(backend_->mapOf(s.internal));
  const core::Pose2 origin_inv = core::invert(poses.front());
  for (const core::Pose2& p : poses) t.poses.push_back(rc::toPose2DMsg(core::compose(origin_inv, p)));
  trajectory_pub_.publish(t);
  auto pub = path_pubs_.find(ext);
  if (pub == path_pubs_.end()) {
    pub = path_pubs_
              .emplace(ext, getNodeHandle().advertise<nav_msgs::Path>(
                                topics::kSessionPathPrefix + std::to_string(ext), 1, true))
              .first;
  }
  pub->second.publish(rc::toPathMsg(poses, s.stamps, map_frame_, now));
  if (tf_) {
    geometry_msgs::TransformStamped tr;
    tr.header.stamp = now;
    tr.header.frame_id = map_frame_;
    tr.child_frame_id = session_prefix_ + std::to_string(ext);
    tr.transform = rc::toTransformMsg(correction);
    tf_->sendTransform(tr);
  }
}

void BackendNodelet::publishAll(bool all_sessions) {
  // Each session's poses once (sessionPoses walks its map's chain).
  std::map<int, std::vector<core::Pose2>> poses;  // by back-end session
  auto posesOf = [&](int internal) -> const std::vector<core::Pose2>& {
    auto it = poses.find(internal);
    if (it == poses.end()) it = poses.emplace(internal, backend_->sessionPoses(internal)).first;
    return it->second;
  };
  if (all_sessions) {
    for (const auto& [ext, s] : sessions_) publishSession(ext, posesOf(s.internal));
  } else if (active_ >= 0) {
    publishSession(active_, posesOf(sessions_.at(active_).internal));
  }
  std::vector<rc::Segment> segments;
  for (const core::Loop& l : accepted_) {
    const int ia = sessions_.at(l.session_a).internal, ib = sessions_.at(l.session_b).internal;
    if (backend_->mapOf(ia) != backend_->mapOf(ib)) continue;
    segments.push_back({posesOf(ia)[l.keyframe_a], posesOf(ib)[l.keyframe_b],
                        l.kind == core::Loop::Kind::kLocal ? rc::Segment::Kind::kLocal : rc::Segment::Kind::kGlobal});
  }
  for (int m : backend_->mapIds())
    for (const core::LinkInfo& link : backend_->links(m))
      segments.push_back({posesOf(link.previous).back(), posesOf(link.current).front(),
                          rc::Segment::Kind::kJoin});
  markers_pub_.publish(rc::toMarkerArrayMsg(segments, map_frame_, ros::Time::now()));
}

void BackendNodelet::onOdometryPose(const geometry_msgs::PoseStampedConstPtr& msg) {
  core::Pose2 odo;
  if (!rc::fromMsg(msg->pose, &odo)) return;
  core::Pose2 corr;
  int active;
  {
    std::lock_guard<std::mutex> lock(state_mutex_);
    if (active_ < 0 || !active_correction_) return;
    active = active_;
    corr = *active_correction_;  // kept by publishSession: no walk of the map per frame
  }
  geometry_msgs::PoseStamped p;
  p.header.stamp = msg->header.stamp;
  p.header.frame_id = map_frame_;
  p.pose = rc::toPoseMsg(core::compose(corr, odo));
  pose_pub_.publish(p);
  if (tf_) {
    geometry_msgs::TransformStamped tr;
    tr.header.stamp = msg->header.stamp;
    tr.header.frame_id = session_prefix_ + std::to_string(active);
    tr.child_frame_id = base_frame_;
    tr.transform = rc::toTransformMsg(odo);
    tf_->sendTransform(tr);
  }
}

bool BackendNodelet::onJoin(uw_multislam::JoinSessions::Request& req, uw_multislam::JoinSessions::Response& res) {
  std::lock_guard<std::mutex> lock(state_mutex_);
  for (int s : {req.session_a, req.session_b}) {
    if (!sessions_.count(s)) {
      res.status = rc::statusMsg(uw_multislam::Status::NOT_FOUND,
                                 "no session " + std::to_string(s) + " (call list_sessions for the ids)");
      return true;
    }
  }
  if (req.min_loops < 0) {
    res.status = rc::statusMsg(uw_multislam::Status::INVALID_ARGUMENT, "min_loops must be >= 0 (0: the configured K)");
    return true;
  }
  const int min_loops = req.min_loops > 0 ? req.min_loops : std::max(1, config_.backend.join_min_loops);
  const core::BackendStatus st =
      backend_->join(sessions_.at(req.session_a).internal, sessions_.at(req.session_b).internal, min_loops);
  res.status = rc::toStatusMsg(st);
  res.map = externalOf(backend_->mapOf(sessions_.at(req.session_a).internal));
  if (st.ok()) {
    NODELET_INFO("back-end: join_sessions %d %d: %s", req.session_a, req.session_b, st.message.c_str());
    last_joins_ = backend_->stats().joins;
    saveMaps();
    publishAll(true);
  }
  return true;
}

bool BackendNodelet::onSplit(uw_multislam::SplitSession::Request& req, uw_multislam::SplitSession::Response& res) {
  std::lock_guard<std::mutex> lock(state_mutex_);
  if (!sessions_.count(req.session)) {
    res.status = rc::statusMsg(uw_multislam::Status::NOT_FOUND,
                               "no session " + std::to_string(req.session) + " (call list_sessions for the ids)");
    return true;
  }
  const core::BackendStatus st = backend_->split(sessions_.at(req.session).internal);
  res.status = rc::toStatusMsg(st);
  if (st.ok()) {
    NODELET_INFO("back-end: split_session %d: %s", req.session, st.message.c_str());
    last_splits_ = backend_->stats().splits;
    saveMaps();
    publishAll(true);
  }
  return true;
}

bool BackendNodelet::onList(uw_multislam::ListSessions::Request&, uw_multislam::ListSessions::Response& res) {
  std::lock_guard<std::mutex> lock(state_mutex_);
  for (const auto& [ext, s] : sessions_) {
    const core::SessionInfo info = backend_->session(s.internal);
    uw_multislam::SessionState st;
    st.session = ext;
    st.name = s.name;
    st.state = info.recording           ? uw_multislam::SessionState::ACTIVE
               : unloaded_.count(ext) ? uw_multislam::SessionState::UNLOADED
                                      : uw_multislam::SessionState::FINISHED;
    st.map = externalOf(info.map);
    st.num_keyframes = info.keyframes;
    st.num_loops = s.loops;
    if (!s.stamps.empty()) {
      st.first_stamp = s.stamps.front();
      st.last_stamp = s.stamps.back();
    }
    res.sessions.push_back(st);
  }
  res.status = rc::statusMsg(uw_multislam::Status::OK, "");
  return true;
}

bool BackendNodelet::onStart(uw_multislam::StartSession::Request& req, uw_multislam::StartSession::Response& res) {
  std::lock_guard<std::mutex> lock(state_mutex_);
  for (const auto& [ext, s] : sessions_) {
    if (!req.name.empty() && s.name == req.name) {
      res.status = rc::statusMsg(uw_multislam::Status::ALREADY_EXISTS,
                                 "a session is already named '" + req.name + "' (session " + std::to_string(ext) + ")");
      return true;
    }
  }
  const int ext = sessions_.empty() ? 0 : sessions_.rbegin()->first + 1;
  endActiveSession();
  Session s;
  s.name = req.name.empty() ? "session_" + std::to_string(ext) : req.name;
  s.internal = backend_->startSession(s.name);
  s.stamps.push_back(ros::Time::now());
  s.odometry.push_back(core::Pose2());
  sessions_.emplace(ext, std::move(s));
  active_ = ext;
  uw_multislam::SessionState st;
  st.session = ext;
  st.name = sessions_.at(ext).name;
  st.state = uw_multislam::SessionState::ACTIVE;
  st.map = ext;
  st.num_keyframes = 1;
  active_pub_.publish(st);
  res.session = ext;
  res.status = rc::statusMsg(uw_multislam::Status::OK, "");
  NODELET_INFO("back-end: start_session: session %d '%s' started; the odometry's next keyframe is its origin", ext,
               st.name.c_str());
  publishAll(true);
  return true;
}

bool BackendNodelet::onReload(uw_multislam::ReloadSession::Request& req, uw_multislam::ReloadSession::Response& res) {
  std::lock_guard<std::mutex> lock(state_mutex_);
  res.session = -1;
  if (!store_) {
    res.status = rc::statusMsg(uw_multislam::Status::FAILED_PRECONDITION,
                               "no session store: ~store_path is empty, nothing to reload");
    return true;
  }
  // By name, or by id ("3").
  int ext = -1;
  for (const auto& [id, s] : sessions_)
    if (s.name == req.name || std::to_string(id) == req.name) ext = id;
  if (ext < 0 || store_sessions_.size() <= static_cast<std::size_t>(ext) || store_sessions_[ext] < 0) {
    res.status = rc::statusMsg(uw_multislam::Status::NOT_FOUND,
                               "no stored session named '" + req.name + "' in " + store_path_ +
                                   " (list_sessions shows the stored ones as UNLOADED)");
    return true;
  }
  if (!unloaded_.count(ext)) {
    res.status = rc::statusMsg(uw_multislam::Status::ALREADY_EXISTS,
                               "session " + std::to_string(ext) + " ('" + sessions_.at(ext).name + "') is already loaded");
    res.session = ext;
    return true;
  }
  std::vector<core::StoredKeyframe> kfs;
  core::CameraIntrinsics camera;
  try {
    kfs = store_->keyframes(store_sessions_[ext], true);
    for (const core::StoredSession& s : store_->sessions())
      if (s.id == store_sessions_[ext]) camera = s.camera;
  } catch (const std::exception& e) {
    res.status = rc::statusMsg(uw_multislam::Status::DATA_LOSS, "reading " + store_path_ + ": " + e.what());
    return true;
  }
  for (const core::StoredKeyframe& k : kfs) {
    rc::KeyframeData d;
    d.session = ext;
    d.keyframe = k.keyframe;
    d.frame_index = k.frame_index;
    d.altitude_m = k.altitude_m > 0 ? k.altitude_m : 1.0;
    d.camera = camera;
    d.features.image_size = k.image_size;
    for (const cv::Point2f& p : k.points) d.features.keypoints.emplace_back(p, 1.0f);
    if (!k.descriptors.empty()) k.descriptors.convertTo(d.features.descriptors, CV_32F);
    d.motion = core::UncertainPose2(core::Pose2(), Eigen::Matrix3d::Identity() * 1e-6);
    d.quality = k.keyframe == 0 ? rc::KeyframeQuality::kFirst : rc::KeyframeQuality::kMatched;
    std_msgs::Header h;
    h.stamp = ros::Time(std::max(0.0, k.stamp_s));
    h.frame_id = session_prefix_ + std::to_string(ext);
    reloaded_pub_.publish(boost::make_shared<uw_multislam::Keyframe>(rc::toKeyframeMsg(d, h)));
  }
  unloaded_.erase(ext);
  res.session = ext;
  res.status = rc::statusMsg(uw_multislam::Status::OK, "");
  NODELET_INFO("back-end: reload_session '%s': session %d, %zu keyframes handed to the loop detector", req.name.c_str(),
               ext, kfs.size());
  return true;
}

void BackendNodelet::fillDiagnostics(diagnostic_updater::DiagnosticStatusWrapper& stat) {
  long dropped = 0, queued = 0;
  {
    std::lock_guard<std::mutex> lock(queue_mutex_);
    dropped = dropped_;
    queued = static_cast<long>(queue_.size());
  }
  std::lock_guard<std::mutex> lock(state_mutex_);
  const core::BackendStats& b = backend_->stats();
  auto d = [](auto v) { return static_cast<double>(v); };
  stat.add("optimizer", core::optimizerName(config_.backend.optimizer));
  stat.add("store", store_ ? store_path_ : std::string("none"));
  diagnostic_status_.fill(stat,
                          {{"keyframes_received", d(counts_.keyframes)},
                           {"keyframes_stale", d(counts_.stale), true},
                           {"keyframe_gaps", d(counts_.gaps), true},
                           {"loops_received", d(counts_.loops)},
                           {"loops_refused", d(counts_.refused), true},
                           {"loops_waiting", d(waiting_.size())},
                           {"loops_dropped_waiting", d(counts_.waiting_dropped), true},
                           {"dropped_queue_full", d(dropped), true},
                           {"queue_length", d(queued)},
                           {"bad_messages", d(counts_.bad), true},
                           {"store_failures", d(store_errors_), true},
                           {"sessions", d(sessions_.size())},
                           {"sessions_unloaded", d(unloaded_.size())},
                           {"maps", d(backend_->mapIds().size())},
                           {"joins", d(b.joins)},
                           {"splits", d(b.splits)},
                           {"loops_refused_at_join", d(b.loops_refused)},
                           {"optimisations", d(b.optimisations)},
                           {"optimise_ms_max", b.optimise_ms_max}},
                          ros::WallTime::now().toSec());
}

void BackendNodelet::logStats(const char* when) {
  const core::BackendStats& b = backend_->stats();
  NODELET_INFO(
      "back-end %s: %ld keyframes (%ld stale, %ld gaps), %ld loops (%ld refused, %zu waiting, %ld dropped while "
      "waiting), %ld messages dropped (queue full), %ld bad, %ld store failures; %d joins, %d splits, %d "
      "optimisations (%.1f ms max), %zu maps",
      when, counts_.keyframes, counts_.stale, counts_.gaps, counts_.loops, counts_.refused, waiting_.size(),
      counts_.waiting_dropped, counts_.dropped, counts_.bad, store_errors_, b.joins, b.splits, b.optimisations, b.optimise_ms_max,
      backend_->mapIds().size());
}

}  // namespace nodelets
}  // namespace uw_multislam

PLUGINLIB_EXPORT_CLASS(uw_multislam::nodelets::BackendNodelet, nodelet::Nodelet)
