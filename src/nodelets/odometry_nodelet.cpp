// uw_multislam/Odometry: wiring, conversions and the worker's loop (doc/ros_api.md).
#include "uw_multislam/ros/nodelets/odometry_nodelet.h"

#include <geometry_msgs/PoseWithCovarianceStamped.h>
#include <pluginlib/class_list_macros.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>

#include "uw_multislam/core/geometry/vehicle_frame.h"
#include "uw_multislam/core/session/session_manager.h"
#include "uw_multislam/ros/conversions.h"
#include "uw_multislam/ros/odometry_reports.h"
#include "uw_multislam/ros/topics.h"

namespace uw_multislam {
namespace nodelets {

namespace rc = ros_conversions;
using ros_diagnostics::OdometryCounters;

OdometryNodelet::~OdometryNodelet() {
  watchdog_.stop();
  pairing_timer_.stop();
  if (images_) images_->shutdown();
  info_sub_.shutdown();
  range_sub_.shutdown();
  if (queue_) queue_->close();  // later frames are refused; the queued ones are still processed
  if (worker_.joinable()) worker_.join();
  prepare_on_arrival_.reset();  // its threads stopped while the members they read (control_) are alive
  if (stream_) logStats("at shutdown");
}

void OdometryNodelet::onInit() {
  ros::NodeHandle& nh = getNodeHandle();
  try {
    options_ = ros_params::odometryNodeletOptions(nh, getPrivateNodeHandle());
    it_ = std::make_unique<image_transport::ImageTransport>(nh);
    images_ = std::make_unique<ros_inputs::ImageInput>(nh, getPrivateNodeHandle(), it_.get(), topics::kImage);
  } catch (const std::exception& e) {
    NODELET_FATAL("odometry: invalid parameters, not starting: %s", e.what());
    throw;
  }
  const auto& o = options_;
  const core::SlamConfig& config = o.config;
  for (const std::string& line : ros_params::describe(o)) NODELET_INFO("odometry: %s", line.c_str());
  NODELET_INFO("odometry: %s", images_->description().c_str());
  NODELET_DEBUG_STREAM("odometry: effective SLAM configuration:\n" << core::slamConfigToYaml(config));
  queue_ = std::make_unique<core::BoundedWorkQueue<Frame>>(o.workerQueueSize(), ros_inputs::handOnDropped);
  // With newest the worker takes the newest frame when it frees up: its features are started on arrival (on another
  // core). A frame superseded before a thread was free is never prepared (core::OrderedPrefetch::Start::kNewest).
  if (o.prepare_threads > 0 && o.drop_policy == "newest")
    prepare_on_arrival_ = std::make_unique<core::OrderedPrefetch<Ahead, Frame>>(
        o.prepare_threads,
        [this](Frame f, int) { return control_.paused() ? Ahead() : prepareAhead(f); },  // paused: dropped anyway
        core::OrderedPrefetch<Ahead, Frame>::Start::kNewest);
  // Live there is one stream; the odometry numbers its sessions (core::FrameStream), and a session's end says its
  // numbers.
  stream_ = std::make_unique<core::FrameStream>(
      config, o.stamps(),
      core::SessionHooks{{},
                         [this](const core::SessionClosing& c) {
                           logStats("at the end of session " + std::to_string(c.session), c.odometry);
                         }},
      o.session);
  stream_->beginStream(o.nav_world_fixed ? std::make_optional(core::NavFrame{o.odom_frame}) : std::nullopt);
  pairing_ = std::make_unique<Pairing>(
      o.pairing(), steadyNow(), o.fallback_camera_info ? std::make_optional(o.fallback_camera_info) : std::nullopt);
  sensor_mount_ =
      std::make_unique<ros_frames::SensorMount>(nh, o.base_frame, o.mount_wait_s, o.max_camera_tilt_deg * M_PI / 180.0);
  nav_ = std::make_unique<ros_inputs::NavInput>(nh, topics::kNavOdometry, o.nav());
  if (o.nav_source != "none") NODELET_INFO("odometry: %s", nav_->description(config.odometry.nav.enabled).c_str());

  keyframes_ = std::make_unique<ros_outputs::KeyframePublisher>(nh, it_.get(), config);
  status_ = std::make_unique<ros_status::OdometryStatusPublisher>(nh, o.input_timeout_s);
  pose_pub_ = nh.advertise<geometry_msgs::PoseWithCovarianceStamped>(topics::kOdometryPose, 10);
  updater_ = std::make_unique<diagnostic_updater::Updater>(nh, getPrivateNodeHandle(), getName());
  updater_->setHardwareID("none");
  updater_->add("odometry", this, &OdometryNodelet::fillDiagnostics);
  watchdog_ = nh.createWallTimer(ros::WallDuration(o.diagnostic_period_s), [this](const ros::WallTimerEvent&) {
    const std::string silent = silentInput(steadyNow());
    if (!silent.empty()) NODELET_WARN_THROTTLE(10, "odometry: %s", silent.c_str());
    updater_->force_update();
  });
  worker_ = std::thread([this] { work(); });
  // Images waiting past their bound are decided by this timer when no message comes.
  pairing_timer_ = nh.createWallTimer(ros::WallDuration(std::min(0.1, o.altitude_max_age_s / 4)),
                                      [this](const ros::WallTimerEvent&) {
                                        std::lock_guard<std::mutex> lock(pairing_mutex_);
                                        handle(pairing_->update(steadyNow()));
                                      });
  session_sub_ = nh.subscribe(topics::kActiveSession, 1, &OdometryNodelet::onActiveSession, this);
  using Op = uw_multislam::OperatorCommand;
  services_.push_back(nh.advertiseService<Op::Request, Op::Response>(
      topics::kPauseService, [this](Op::Request&, Op::Response& res) { return setPaused(true, &res); }));
  services_.push_back(nh.advertiseService<Op::Request, Op::Response>(
      topics::kResumeService, [this](Op::Request&, Op::Response& res) { return setPaused(false, &res); }));
  images_->subscribe(o.inputQueueSize(), [this](ros_inputs::ImageMsg m) {
    std::lock_guard<std::mutex> lock(pairing_mutex_);
    const double stamp = m.header().stamp.toSec();
    handle(pairing_->addImage(std::move(m), stamp, steadyNow()));
  });
  info_sub_ = nh.subscribe(topics::kCameraInfo, o.inputQueueSize(), &OdometryNodelet::onCameraInfo, this);
  if (o.use_altitude_topic)
    range_sub_ = nh.subscribe(topics::kAltitude, o.inputQueueSize(), &OdometryNodelet::onRange, this);
}

void OdometryNodelet::onCameraInfo(const sensor_msgs::CameraInfoConstPtr& info) {
  std::lock_guard<std::mutex> lock(pairing_mutex_);
  handle(pairing_->addCameraInfo(info, info->header.stamp.toSec(), steadyNow()));
}

void OdometryNodelet::onRange(const sensor_msgs::RangeConstPtr& range) {
  bool above_max = false;
  std::string why;
  const double altitude = rc::altitudeReading(*range, options_.config.odometry.max_altitude_m, &above_max, &why);
  if (std::isnan(altitude)) {
    ++ranges_refused_;
    ranges_above_max_ += above_max;
    NODELET_WARN_THROTTLE(
        5, "odometry: %s: images at this reading's stamp get no altitude (the last valid one is used)", why.c_str());
  }
  std::lock_guard<std::mutex> lock(pairing_mutex_);
  altimeter_frame_ = range->header.frame_id;
  const double last = pairing_->newestAltitude();
  bool cleared = false;
  handle(pairing_->addAltitude(range->header.stamp.toSec(), altitude, steadyNow(), &cleared));
  if (cleared)
    NODELET_WARN(
        "odometry: altitude stamps jumped back by %.3f s (a bag that loops, or a clock reset): earlier "
        "readings dropped",
        last - range->header.stamp.toSec());
}

void OdometryNodelet::handle(Pairing::Decisions decisions) {
  using K = Pairing::Decision::Kind;
  for (Pairing::Decision& d : decisions) {
    if (d.kind != K::kPaired) {
      const bool no_info = d.kind == K::kNoCameraInfo;
      ros_diagnostics::reportUnpaired(
          no_info, d.stamp_s, no_info ? options_.sync_max_interval_s : options_.altitude_max_age_s, pairing_->counts());
    } else {
      if (d.first_fallback)
        NODELET_WARN("odometry: no camera_info on %s: images use the calibration of ~camera_info_url %s",
                     info_sub_.getTopic().c_str(), options_.camera_info_url.c_str());
      const double now = steadyNow();
      budget_.arrived(now, d.image.header().stamp.toSec());
      Frame frame{std::move(d.image), std::move(d.info), d.altitude, d.altitude_m, altimeter_frame_, {}, 0, now};
      frame.passed_over = std::move(d.passed_over);
      if (prepare_on_arrival_) frame.arrival = prepare_on_arrival_->submit(frame);  // in the queue's order
      queue_->push(std::move(frame));
    }
  }
}

bool OdometryNodelet::setPaused(bool paused, uw_multislam::OperatorCommand::Response* res) {
  if (control_.setPaused(paused)) {
    res->status.code = uw_multislam::Status::OK;
    NODELET_INFO("odometry: %s (%ld frames dropped while paused so far)",
                 paused ? "paused by the operator: frames are dropped until resume" : "resumed",
                 control_.droppedWhilePaused());
  } else {
    res->status.code = uw_multislam::Status::FAILED_PRECONDITION;
    res->status.message = paused ? "the odometry is already paused (call resume)" : "the odometry is not paused";
  }
  res->paused = control_.paused();
  res->frames_dropped_paused = control_.droppedWhilePaused();
  return true;
}

void OdometryNodelet::onActiveSession(const uw_multislam::SessionStateConstPtr& msg) {
  if (msg->session < 0 || msg->session > core::kMaxSessionId) {
    NODELET_WARN_THROTTLE(10, "odometry: ignoring active_session with id %d, outside [0, %d]", msg->session,
                          core::kMaxSessionId);
    return;
  }
  const auto effect = control_.request(msg->session, msg->next_session, msg->next_session_only,
                                       msg->state == uw_multislam::SessionState::FINISHED);
  if (effect == core::StreamControl::Effect::kPausedByFinish)
    NODELET_INFO(
        "odometry: the session was finished: frames are dropped until start_session or resume (then "
        "session %d starts)",
        msg->session);
  if (effect == core::StreamControl::Effect::kResumedAfterFinish)
    NODELET_INFO("odometry: session %d requested after finish_session: frames are processed again", msg->session);
}

void OdometryNodelet::work() {
  last_stats_ = ros::WallTime::now();
  if (options_.drop_policy == "oldest") {
    // ~prepare_threads: frames already waiting are prepared on long-lived threads while this one
    // processes the frame before them (a thread per frame was slower than none: bench_load.sh).
    core::drainWithPrepareAhead<Frame, Ahead>(
        *queue_, options_.prepare_threads, [this](const Frame& f) { return prepareAhead(f); },
        [this](Frame& f, Ahead* ahead) { run(f, ahead); });
    return;
  }
  // The skip rule chooses, or waits for the next frame (the worker's state: popSelected runs on this thread).
  ros_inputs::NewestChooser choose(options_.stale_fraction, &budget_, &counts_);
  core::drainNewest<Frame, Ahead>(
      *queue_, queue_->capacity(), prepare_on_arrival_.get(),
      [this, &choose](const std::deque<Frame>& w, const std::vector<bool>& started) {
        return choose(stream_->skipRule(), w, mount_, started);
      },
      ros_inputs::handOnSkipped, [](const Frame& f) { return f.arrival; },
      [this](Frame& f, Ahead* ahead, Clock::time_point start) { run(f, ahead, start); },
      [this](const std::string& e) {  // a numbering error: the frame is prepared here rather than stop
        NODELET_ERROR_THROTTLE(5, "odometry: frame prepared on arrival not found: %s", e.c_str());
      });
}

void OdometryNodelet::run(Frame& f, Ahead* ahead, Clock::time_point start) {
  try {
    process(f, ahead);
  } catch (const std::exception& e) {  // the core throws only on programming errors: log, keep going
    NODELET_ERROR_THROTTLE(5, "odometry: frame skipped, %s", e.what());
  }
  const double ms = std::chrono::duration<double, std::milli>(Clock::now() - start).count();
  counts_.frameTime(ms);
  counts_.session = stream_->lastSession();
  budget_.processed(ms);
  {
    std::lock_guard<std::mutex> lock(stats_mutex_);
    published_ = counts_;
  }
  status_->frame(snapshot(counts_));
  if ((ros::WallTime::now() - last_stats_).toSec() >= options_.stats_period_s) {
    logStats("so far");
    last_stats_ = ros::WallTime::now();
  }
}

OdometryNodelet::Refusal OdometryNodelet::convert(const Frame& f, core::CameraIntrinsics* camera, cv::Mat* image,
                                                  std::string* why) const {
  if (!rc::cameraFromMsg(*f.info, options_.rectified_images, camera, why))
    return &OdometryCounters::skipped_camera_info;
  rc::ImageRefusal refusal = rc::ImageRefusal::kNone;
  const std::uint64_t max_pixels = static_cast<std::uint64_t>(options_.max_image_pixels);
  if (ros_inputs::imageFromInput(f.msg, *camera, max_pixels, image, why, &refusal)) return nullptr;
  return ros_diagnostics::imageRefusalCounter(refusal);
}

OdometryNodelet::Ahead OdometryNodelet::prepareAhead(const Frame& f) const {
  Ahead a;
  try {
    cv::Mat image;
    std::string why;
    if (!convert(f, &a.camera, &image, &why))
      a.prepared = core::FramePreparer(a.camera, options_.config.odometry).prepare(image);
  } catch (const std::exception&) {
    a.prepared = core::PreparedFrame();  // process() converts the frame again and reports what is wrong
  }
  return a;
}

void OdometryNodelet::process(const Frame& f, Ahead* ahead) {
  ++counts_.frames_finished;
  stream_->passOver(f.passed_over);  // received but not processed: seen, not a gap
  const ros::Time stamp = f.msg.header().stamp;
  if (control_.paused()) {  // dropped and counted; its stamp seen like a queue drop's (the pause is no time gap)
    stream_->passOver({stamp.toSec()});
    counts_.frames_dropped_paused = control_.countDropped();
    return;
  }
  core::FrameInput in;
  std::string why;
  if (const Refusal refusal = convert(f, &in.camera, &in.image, &why))
    return ros_diagnostics::reportRefusal(refusal, why, &counts_);
  if (!resolveMount(f)) return stream_->passOver({stamp.toSec()});  // no tracking without it; its stamp is seen
  const cv::Mat image = in.image;
  in.stamp_s = stamp.toSec();
  // The altimeter's range -> the camera's altitude; a fixed or fallback altitude is the camera's already.
  in.altitude_m =
      f.altitude == core::PairedAltitude::kReading ? core::cameraAltitude(f.altitude_m, mount_) : f.altitude_m;
  in.nav = [&](bool clock_jumped_back) { return nav_->at(stamp, mount_, clock_jumped_back); };
  in.requested = control_.take();
  // Prepared ahead with this frame's camera (a new camera starts a session with it).
  in.prepared = ahead && ahead->prepared.done && ahead->camera == in.camera ? &ahead->prepared : nullptr;
  counts_.prepared_ahead += in.prepared != nullptr;
  // Newest only, with a prediction (the stream uses it only then; without, frames are taken in order: none waits).
  in.keyframe_lookahead_s = options_.keyframe_lookahead ? core::keyframeLookaheadS(budget_.timing(steadyNow())) : 0.0;
  const core::FrameResult r = stream_->process(std::move(in));
  ros_diagnostics::reportFrame(r, *stream_, options_.config.tracking, &counts_);
  if (!r.skipped_stamp)
    ros_diagnostics::reportAltitude(f.altitude, f.altitude_m, stamp.toSec(), range_sub_.getTopic(),
                                    options_.input_timeout_s, &counts_);
  if (!r.moved) return;
  // base_link in the z-up session frame, with the covariance of the motions since its first frame.
  // Before the keyframe's message (thumbnail): the pose's latency is the frame's, not the keyframe's.
  pose_pub_.publish(rc::toPoseWithCovarianceStampedMsg(
      core::vehicleFromCamera(core::UncertainPose2(r.update.pose, r.update.covariance), mount_),
      options_.session_frame_prefix + std::to_string(r.session), stamp));
  counts_.keyframes += keyframes_->publish(r.keyframes, r.update.index, image, f.msg.header());
}

bool OdometryNodelet::resolveMount(const Frame& f) {
  // The sensors' mount from tf (no default mount), looked up again now and then: a mount that moves is said.
  const ros_frames::SensorMount::Lookup mount = sensor_mount_->get(f.msg.header().frame_id, f.altimeter_frame);
  {
    std::lock_guard<std::mutex> lock(stats_mutex_);  // why frames are refused, while they are
    if (mount.state != ros_frames::SensorMount::State::kResolved) mount_error_ = mount.message;
    if (mount.fresh) mount_error_.clear();
  }
  if (!ros_diagnostics::reportMount(mount, &counts_)) return false;
  mount_ = mount.mount;
  return true;
}

std::string OdometryNodelet::silentInput(double now) {
  core::InputSilence silence;
  {
    std::lock_guard<std::mutex> lock(pairing_mutex_);
    silence = pairing_->silence(now);
  }
  return ros_params::silenceMessage(
      silence, options_, {images_->topic(), images_->transport(), info_sub_.getTopic(), range_sub_.getTopic()});
}

OdometryCounters OdometryNodelet::snapshot(OdometryCounters c) {
  {
    std::lock_guard<std::mutex> lock(pairing_mutex_);
    ros_diagnostics::setPairingCounters(pairing_->counts(), pairing_->waiting(), &c);
  }
  c.altitudes_refused = ranges_refused_, c.altitudes_above_max_altitude = ranges_above_max_;
  c.dropped_queue_full = queue_->dropped(), c.queue_length = static_cast<long>(queue_->size());
  c.skipped_for_newest = queue_->skipped();
  c.ms_per_frame_recent = budget_.msPerFrame(), c.input_period_ms = budget_.inputPeriodMs();
  c.frames_synchronised = queue_->pushed(), c.frames_processed = queue_->popped();
  // Images not paired: skipped for want of a camera_info or an altitude, or still waiting.
  c.images_not_paired = std::max(0L, c.images_received - c.frames_synchronised);
  c.paused = control_.paused() ? 1 : 0;
  c.nav_received = nav_->received(), c.nav_refused = nav_->refused(), c.nav_tf_missing = nav_->tfMissing();
  c.nav_covariance_replaced = nav_->covarianceReplaced();
  c.ms_per_frame_mean = c.frames_finished > 0 ? c.total_ms / static_cast<double>(c.frames_finished) : 0.0;
  return c;
}

void OdometryNodelet::fillDiagnostics(diagnostic_updater::DiagnosticStatusWrapper& stat) {
  OdometryCounters c;
  std::string error;
  {
    std::lock_guard<std::mutex> lock(stats_mutex_);
    c = published_;
    error = mount_error_;
  }
  c = snapshot(c);
  std::string problem = silentInput(steadyNow());
  if (problem.empty()) {
    const bool arriving = budget_.arriving(steadyNow(), options_.input_timeout_s);
    problem = ros_diagnostics::budgetProblem(c, options_.drop_policy, arriving);
  }
  diagnostic_status_.fill(stat, ros_diagnostics::odometryCounterTable().counters(c), steadyNow(), problem,
                          error.empty() ? "" : "tracking does not start: " + error);
}

void OdometryNodelet::logStats(const std::string& when, const core::Odometry* odo) {  // the worker's, or joined
  if (!odo && stream_->odometry()) odo = stream_->odometry()->odometry();
  const core::OdometryStats s = odo ? odo->stats() : core::OdometryStats();
  const double ms = odo ? odo->times().get("odometry_total").meanMs() : 0.0;
  const std::string counters = ros_diagnostics::countersLine(
      "odometry counters " + when + ":", ros_diagnostics::odometryCounterTable().counters(snapshot(counts_)));
  NODELET_INFO("%s; session %d: %d frames, %d keyframes, %d altitudes reused, %.1f ms/frame", counters.c_str(),
               stream_->lastSession(), s.frames, s.keyframes, s.altitude_reused, ms);
}

}  // namespace nodelets
}  // namespace uw_multislam

PLUGINLIB_EXPORT_CLASS(uw_multislam::nodelets::OdometryNodelet, nodelet::Nodelet)
