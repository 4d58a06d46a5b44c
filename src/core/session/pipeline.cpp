#include "uw_multislam/core/session/pipeline.h"

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "uw_multislam/core/frontend/image_file.h"
#include "uw_multislam/core/session/nav_session_placer.h"

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
      detector_(config.loops, config.odometry.matching, config.odometry.ransac, config.odometry.features.num_features) {
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
  stream_ = name;
  nav_frame_ = std::move(nav_frame);
  previous_piece_ = -1;
  stream_anchor_.reset();
  image_of_ = std::move(image_of);
  nav_ = config_.odometry.nav.enabled ? std::move(nav) : NavTrack();
  cameras_.push_back(camera.pinhole());  // the camera of the (undistorted) features keyframes carry
  stream_camera_ = camera;
  segmented_ = std::make_unique<SegmentedOdometry>(camera, config_.odometry, config_.tracking);
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

void Pipeline::startPiece(double stamp_s) {
  // Names are unique (start_session and reload_session address sessions by them): a folder run
  // again against the same store becomes "<folder> (2)", and so on.
  const std::string base = pieces_ == 0 ? sessionNameOfFolder(stream_) : stream_ + "#" + std::to_string(pieces_);
  ++pieces_;
  ScopedStage stage(&times_, "session_manager");
  const Status st = worker_->locked([&](SessionManager& m) {
    std::string name = base;
    for (int run = 2; m.view().idOfName(name) >= 0; ++run) name = base + " (" + std::to_string(run) + ")";
    return m.startSession(name, stamp_s, -1, &session_);
  });
  if (!st.ok()) throw std::invalid_argument(stream_ + ": " + st.message);
  worker_->optimiseDue();  // the session it ended may have left its map due
  stream_sessions_.back().push_back(session_);
  chain_ = SessionChain();
}

void Pipeline::endPiece(double stamp_s) {
  {
    ScopedStage stage(&times_, "session_manager");
    worker_->locked([&](SessionManager& m) { return m.endSession(stamp_s); });
    worker_->optimiseDue();
  }
  const Odometry& odometry = *segmented_->odometry();
  const OdometryStats& st = odometry.stats();
  char line[400];  // numbers only: the session's name (a folder path of any length) goes in as a string
  std::snprintf(line, sizeof line,
                "%d frames, %d keyframes, %d tracked, %d fallbacks, %d promotions, %d skipped "
                "(%d image, %d altitude), %d altitudes reused (%d above odometry.max_altitude_m), %.1f ms/frame",
                st.frames, st.keyframes, st.tracked, st.fallbacks, st.promotions,
                st.skipped_image + st.skipped_altitude, st.skipped_image, st.skipped_altitude, st.altitude_reused,
                st.altitude_out_of_range, odometry.times().get("odometry_total").meanMs());
  const std::string name = worker_->locked([&](const SessionQueries& m) { return m.name(session_); });
  say("session " + std::to_string(session_) + " (" + name + "): " + line);
  previous_piece_ = session_;
  if (nav_frame_) {
    if (const auto last = segmented_->lastNavKeyframe())
      stream_anchor_ = NavAnchor{session_, last->first, last->second, *nav_frame_};
  }
  if (st.gate_checks > 0 || st.nav_frames > 0 || st.nav_implausible > 0) {
    std::snprintf(line, sizeof line,
                  "session %d: nav prior: %d frames carried by the nav, %d visual motions checked, %d refused by the "
                  "gate, %d fused, %ld RANSAC hypotheses gated, %d nav steps too fast to be a motion (not used), %d "
                  "frames with neither a visual motion nor a usable nav reading past the bridged ones (the "
                  "session ended)",
                  session_, st.nav_frames, st.gate_checks, st.gate_refusals, st.fused, st.hypotheses_gated,
                  st.nav_implausible, st.nav_losses);
    say(line);
  }
  if (st.klt_tracked > 0 || st.klt_extracted > 0) {
    std::snprintf(line, sizeof line,
                  "session %d: KLT between keyframes: %d frames tracked without SIFT, %d extracted (%d of them "
                  "degraded tracks)",
                  session_, st.klt_tracked, st.klt_extracted, st.klt_degraded);
    say(line);
  }
  session_ = -1;
}

FramePreparer Pipeline::preparer() const {
  if (!segmented_) throw std::logic_error("Pipeline::preparer: no stream begun");
  return FramePreparer(stream_camera_, config_.odometry);
}

SegmentedOdometry::Step Pipeline::processFrame(const OdometryInput& input, PreparedFrame* prepared) {
  OdometryInput with_nav;
  NavRecord nav;
  if (!input.nav && !nav_.empty() && nav_.at(input.stamp_s, &nav)) {
    with_nav = input;  // shares the image
    with_nav.nav = nav;
  }
  const OdometryInput& frame = with_nav.nav ? with_nav : input;
  const SegmentedOdometry::Step step = segmented_->process(frame, prepared);
  const OdometryUpdate& u = step.update;
  ++stream_frames_;
  if (frame.image.empty()) ++stream_unreadable_;
  if (step.session_started) {
    startPiece(frame.stamp_s);
    if (pieces_ > 1)
      say("stream " + stream_ + ": tracking resumed at frame " + std::to_string(frame.index) + ": session " +
          std::to_string(session_) + " starts");
  }
  if (verbose_ && u.status == FrameStatus::kSkipped && !frame.image.empty())
    say("stream " + stream_ + " frame " + std::to_string(frame.index) + " skipped: " + u.reason);
  if (verbose_ && u.status == FrameStatus::kFallback)
    say("stream " + stream_ + " frame " + std::to_string(frame.index) + ": odometry fallback (" + u.reason + ")");
  if (verbose_ && !u.nav_note.empty())
    say("stream " + stream_ + " frame " + std::to_string(frame.index) + ": " + u.nav_note);
  if (verbose_ && u.source == MotionSource::kNav)
    say("stream " + stream_ + " frame " + std::to_string(frame.index) + ": nav motion (" + u.reason + ")");
  if (session_ < 0) return step;  // no session open: tracking lost
  const Odometry& odometry = *segmented_->odometry();
  for (const auto& kf : segmented_->newKeyframes()) {
    const KeyframeInfo& info = odometry.keyframes()[kf.id];
    KeyframeInput k;
    k.session = session_;
    k.keyframe = kf.id;
    k.frame_index = info.frame_index;
    k.stamp_s = info.stamp_s;
    k.altitude_m = info.altitude_m;
    k.camera = cameras_.back();
    k.features = kf.features;
    if (kf.id > 0) k.motion = odometry.trajectory().motion(kf.id);  // (10)(11)
    k.motion_source = info.source;
    k.odometry_pose = odometry.trajectory().absolutePose(kf.id);
    {
      ScopedStage stage(&times_, "hash");
      k.hash = worker_->hasher().hash(kf.features.descriptors);  // once: the detector and the store share it
    }
    chain_.append(kf.id, k.motion, k.odometry_pose);
    const auto [session_poses, store] = worker_->locked(
        [&](const SessionQueries& m) { return std::make_pair(m.posesInSessionFrame(session_), m.hasStore()); });
    std::vector<Loop> loops =
        detector_.addKeyframe(session_, kf.id, info.frame_index, info.altitude_m, &cameras_.back(), kf.features,
                              chain_.candidateTrajectory(session_poses), &k.hash);
    if (detector_.stats().feature_read_failures > read_failures_) {
      read_failures_ = detector_.stats().feature_read_failures;
      say("stream " + stream_ + " keyframe " + std::to_string(kf.id) + ": a stored loop candidate skipped (" +
          std::to_string(read_failures_) + " so far): " + detector_.lastReadError());
    }
    if (store && image_of_)
      k.thumbnail = encodeKeyframeImage(info.frame_index == frame.index ? frame.image : image_of_(info.frame_index),
                                        config_.store_image);
    if (step.session_started && kf.id == 0) k.nav_placement = placementOf(step);
    ScopedStage stage(&times_, "session_manager");
    Status st;
    worker_->addKeyframe(std::move(k), std::move(loops),
                         [&st](const SessionQueries&, const KeyframeInput&, const Status& s) { st = s; });
    if (!st.ok()) throw std::logic_error("session manager refused an in-process keyframe: " + st.message);
  }
  if (step.session_closed) {
    say("stream " + stream_ + ": tracking lost at frame " + std::to_string(frame.index) + " (" +
        std::to_string(config_.tracking.max_fallbacks) + " unmatched frames): session " + std::to_string(session_) +
        " closed");
    endPiece(frame.stamp_s);
  }
  return step;
}

namespace {
// Two nav_frame.yaml declare one world frame when they name it alike: the convention is only how
// nav.csv's rows are written (both are read into the same ENU frame), and an origin given in one
// file but not the other is the same frame; two different origins under one name are not.
bool sameWorldFrame(const NavFrame& a, const NavFrame& b) {
  return a.name == b.name &&
         (!a.has_origin || !b.has_origin || (a.latitude_deg == b.latitude_deg && a.longitude_deg == b.longitude_deg));
}
}  // namespace

std::optional<NavPlacementInput> Pipeline::placementOf(const SegmentedOdometry::Step& step) const {
  const NavPriorOptions& o = config_.odometry.nav;
  if (!o.enabled || !o.place_pieces) return std::nullopt;
  NavPlacementInput p;
  std::string what;
  if (step.placement && previous_piece_ >= 0) {
    p.session = previous_piece_;  // the piece the tracking loss ended, one dead reckoning
    p.keyframe = step.placement->keyframe;
    p.z = step.placement->z;
    what = "after the tracking loss";
  } else if (pieces_ == 1 && nav_anchor_ && nav_frame_ && sameWorldFrame(nav_anchor_->frame, *nav_frame_)) {
    const std::optional<NavRecord>& here = segmented_->odometry()->keyframes().front().nav;
    if (!here) return std::nullopt;
    p = placeAgainst({nav_anchor_->session, nav_anchor_->keyframe, nav_anchor_->nav}, *here, o);
    what = "in the nav's world frame " + nav_frame_->name;
  } else {
    return std::nullopt;
  }
  say("stream " + stream_ + ": session " + std::to_string(session_) + " placed by the nav " + what + " " +
      describePlacement(p));
  return p;
}

void Pipeline::endStream(double stamp_s) {
  if (session_ >= 0) endPiece(stamp_s);
  if (stream_anchor_) nav_anchor_ = stream_anchor_;
  stream_anchor_.reset();
  if (pieces_ == 0 && segmented_) {
    // Not one session: every frame unusable (unreadable images, no altitude, another size, no
    // features). Said once, with the counts, instead of the session lines that never come.
    say("stream " + stream_ + ": no session started: " + std::to_string(stream_frames_) + " frames, " +
        std::to_string(stream_unreadable_) +
        " of them without an image (unreadable), the others unusable or with too few features to start one");
  }
  if (segmented_) finished_.merge(segmented_->times());
  segmented_.reset();
}

void Pipeline::finish() {
  ScopedStage stage(&times_, "session_manager");
  worker_->locked([](SessionManager& m) { m.flush(); });
}

StageTimes Pipeline::times() const {
  StageTimes t = finished_;
  if (segmented_) t.merge(segmented_->times());
  t.merge(detector_.times());
  t.merge(times_);
  return t;
}

}  // namespace core
}  // namespace uw_multislam
