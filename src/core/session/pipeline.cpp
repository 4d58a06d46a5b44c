#include "uw_multislam/core/session/pipeline.h"

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "uw_multislam/core/frontend/image_file.h"

namespace uw_multislam {
namespace core {

Pipeline::Pipeline(const SlamConfig& config, SessionWorker* worker, Log log, bool verbose)
    : Pipeline(config, worker, nullptr, std::move(log), verbose) {}

Pipeline::Pipeline(const SlamConfig& config, SessionManager* manager, Log log, bool verbose)
    : Pipeline(config, nullptr, std::make_unique<SessionWorker>(manager, SessionWorkerOptions()), std::move(log),
               verbose) {}

Pipeline::Pipeline(const SlamConfig& config, SessionWorker* worker, std::unique_ptr<SessionWorker> own, Log log,
                   bool verbose)
    : config_(config),
      own_worker_(std::move(own)),
      worker_(worker ? worker : own_worker_.get()),
      log_(std::move(log)),
      verbose_(verbose),
      detector_(config.loops, config.odometry.matching, config.odometry.ransac, config.odometry.features.num_features),
      // Offline the stamps are the dataset's: the live odometry's default stamp rules.
      frames_(
          config, StampGuardOptions(),
          {[this](const SessionOpening& o) { return startPiece(o); }, [this](const SessionClosing& c) { endPiece(c); }},
          0, &worker_->hasher()) {
  ScopedStage stage(&times_, "store_load");
  worker_->locked([this](SessionManager& m) { return loadStoredSessions(&m, &detector_, &cameras_); });
  // The detector reads a stored candidate's features through the worker (under its lock).
  detector_.setFeatureLoader([w = worker_](int session, int keyframe) {
    return w->locked([&](const SessionQueries& m) { return m.storedFeatures(session, keyframe).features(); });
  });
}

int loadStoredSessions(SessionManager* manager, LoopDetector* detector, std::deque<CameraIntrinsics>* cameras) {
  int keyframes = 0;
  detector->setFeatureLoader(
      [manager](int session, int keyframe) { return manager->view().storedFeatures(session, keyframe).features(); });
  for (const SessionSummary& s : manager->view().list()) {
    if (s.state != SessionState::kUnloaded) continue;
    ReloadedSession r;
    const Status st = manager->reload(std::to_string(s.id), &r, SessionManager::ReloadRead::kHashes);
    if (!st.ok()) throw StoreError(st.message);
    cameras->push_back(r.camera);
    for (const StoredKeyframe& k : r.keyframes)
      detector->addPagedKeyframe(r.id, k.keyframe, k.frame_index, k.altitude_m, &cameras->back(), k.hash);
    keyframes += static_cast<int>(r.keyframes.size());
  }
  return keyframes;
}

void Pipeline::say(const std::string& line) const {
  if (log_) log_(line);
}

void Pipeline::beginStream(const std::string& name, const CameraIntrinsics& camera, ImageOf image_of, NavTrack nav,
                           std::optional<NavFrame> nav_frame) {
  if (streaming_) endStream(0.0);
  stream_ = name;
  image_of_ = std::move(image_of);
  nav_ = config_.odometry.nav.enabled ? std::move(nav) : NavTrack();
  cameras_.push_back(camera.pinhole());  // the camera of the (undistorted) features keyframes carry
  stream_camera_ = camera;
  frames_.beginStream(std::move(nav_frame));
  streaming_ = true;
  pieces_ = 0;
  stream_frames_ = stream_unreadable_ = 0;
  session_ = -1;
  stream_sessions_.emplace_back();
}

void Pipeline::beginStream(const Dataset& d) {
  beginStream(
      d.directory, d.camera,
      [&d](int index) {
        for (const FrameRecord& f : d.frames)
          if (f.index == index) return readFrameImageBgr(d.imagePath(f));
        return cv::Mat();
      },
      NavTrack(d.nav), d.nav_frame);
}

int Pipeline::startPiece(const SessionOpening& o) {
  // Names are unique (start_session and reload_session address sessions by them): a folder run
  // again against the same store becomes "<folder> (2)", and so on.
  const std::string base = o.piece == 0 ? sessionNameOfFolder(stream_) : stream_ + "#" + std::to_string(o.piece);
  ++pieces_;
  ScopedStage stage(&times_, "session_manager");
  const Status st = worker_->locked([&](SessionManager& m) {
    std::string name = base;
    for (int run = 2; m.view().idOfName(name) >= 0; ++run) name = base + " (" + std::to_string(run) + ")";
    return m.startSession(name, o.stamp_s, -1, &session_);
  });
  if (!st.ok()) throw std::invalid_argument(stream_ + ": " + st.message);
  worker_->optimiseDue();  // the session it ended may have left its map due
  stream_sessions_.back().push_back(session_);
  chain_ = SessionChain();
  if (o.cause != SessionCause::kFirstFrame)
    say("stream " + stream_ + ": " + o.why + ": session " + std::to_string(session_) + " starts");
  return session_;
}

void Pipeline::endPiece(const SessionClosing& c) {
  {
    ScopedStage stage(&times_, "session_manager");
    worker_->locked([&](SessionManager& m) { return m.endSession(c.stamp_s); });
    worker_->optimiseDue();
  }
  if (!c.odometry) return;
  const Odometry& odometry = *c.odometry;
  const OdometryStats& st = odometry.stats();
  char line[400];  // numbers only: the session's name (a folder path of any length) goes in as a string
  std::snprintf(line, sizeof line,
                "%d frames, %d keyframes, %d tracked, %d fallbacks, %d promotions, %d dense registrations tried "
                "(%d accepted), %d restarts, %d skipped (%d image, %d altitude), %d altitudes reused (%d above "
                "odometry.max_altitude_m), %.1f ms/frame",
                st.frames, st.keyframes, st.tracked, st.fallbacks, st.promotions, st.dense_tries, st.dense_matches,
                st.restarts, st.skipped_image + st.skipped_altitude, st.skipped_image, st.skipped_altitude,
                st.altitude_reused, st.altitude_out_of_range, odometry.times().get("odometry_total").meanMs());
  const std::string name = worker_->locked([&](const SessionQueries& m) { return m.name(c.session); });
  say("session " + std::to_string(c.session) + " (" + name + "): " + line);
  if (st.gate_checks > 0 || st.nav_frames > 0 || st.nav_implausible > 0) {
    std::snprintf(line, sizeof line,
                  "session %d: nav prior: %d frames carried by the nav, %d visual motions checked, %d refused by the "
                  "gate, %d fused, %ld RANSAC hypotheses gated, %d nav steps too fast to be a motion (not used), %d "
                  "frames with neither a visual motion nor a usable nav reading past the bridged ones (the "
                  "session ended)",
                  c.session, st.nav_frames, st.gate_checks, st.gate_refusals, st.fused, st.hypotheses_gated,
                  st.nav_implausible, st.nav_losses);
    say(line);
  }
  if (st.klt_tracked > 0 || st.klt_extracted > 0) {
    std::snprintf(line, sizeof line,
                  "session %d: KLT between keyframes: %d frames tracked without SIFT, %d extracted (%d of them "
                  "degraded tracks)",
                  c.session, st.klt_tracked, st.klt_extracted, st.klt_degraded);
    say(line);
  }
  session_ = -1;
}

FramePreparer Pipeline::preparer() const {
  if (!streaming_) throw std::logic_error("Pipeline::preparer: no stream begun");
  return FramePreparer(stream_camera_, config_.odometry);
}

FrameResult Pipeline::processFrame(const OdometryInput& input, PreparedFrame* prepared) {
  if (!streaming_) throw std::logic_error("Pipeline::processFrame: no stream begun");
  FrameInput in;
  in.image = input.image;  // shared
  in.camera = stream_camera_;
  in.altitude_m = input.altitude_m;
  in.stamp_s = input.stamp_s;
  in.index = input.index;
  in.prepared = prepared;
  in.keyframe_lookahead_s = input.keyframe_lookahead_s;
  if (input.nav) {
    in.nav = [&input](bool) { return input.nav; };
  } else if (!nav_.empty()) {
    in.nav = [this, stamp = input.stamp_s](bool) -> std::optional<NavRecord> {
      NavRecord r;
      if (!nav_.at(stamp, &r)) return std::nullopt;
      return r;
    };
  }
  FrameResult r = frames_.process(std::move(in));
  const OdometryUpdate& u = r.update;
  ++stream_frames_;
  if (input.image.empty()) ++stream_unreadable_;
  const std::string frame = "stream " + stream_ + " frame " + std::to_string(input.index);
  if (r.skipped_stamp)
    say(frame + " skipped: its stamp " + std::to_string(input.stamp_s) + " is " + stampClassName(r.timing));
  for (const std::string& line : r.warnings) say("stream " + stream_ + ": " + line);
  for (const std::string& line : r.notes) say("stream " + stream_ + ": " + line);
  if (verbose_ && u.status == FrameStatus::kSkipped && !input.image.empty() && !r.skipped_stamp)
    say(frame + " skipped: " + u.reason);
  if (verbose_ && u.status == FrameStatus::kFallback) say(frame + ": odometry fallback (" + u.reason + ")");
  if (verbose_ && !u.nav_note.empty()) say(frame + ": " + u.nav_note);
  if (verbose_ && u.source == MotionSource::kNav) say(frame + ": nav motion (" + u.reason + ")");
  for (StreamKeyframe& k : r.keyframes) addKeyframe(std::move(k), input);
  for (const FrameResult::Ended& e : r.ended)
    if (e.cause == SessionEnd::kTrackingLoss)
      say("stream " + stream_ + ": tracking lost at frame " + std::to_string(input.index) + " (" + e.why +
          "): session " + std::to_string(e.session) + " closed");
  return r;
}

void Pipeline::addKeyframe(StreamKeyframe s, const OdometryInput& frame) {
  KeyframeInput& k = s.input;
  k.camera = cameras_.back();
  chain_.append(k.keyframe, k.motion, k.odometry_pose);
  const auto [session_poses, store] = worker_->locked(
      [&](const SessionQueries& m) { return std::make_pair(m.posesInSessionFrame(k.session), m.hasStore()); });
  std::vector<Loop> loops = detector_.addKeyframe(k.session, k.keyframe, k.frame_index, k.altitude_m, &cameras_.back(),
                                                  k.features, chain_.candidateTrajectory(session_poses), &k.hash);
  if (detector_.stats().feature_read_failures > read_failures_) {
    read_failures_ = detector_.stats().feature_read_failures;
    say("stream " + stream_ + " keyframe " + std::to_string(k.keyframe) + ": a stored loop candidate skipped (" +
        std::to_string(read_failures_) + " so far): " + detector_.lastReadError());
  }
  if (store && image_of_)
    k.thumbnail =
        encodeKeyframeImage(k.frame_index == frame.index ? frame.image : image_of_(k.frame_index), config_.store_image);
  ScopedStage stage(&times_, "session_manager");
  Status st;
  worker_->addKeyframe(std::move(k), std::move(loops),
                       [&st](const SessionQueries&, const KeyframeInput&, const Status& s) { st = s; });
  if (!st.ok()) throw std::logic_error("session manager refused an in-process keyframe: " + st.message);
}

void Pipeline::endStream(double stamp_s) {
  if (!streaming_) return;
  frames_.endStream(stamp_s);
  streaming_ = false;
  const FrameStreamCounts& n = frames_.counts();
  if (n.tracking_losses > 0)
    say("stream " + stream_ + " so far: " + std::to_string(n.tracking_losses) + " tracking losses (" +
        std::to_string(n.restarts) + " of them restarts at an unmatched frame), " + std::to_string(n.bridges) +
        " pieces joined to the one before by a visual bridge (" + std::to_string(n.rejoin_tries) +
        " keyframes tried), " + std::to_string(n.placements) + " placed by the nav");
  if (pieces_ == 0) {
    // Not one session: every frame unusable (unreadable images, no altitude, another size, no
    // features). Said once, with the counts, instead of the session lines that never come.
    say("stream " + stream_ + ": no session started: " + std::to_string(stream_frames_) + " frames, " +
        std::to_string(stream_unreadable_) +
        " of them without an image (unreadable), the others unusable or with too few features to start one");
  }
}

void Pipeline::finish() {
  ScopedStage stage(&times_, "session_manager");
  worker_->locked([](SessionManager& m) { m.flush(); });
}

StageTimes Pipeline::times() const {
  StageTimes t = frames_.times();
  t.merge(detector_.times());
  t.merge(times_);
  return t;
}

}  // namespace core
}  // namespace uw_multislam
