// The back-end nodelet: threading in its header; behaviour in doc/nodes/backend.md, ROS API in doc/ros_api.md.
#include "uw_multislam/ros/nodelets/backend_nodelet.h"

#include <pluginlib/class_list_macros.hpp>

#include <cstdio>
#include <utility>

#include "uw_multislam/core/session/stored_loops.h"
#include "uw_multislam/ros/backend_conversions.h"
#include "uw_multislam/ros/conversions.h"
#include "uw_multislam/ros/topics.h"

namespace uw_multislam {
namespace nodelets {

namespace rc = ros_conversions;
using core::SessionManager;
using core::Status;
using core::StatusCode;

BackendNodelet::~BackendNodelet() {
  for (ros::WallTimer* t : {&diagnostic_timer_, &stats_timer_}) t->stop();
  for (ros::Subscriber* s : {&keyframe_sub_, &loop_sub_, &pose_sub_}) s->shutdown();
  if (!worker_) return;
  if (fleet_) fleet_->stopListening();
  say("unloading: " + std::to_string(worker_->stats().queued) +
      " messages queued, processed before the maps are saved");
  worker_->stop();  // processes what is queued
  worker_->locked([this](SessionManager& m) {
    m.flush();  // pending optimisation, and the maps saved
    say(ros_diagnostics::countersLine("counters at shutdown:", counters(m.view())));
    try {  // now, while every member onEvent reports to is alive (the manager's destructor would do it)
      m.fleet().finishAll();
    } catch (const std::exception& e) {
      say(std::string("other vehicles' sessions not finished at shutdown: ") + e.what());
    }
  });
  mosaic_.reset();  // its thread takes the worker's lock: stopped while the worker lives
}

void BackendNodelet::onInit() {
  // The worker (the manager and the store behind it) first: nothing is advertised before it is
  // usable, and a refused store leaves the nodelet inert instead of throwing out of onInit (which
  // took the whole nodelet manager down with it).
  ros::NodeHandle& nh = getNodeHandle();
  try {
    options_ = ros_params::backendNodeletOptions(nh, getPrivateNodeHandle());
    config_ = ros_params::slamConfigFromParams(nh);
    const std::string bad = config_.validate();
    if (!bad.empty()) throw std::invalid_argument(nh.resolveName("slam") + ": " + bad);
    worker_ = ros_params::makeSessionWorker(
        options_, config_, [this](const core::SessionEvent& e) { onEvent(e); },
        [this](const std::string& line) { say(line); });
    frames_ = std::make_unique<ros_frames::FramePublisher>(nh, options_.frames);  // a tilted camera throws
    datum_ = std::make_unique<ros_geo::DatumService>(  // set_datum; a polar datum with a UTM frame throws
        nh, worker_.get(), frames_.get(), options_.frames, [this](const std::string& line) { say(line); });
  } catch (const std::exception& e) {
    NODELET_FATAL(
        "back-end: not starting (no topics, no services): %s%s", e.what(),
        options_.store_path.empty() ? "" : " (set ~store_path to another file, or \"\" to run without a store)");
    worker_.reset();
    return;
  }
  sessions_ = std::make_unique<ros_sessions::SessionPublisher>(nh, frames_.get(), options_.frames,
                                                               [this](const std::string& line) { say(line); });
  datum_->republishWith([this](const core::SessionQueries& m) {  // new axes: every pose, and the mosaic drawn again
    sessions_->publishAll(m, true);
    if (mosaic_) mosaic_->markDue();
  });
  if (options_.reload_stored) worker_->reloadStored();  // handed to every loop detector that subscribes
  reloaded_ = std::make_unique<ros_sessions::ReloadedKeyframesPublisher>(getMTNodeHandle(), worker_.get(),
                                                                         options_.frames.session_frame_prefix);
  mosaic_ = std::make_unique<ros_mosaic::LiveMosaicPublisher>(nh, *worker_, options_.mosaic_rate_hz, options_.mosaic,
                                                              options_.frames.map_frame,
                                                              [this] { return frames_->mapFrame(); });
  exporter_ = std::make_unique<core::SessionExporter>(options_.export_root);
  if (std::string why; !exporter_->createRoot(&why))
    NODELET_WARN("back-end: ~export_root: %s: export answers FAILED_PRECONDITION", why.c_str());
  for (const std::string& line : ros_params::describeBackend(options_, config_)) say(line);
  peers_ = std::make_unique<ros_fleet::PeerClient>(nh, options_.fleet_peers, options_.fleet_peer_timeout_s);
  worker_->locked([this](const core::SessionQueries& m) {
    if (m.nextId() == 0) return;  // an empty store, or none: the odometry starts at 0 anyway
    sessions_->publishAll(m, true);
    // Stored sessions keep their store ids: the odometry continues past every one of them (and
    // past deleted ones), so its next session's id is new and becomes its store id.
    sessions_->announceNextSession(m);
  });
  if (!options_.fleet_vehicle.empty())
    fleet_ = std::make_unique<ros_fleet::HashExchange>(
        nh, options_.fleet_vehicle, options_.queue_size, options_.fleet_hash_codes,
        options_.frames.session_frame_prefix, worker_.get(),
        [this](const core::SessionQueries& m) { sessions_->announceNextId(m); });
  status_ = std::make_unique<ros_status::BackendStatusPublisher>(nh, worker_.get(), options_.frames.base_frame);
  worker_->start([this](SessionManager& m) {
    sessions_->publishAll(m.view(), std::exchange(publish_all_, false));
    status_->afterItem(m.view());  // at each keyframe: the status
  });
  services_ = {
      nh.advertiseService(topics::kJoinSessionsService, &BackendNodelet::onJoin, this),
      nh.advertiseService(topics::kSplitSessionService, &BackendNodelet::onSplit, this),
      nh.advertiseService(topics::kListSessionsService, &BackendNodelet::onList, this),
      nh.advertiseService(topics::kStartSessionService, &BackendNodelet::onStart, this),
      nh.advertiseService(topics::kFinishSessionService, &BackendNodelet::onFinish, this),
      nh.advertiseService(topics::kAddLinkService, &BackendNodelet::onAddLink, this),
      nh.advertiseService(topics::kOptimiseService, &BackendNodelet::onOptimise, this),
      nh.advertiseService(topics::kDetectLoopsService, &BackendNodelet::onDetectLoops, this),
      nh.advertiseService(topics::kSetModeService, &BackendNodelet::onSetMode, this),
      nh.advertiseService(topics::kHistoryService, &BackendNodelet::onHistory, this),
      nh.advertiseService(topics::kReloadSessionService, &BackendNodelet::onReload, this),
      nh.advertiseService(topics::kUnloadSessionService, &BackendNodelet::onUnload, this),
      nh.advertiseService(topics::kDeleteSessionService, &BackendNodelet::onDelete, this),
      nh.advertiseService(topics::kExportService, &BackendNodelet::onExport, this),
      // Multi-threaded: one forwarded to another vehicle waits up to ~fleet/peer_timeout_s, no other service.
      getMTNodeHandle().advertiseService(topics::kKeyframeFeaturesService, &BackendNodelet::onKeyframeFeatures, this)};
  updater_ = std::make_unique<diagnostic_updater::Updater>(nh, getPrivateNodeHandle(), getName());
  updater_->setHardwareID("none");
  updater_->add("backend", this, &BackendNodelet::fillDiagnostics);
  diagnostic_timer_ = nh.createWallTimer(ros::WallDuration(options_.diagnostic_period_s),
                                         [this](const ros::WallTimerEvent&) { updater_->force_update(); });
  stats_timer_ = nh.createWallTimer(ros::WallDuration(options_.stats_period_s), [this](const ros::WallTimerEvent&) {
    worker_->locked(
        [this](const core::SessionQueries& m) { say(ros_diagnostics::countersLine("counters so far:", counters(m))); });
  });
  // roscpp's own queues as deep as the worker's: a starved callback thread must not drop uncounted.
  keyframe_sub_ = nh.subscribe(topics::kKeyframes, options_.queue_size, &BackendNodelet::onKeyframe, this);
  loop_sub_ = nh.subscribe(topics::kLoops, options_.queue_size, &BackendNodelet::onLoop, this);
  if (fleet_) fleet_->listen(nh, options_.queue_size, options_.fleet_peers);
  pose_sub_ = nh.subscribe(topics::kOdometryPose, 10, &ros_sessions::SessionPublisher::onOdometry, sessions_.get());
  fix_ = ros_geo::FixInput::make(nh, options_, worker_.get(), frames_.get());  // NavSatFix: position priors
}

void BackendNodelet::onKeyframe(const uw_multislam::KeyframeConstPtr& msg) {
  ++received_;
  rc::KeyframeData k;
  std::string why;
  if (!rc::fromMsg(*msg, &k, &why)) {
    ++bad_keyframes_;
    NODELET_WARN_THROTTLE(5, "back-end: keyframe skipped: %s", why.c_str());
    return;
  }
  if (fleet_) fleet_->hashIfMissing(&k);  // once, here: the manager takes this hash too
  core::KeyframeInput input = rc::toKeyframeInput(k, msg->header.stamp.toSec());
  k.features = core::FrameFeatures();  // the input has them; the link needs the hash, motion and pose only
  k.thumbnail.clear();
  worker_->addKeyframe(std::move(input), {},
                       [this, k, header = msg->header](const core::SessionQueries& m, const core::KeyframeInput& in,
                                                       const Status& st) mutable {
                         if (!st.ok()) {
                           NODELET_WARN_THROTTLE(5, "back-end: keyframe skipped: %s", st.message.c_str());
                           return;
                         }
                         mosaic_->add(in.session, in.keyframe, in.altitude_m, in.camera, in.thumbnail);
                         if (fleet_) fleet_->sendOurs(m, std::move(k), header);
                       });
}

void BackendNodelet::onLoop(const uw_multislam::LoopConstPtr& msg) {
  ++received_;
  core::Loop l;
  std::string why;
  if (!rc::fromMsg(*msg, &l, &why)) {
    ++bad_loops_;
    NODELET_WARN_THROTTLE(5, "back-end: loop skipped: %s", why.c_str());
    return;
  }
  worker_->addLoop(l);
}

void BackendNodelet::onEvent(const core::SessionEvent& e) {
  using K = core::SessionEvent::Kind;
  if (e.kind == K::kSessionEnded && fleet_ && e.vehicle.empty()) fleet_->sessionEnded(e.session);
  if (mosaic_) mosaic_->markDue();  // a keyframe, a join, a split, an optimisation: the active map may change
  const bool changed = e.kind != K::kKeyframeAdded && e.kind != K::kLoopAccepted;  // every session to publish
  publish_all_ = publish_all_ || changed;
  if (changed && e.kind != K::kMapOptimised) say(std::string(core::sessionEventName(e.kind)) + ": " + e.message);
}

// --- Services: each locks (through the worker) and delegates; optimisation is left to the worker.

template <typename F>
uw_multislam::Status BackendNodelet::change(F request) {
  const Status st = worker_->locked([&](SessionManager& m) {
    const Status st = request(m);
    if (st.ok()) sessions_->publishAll(m.view(), true);  // lists, states, maps: every session
    return st;
  });
  if (st.ok()) worker_->optimiseDue();  // what the request left due, solved by the worker
  return answer(st, "request");
}

uw_multislam::Status BackendNodelet::answer(const core::Status& st, const char* service) const {
  const core::Status out = core::withRoles(st, core::pathRoles(options_.store_path, options_.export_root));
  if (out.message != st.message) NODELET_WARN("back-end: %s: %s", service, st.message.c_str());
  return rc::toStatusMsg(out);
}

bool BackendNodelet::onJoin(uw_multislam::JoinSessions::Request& req, uw_multislam::JoinSessions::Response& res) {
  res.status = change([&](SessionManager& m) {
    const Status st = m.join(req.session_a, req.session_b, req.min_loops);
    res.map = m.view().has(req.session_a) ? m.view().mapOf(req.session_a) : -1;
    return st;
  });
  return true;
}

bool BackendNodelet::onSplit(uw_multislam::SplitSession::Request& req, uw_multislam::SplitSession::Response& res) {
  res.status = change([&](SessionManager& m) { return m.split(req.session); });
  return true;
}

bool BackendNodelet::onList(uw_multislam::ListSessions::Request&, uw_multislam::ListSessions::Response& res) {
  worker_->locked([&](const core::SessionQueries& m) {
    for (const core::SessionSummary& s : m.list()) {
      res.sessions.push_back(rc::toSessionStateMsg(s));
      if (m.restored(s.id)) continue;  // stored sessions: only this run's relocalise
      if (const auto r = m.relocalise(s.id)) res.sessions.back().relocalised_map = r->map;
    }
  });
  res.status = answer(Status::Ok(), "list_sessions");
  return true;
}

bool BackendNodelet::onStart(uw_multislam::StartSession::Request& req, uw_multislam::StartSession::Response& res) {
  res.session = -1;
  res.status = change([&](SessionManager& m) {
    const Status st = m.startSession(req.name, ros::Time::now().toSec(), -1, &res.session);
    if (!st.ok()) return st;
    sessions_->announceNextSession(m.view());
    NODELET_INFO("back-end: start_session: session %d '%s' started; the odometry's next keyframe is its origin",
                 res.session, m.view().name(res.session).c_str());
    return st;
  });
  return true;
}

bool BackendNodelet::onFinish(uw_multislam::FinishSession::Request&, uw_multislam::FinishSession::Response& res) {
  res.session = -1;
  res.status = change([&](SessionManager& m) {
    const int id = m.view().activeSession();
    const Status st = m.endSession(ros::Time::now().toSec());
    if (!st.ok()) return st;
    res.session = id;
    // No session records now: the odometry drops frames until start_session or resume, then
    // starts the session with the next id.
    sessions_->announceNextSession(m.view(), uw_multislam::SessionState::FINISHED);
    sessions_->resetRelocalisation();  // no active session: nothing relocalised (diagnostics)
    NODELET_INFO("back-end: finish_session: session %d '%s' finished; the odometry waits for start_session or resume",
                 id, m.view().name(id).c_str());
    return st;
  });
  return true;
}

bool BackendNodelet::onAddLink(uw_multislam::AddLink::Request& req, uw_multislam::AddLink::Response& res) {
  core::Loop l;  // checked as a detector's loop is, then by the core (find: RANSAC on the stored features)
  std::string why;
  if (!rc::fromAddLinkRequest(req, &l, &why)) {
    res.status = answer({StatusCode::kInvalidArgument, "add_link: " + why}, "add_link");
    return true;
  }
  res.status =
      change([&](SessionManager& m) { return core::addOperatorLink(&m, config_, req.find, &l, req.pose.theta); });
  res.pose = rc::toPose2DMsg(l.z.mean);
  res.inliers = l.inliers;
  return true;
}

bool BackendNodelet::onOptimise(uw_multislam::Optimise::Request&, uw_multislam::Optimise::Response& res) {
  res.status = answer(worker_->locked([&](SessionManager& m) { return m.optimisePending(&res.maps); }), "optimise");
  if (res.status.code == uw_multislam::Status::OK && res.maps > 0) worker_->optimiseDue();  // the worker solves them
  return true;
}

bool BackendNodelet::onHistory(uw_multislam::History::Request& req, uw_multislam::History::Response& res) {
  worker_->locked([&](const core::SessionQueries& m) { res = rc::toHistoryResponse(m.history(), req.last); });
  return true;
}

bool BackendNodelet::onDetectLoops(uw_multislam::DetectLoops::Request& req, uw_multislam::DetectLoops::Response& res) {
  core::StoredLoopSearch f;
  int joins = 0;
  const Status st = worker_->locked([&](SessionManager& m) {  // the worker waits meanwhile
    joins = -m.view().backendStats().joins;
    const Status st = core::detectStoredLoops(&m, config_, req.sessions, &f, [this](const std::string& l) { say(l); });
    joins += m.view().backendStats().joins;
    if (f.accepted > 0) sessions_->publishAll(m.view(), true);
    return st;
  });
  res = rc::toDetectLoopsResponse(st, f, joins);
  res.status = answer(st, "detect_loops");
  NODELET_INFO("back-end: detect_loops: %s", rc::detectLoopsLine(st, f, joins).c_str());
  if (f.accepted > 0) worker_->optimiseDue();  // the maps the loops touched may be due
  return true;
}

bool BackendNodelet::onSetMode(uw_multislam::SetMode::Request& req, uw_multislam::SetMode::Response& res) {
  const Status st = worker_->locked([&](SessionManager& m) {
    const Status st = rc::setMode(&m, req.mode);
    res.mode = m.view().localising() ? "localisation" : "mapping";
    return st;
  });
  res.status = answer(st, "set_mode");
  if (st.ok()) NODELET_INFO("back-end: set_mode %s: %s", res.mode.c_str(), st.message.c_str());
  return true;
}

bool BackendNodelet::onReload(uw_multislam::ReloadSession::Request& req, uw_multislam::ReloadSession::Response& res) {
  core::ReloadedSession r;
  const Status st = reloaded_->reload(req.name, &r);
  res.status = answer(st, "reload_session");
  res.session = r.id;
  if (!st.ok()) return true;
  mosaic_->add(r);
  NODELET_INFO("back-end: reload_session '%s': session %d, %zu keyframes handed to the loop detector", req.name.c_str(),
               r.id, r.keyframes.size());
  return true;
}

void BackendNodelet::forgetSession(int id) {
  reloaded_->forget(id);
  mosaic_->removeSession(id);
}

bool BackendNodelet::onUnload(uw_multislam::ReloadSession::Request& req, uw_multislam::ReloadSession::Response& res) {
  res.session = -1;
  res.status = change([&](SessionManager& m) {
    const Status st = m.unload(req.name, &res.session);
    if (st.ok()) forgetSession(res.session), ++sessions_unloaded_;  // under the lock: in order with the handover
    return st;
  });
  if (res.status.code == uw_multislam::Status::OK)
    NODELET_INFO("back-end: unload_session '%s': session %d UNLOADED, the loop detectors forget its keyframes",
                 req.name.c_str(), res.session);
  else
    NODELET_WARN("back-end: unload_session '%s' refused: %s", req.name.c_str(), res.status.message.c_str());
  return true;
}

bool BackendNodelet::onDelete(uw_multislam::DeleteSession::Request& req, uw_multislam::DeleteSession::Response& res) {
  res.session = -1;
  res.status = change([&](SessionManager& m) {
    const Status st = m.deleteSession(req.name, req.confirm, &res.session);
    if (st.ok()) forgetSession(res.session), sessions_->clearPath(res.session), ++sessions_deleted_;
    return st;
  });
  if (res.status.code == uw_multislam::Status::OK)
    NODELET_WARN("back-end: delete_session '%s': session %d deleted from the store and from memory", req.name.c_str(),
                 res.session);
  else
    NODELET_WARN("back-end: delete_session '%s' refused: %s", req.name.c_str(), res.status.message.c_str());
  return true;
}

bool BackendNodelet::onExport(uw_multislam::ExportSurvey::Request& req, uw_multislam::ExportSurvey::Response& res) {
  core::SessionExport out;
  const Status st = exporter_->run(
      *worker_, {req.session, req.folder, req.origin, req.resolution_m, !req.no_mosaic, static_cast<bool>(req.map)},
      &out);
  res.status = answer(st, "export");
  if (!st.ok()) {
    NODELET_WARN("back-end: export '%s' refused: %s", req.session.c_str(), st.message.c_str());
    return true;
  }
  res.directory = out.directory;
  res.files = out.files;
  NODELET_INFO("back-end: export: %s (%s, %zu keyframes) written to %s: %zu files", out.label.c_str(), out.name.c_str(),
               out.keyframes, out.directory.c_str(), out.files.size());
  return true;
}

bool BackendNodelet::onKeyframeFeatures(uw_multislam::KeyframeFeatures::Request& req,
                                        uw_multislam::KeyframeFeatures::Response& res) {
  core::KeyframeFeaturesAnswer a;
  const Status st = worker_->keyframeFeatures(req.session, req.keyframe, req.check_only, &a);
  const std::string frame = options_.frames.session_frame_prefix + std::to_string(req.session);
  if (st.ok() && !a.vehicle.empty()) {  // another vehicle's: asked of it, without the worker's lock
    res = peers_->request(a.vehicle, a.remote_session, req.session, req, frame);
    return true;
  }
  res.status = answer(st, "keyframe_features");
  if (st.ok() && !req.check_only) res.keyframe = rc::reloadedKeyframeMsg(a.session, a.keyframe, frame);
  return true;
}

std::vector<ros_diagnostics::Counter> BackendNodelet::counters(const core::SessionQueries& m) const {
  namespace rd = ros_diagnostics;
  rd::BackendCounters c;
  c.messages_received = received_ + (fleet_ ? fleet_->messages() : 0);
  rd::setWorkerCounters(worker_->stats(), worker_->handoverStats(), bad_keyframes_, bad_loops_, &c);
  rd::setFrameCounters(frames_->stats(), &c);
  c.sessions_unloaded = sessions_unloaded_, c.sessions_deleted = sessions_deleted_;
  rd::setRelocalisationCounters(sessions_->relocalisation(), &c);
  if (mosaic_) rd::setMosaicCounters(mosaic_->stats(), &c);
  rd::setManagerCounters(m, &c);
  if (fix_) fix_->counters(&c);
  std::vector<rd::Counter> out = rd::backendCounterTable().counters(c);
  if (fleet_)
    for (rd::Counter& k : rd::fleetCounters(fleet_->stats(), peers_->stats())) out.push_back(std::move(k));
  return out;
}

void BackendNodelet::fillDiagnostics(diagnostic_updater::DiagnosticStatusWrapper& stat) {
  worker_->locked([&](const core::SessionQueries& m) {
    ros_diagnostics::addBackendValues(stat, m, core::optimizerName(config_.backend.optimizer), options_.store_path,
                                      sessions_->relocalisation());
    diagnostic_status_.fill(stat, counters(m), ros::WallTime::now().toSec());
  });
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
