#include "uw_multislam/core/session/frame_stream.h"

#include <algorithm>
#include <cstdio>
#include <stdexcept>

namespace uw_multislam {
namespace core {

const char* sessionCauseName(SessionCause c) {
  switch (c) {
    case SessionCause::kFirstFrame:
      return "first frame";
    case SessionCause::kRequested:
      return "requested";
    case SessionCause::kStampJump:
      return "stamp jump";
    case SessionCause::kCamera:
      return "camera changed";
    case SessionCause::kTrackingResumed:
      return "tracking resumed";
  }
  return "?";
}

StreamKeyframe streamKeyframe(const Odometry& odometry, const Odometry::NewKeyframe& kf, int session,
                              const ImageHasher* hasher) {
  const KeyframeInfo& info = odometry.keyframes().at(static_cast<std::size_t>(kf.id));
  StreamKeyframe s;
  KeyframeInput& k = s.input;
  k.session = session;
  k.keyframe = kf.id;
  k.frame_index = info.frame_index;
  k.stamp_s = info.stamp_s;
  k.altitude_m = info.altitude_m;
  k.camera = odometry.featureCamera();  // the keypoints are undistorted
  k.features = kf.features;
  k.motion = kf.id > 0 ? odometry.trajectory().motion(kf.id) : UncertainPose2::exact(Pose2());  // (10)(11)
  k.motion_source = info.source;
  k.odometry_pose = odometry.trajectory().absolutePose(kf.id);
  if (hasher) k.hash = hasher->hash(kf.features.descriptors);  // once: loop detection and the store share it
  s.fallback = info.fallback;
  if (kf.id > 0 && !info.fallback) s.match = info.match;
  return s;
}

namespace {
SessionCause causeOf(SessionStart::Cause c) {
  switch (c) {
    case SessionStart::Cause::kRequested:
      return SessionCause::kRequested;
    case SessionStart::Cause::kStampJump:
      return SessionCause::kStampJump;
    case SessionStart::Cause::kCamera:
      return SessionCause::kCamera;
    default:
      return SessionCause::kFirstFrame;
  }
}
}  // namespace

FrameStream::FrameStream(const SlamConfig& config, const StampGuardOptions& stamps, SessionHooks hooks,
                         int first_session, const ImageHasher* hasher)
    : config_(config),
      stamp_options_(stamps),
      hooks_(std::move(hooks)),
      placer_(config.odometry.nav),
      stamps_(std::make_unique<StampGuard>(stamps)),
      session_(first_session) {
  if (!hasher)
    hasher = &own_hasher_.emplace(config.loops.global.hash_mode, config.odometry.features.num_features,
                                  config.loops.global.projection_seed);
  hasher_ = hasher;
  std::string bad = config.tracking.validate();
  if (bad.empty()) bad = config.odometry.validate();
  if (!bad.empty()) throw std::invalid_argument("frame stream: " + bad);
}

void FrameStream::beginStream(std::optional<NavFrame> nav_frame) {
  end(SessionEnd::kNextSession, last_stamp_, nullptr);
  stamps_ = std::make_unique<StampGuard>(stamp_options_);
  placer_.beginStream(std::move(nav_frame));
  first_ = true;
  pieces_ = 0;
  pending_.reset();
}

void FrameStream::endStream(double stamp_s) { end(SessionEnd::kStreamEnd, stamp_s, nullptr); }

void FrameStream::passOver(const std::vector<double>& stamps_s) {
  for (double t : stamps_s) stamps_->passOver(t);
}

StageTimes FrameStream::times() const {
  StageTimes t = finished_;
  if (segmented_) t.merge(segmented_->times());
  return t;
}

void FrameStream::end(SessionEnd cause, double stamp_s, FrameResult* r, std::string why) {
  if (!open_) return;
  if (hooks_.close) hooks_.close({session_, cause, stamp_s, segmented_ ? segmented_->odometry() : nullptr});
  if (r) r->ended.push_back({session_, cause, std::move(why)});
  open_ = false;
  previous_session_ = session_;
  placer_.pieceEnded();
  held_placement_.reset();
}

void FrameStream::restart(const SessionStart& start, const CameraIntrinsics& camera, FrameResult* r) {
  end(SessionEnd::kNextSession, last_stamp_, r);
  if (segmented_) {
    finished_.merge(segmented_->times());
    retired_dense_tries_ += segmented_->denseTries();
    retired_dense_matches_ += segmented_->denseMatches();
    retired_restarts_ += segmented_->restarts();
    retired_rejoin_tries_ += segmented_->rejoinTries();
  }
  segmented_ = std::make_unique<SegmentedOdometry>(camera, config_.odometry, config_.tracking);
  skip_rule_.emplace(camera, config_.odometry.keyframes);
  camera_ = camera;
  frame_index_ = 0;
  pending_ = start;
  first_ = false;
}

void FrameStream::open(SessionCause cause, int proposed, const std::string& why, double stamp_s, FrameResult* r) {
  const int id = hooks_.open ? hooks_.open({cause, proposed, stamp_s, pieces_, why}) : proposed;
  session_ = id;
  open_ = true;
  any_session_ = true;
  ++pieces_;
  ++counts_.sessions;
  r->started = FrameResult::Started{id, cause, why};
}

void FrameStream::release(const SegmentedOdometry::Step& step, FrameResult* r) {
  if (step.placement) held_placement_ = *step.placement;
  if (!open_) return;
  const Odometry& odometry = *segmented_->odometry();
  const std::vector<Odometry::NewKeyframe>& released = segmented_->newKeyframes();
  // The odometry's placement goes with the keyframe of the frame that made it (the piece's first
  // after a tracking loss), else the last released one, else it waits for the piece's next.
  int placed_kf = -1;
  if (held_placement_ && !released.empty()) {
    placed_kf = released.back().id;
    for (const auto& kf : released)
      if (kf.id == step.update.keyframe_id) placed_kf = kf.id;
  }
  for (const auto& kf : released) {
    StreamKeyframe k = streamKeyframe(odometry, kf, session_, hasher_);
    const std::optional<NavRecord>& nav = odometry.keyframes()[static_cast<std::size_t>(kf.id)].nav;
    NavPlacer::Placed placed;
    if (kf.id == placed_kf) {
      placed = held_placement_->visual ? NavPlacer::bridged(*held_placement_, previous_session_, session_, kf.id)
                                       : placer_.afterLoss(*held_placement_, previous_session_, session_, kf.id, nav);
      held_placement_.reset();
    } else if (kf.id == 0 && r->started && r->started->cause != SessionCause::kTrackingResumed) {
      placed = placer_.newSession(session_, nav);
    }
    k.input.nav_placement = placed.placement;
    (placed.placement && placed.placement->visual ? counts_.bridges : counts_.placements) +=
        placed.placement.has_value();
    counts_.placements_refused += placed.refused;
    if (!placed.said.empty()) (placed.refused ? r->warnings : r->notes).push_back(placed.said);
    placer_.released(session_, kf.id, nav);  // after its own placement: the anchor is an earlier keyframe
    r->keyframes.push_back(std::move(k));
    ++counts_.keyframes;
  }
}

FrameResult FrameStream::process(FrameInput in) {
  FrameResult r;
  ++counts_.frames;
  next_free_ = in.requested.next_free;
  r.timing = stamps_->accept(in.stamp_s);
  if (StampGuard::skips(r.timing)) {
    ++(r.timing == StampClass::kDuplicate ? counts_.duplicates : counts_.out_of_order);
    r.skipped_stamp = true;
    r.session = session();
    return r;
  }
  if (StampGuard::startsSession(r.timing)) r.jump_s = stamps_->lastJump();
  const std::optional<double> period = stamps_->period();
  if (!warned_period_ && period && stamp_options_.session_gap_s > 0 && *period > stamp_options_.session_gap_s) {
    warned_period_ = true;
    char line[400];
    std::snprintf(line, sizeof line,
                  "the camera's frame period, %.1f s (the median of its recent stamp intervals), is beyond "
                  "session_gap_s %.1f s: a fixed gap would start a session at every frame; a forward gap starts one "
                  "only beyond %.3g frame periods (%.1f s now)",
                  *period, stamp_options_.session_gap_s, stamp_options_.gap_periods, stamps_->gapThreshold());
    r.warnings.push_back(line);
  }

  // Session starts. A session the stream numbers itself takes the next id past the last one and
  // past those other vehicles' sessions took in the back-end (requested.next_free).
  const int current = first_ && any_session_ ? session_ + 1 : session_;
  const SessionStart start =
      sessionStart(first_, current, in.requested, r.timing, r.jump_s, segmented_ && camera_ != in.camera);
  if (start.starts()) {
    if (start.cause == SessionStart::Cause::kStampJump) ++(r.jump_s < 0 ? counts_.jumps_back : counts_.jumps_forward);
    restart(start, in.camera, &r);
  }

  std::optional<NavRecord> nav;
  if (in.nav && config_.odometry.nav.enabled) nav = in.nav(r.timing == StampClass::kJumpBack);
  r.with_nav = nav.has_value();
  const int index = in.index >= 0 ? in.index : frame_index_++;
  const double ahead = skip_rule_->predicting() ? in.keyframe_lookahead_s : 0.0;
  const SegmentedOdometry::Step step =
      segmented_->process({index, in.stamp_s, in.altitude_m, in.image, nav, ahead}, in.prepared);
  r.update = step.update;
  counts_.dense_tries = retired_dense_tries_ + segmented_->denseTries();
  counts_.dense_matches = retired_dense_matches_ + segmented_->denseMatches();
  counts_.restarts = retired_restarts_ + segmented_->restarts();
  counts_.rejoin_tries = retired_rejoin_tries_ + segmented_->rejoinTries();
  r.moved = step.update.status != FrameStatus::kSkipped;
  skip_rule_->observe(
      processedFrame(step.update, in.stamp_s, in.altitude_m, step.session_started, segmented_->odometry()));
  if (step.session_started) {
    if (pending_) {
      open(causeOf(pending_->cause), pending_->id, pending_->why, in.stamp_s, &r);
      pending_.reset();
    } else {
      // After a restart the piece's origin is the unmatched frame before this one.
      const int origin = segmented_->odometry()->keyframes().front().frame_index;
      open(SessionCause::kTrackingResumed, std::max(session_ + 1, next_free_),
           "tracking resumed at frame " + std::to_string(origin), in.stamp_s, &r);
    }
  }
  if (open_) last_stamp_ = in.stamp_s;
  release(step, &r);
  r.session = session();  // the frame's pose is in it, also when this frame closes it
  if (step.session_closed) {
    ++counts_.tracking_losses;
    std::string why;
    if (step.update.restart_index >= 0) {
      why = "frame " + std::to_string(step.update.index) + " registers only with the unmatched frame " +
            std::to_string(step.update.restart_index) + " before it: the next session starts there";
    } else if (step.update.nav_loss) {
      why = "neither vision nor the nav gave a motion";
    } else {
      why = std::to_string(config_.tracking.max_fallbacks) + " unmatched frames";
    }
    end(SessionEnd::kTrackingLoss, in.stamp_s, &r, std::move(why));
  }
  return r;
}

}  // namespace core
}  // namespace uw_multislam
