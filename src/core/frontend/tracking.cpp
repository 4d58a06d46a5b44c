#include "uw_multislam/core/frontend/tracking.h"

#include <algorithm>
#include <stdexcept>

namespace uw_multislam {
namespace core {

std::string TrackingLossOptions::validate() const {
  if (max_fallbacks < 0) return "max_fallbacks must be >= 0 (0 = never close a session)";
  if (min_features < 1) return "min_features must be >= 1";
  if (rejoin_keyframes < 0) return "rejoin_keyframes must be >= 0 (0 = never)";
  return {};
}

SegmentedOdometry::SegmentedOdometry(const CameraIntrinsics& camera, const OdometryOptions& odometry,
                                     const TrackingLossOptions& loss)
    : camera_(camera), options_(odometry), loss_(loss) {
  const std::string bad = loss.validate();
  if (!bad.empty()) throw std::invalid_argument("tracking: " + bad);
  const std::string bad_odometry = odometry.validate();
  if (!bad_odometry.empty()) throw std::invalid_argument("odometry: " + bad_odometry);
}

StageTimes SegmentedOdometry::times() const {
  StageTimes all = times_;
  if (odometry_) all.merge(odometry_->times());
  return all;
}

void SegmentedOdometry::retire(const Odometry& odometry) {
  times_.merge(odometry.times());
  dense_tries_ += odometry.stats().dense_tries;
  dense_matches_ += odometry.stats().dense_matches;
  restarts_ += odometry.stats().restarts;
}

long SegmentedOdometry::denseTries() const { return dense_tries_ + (odometry_ ? odometry_->stats().dense_tries : 0); }
long SegmentedOdometry::denseMatches() const {
  return dense_matches_ + (odometry_ ? odometry_->stats().dense_matches : 0);
}
long SegmentedOdometry::restarts() const { return restarts_ + (odometry_ ? odometry_->stats().restarts : 0); }

void SegmentedOdometry::begin(std::unique_ptr<Odometry> odometry, Step* step) {
  odometry_ = std::move(odometry);
  consecutive_fallbacks_ = 0;
  pending_.clear();
  released_ = odometry_->newKeyframes();
  kept_ = static_cast<int>(released_.size());
  ++sessions_;
  step->session_started = true;
  // The nav saw the whole stretch the odometry lost: it places this piece against the last one
  // (a link the back-end joins the maps by, loops refine it), instead of a new map.
  const std::optional<NavRecord>& here = odometry_->keyframes().front().nav;
  if (options_.nav.enabled && options_.nav.place_pieces && previous_nav_ && here)
    step->placement =
        NavPlacement{previous_nav_->first, navPlacement(previous_nav_->second, *here, options_.nav, true)};
  previous_nav_.reset();
  if (step->placement) anchor_.reset();  // placed by the nav already
}

void SegmentedOdometry::rejoin(Step* step) {
  const int id = step->update.keyframe_id;
  if (!anchor_ || step->placement || id < 0 || odometry_->keyframes()[static_cast<std::size_t>(id)].fallback) return;
  // The placement goes with this keyframe: only when it is released now.
  const auto& released = released_;
  if (std::none_of(released.begin(), released.end(), [id](const Odometry::NewKeyframe& k) { return k.id == id; }))
    return;
  ++rejoin_tries_;
  --rejoin_left_;
  if (const std::optional<UncertainPose2> z = odometry_->registerAnchor(*anchor_)) {
    step->placement = NavPlacement{anchor_->keyframe, *z, true};
    ++rejoins_;
    anchor_.reset();
  } else if (rejoin_left_ <= 0) {
    anchor_.reset();
  }
}

bool SegmentedOdometry::restart(Step* step) {
  std::vector<Odometry::RestartFrame> frames = std::move(restart_);
  restart_.clear();
  auto candidate = std::make_unique<Odometry>(camera_, options_);
  const OdometryUpdate first = candidate->process(frames.front().input, &frames.front().prepared);
  if (first.status != FrameStatus::kFirstKeyframe || first.features < loss_.min_features) {
    retire(*candidate);
    return false;
  }
  begin(std::move(candidate), step);
  for (std::size_t i = 1; i < frames.size(); ++i) absorb(odometry_->process(frames[i].input, &frames[i].prepared));
  return true;
}

void SegmentedOdometry::absorb(const OdometryUpdate& u) {
  const FrameStatus st = u.status;
  if (st == FrameStatus::kFallback) {
    ++consecutive_fallbacks_;
  } else if (st != FrameStatus::kSkipped) {
    consecutive_fallbacks_ = 0;
  }
  // Only a visual match (not a frame the nav carried) releases the fallback keyframes held: a
  // nav-carried frame says nothing about whether the reused motions were right.
  const bool matched = (st == FrameStatus::kTracked || st == FrameStatus::kKeyframe) && u.source != MotionSource::kNav;
  // Hold fallback keyframes (and any after them) until a frame is matched again.
  std::vector<Odometry::NewKeyframe> released;
  for (const auto& kf : odometry_->newKeyframes()) {
    if (pending_.empty() && !odometry_->keyframes()[kf.id].fallback) {
      released.push_back(kf);
    } else {
      pending_.push_back(kf);
    }
  }
  if (matched) {
    released.insert(released.end(), pending_.begin(), pending_.end());
    pending_.clear();
  }
  kept_ += static_cast<int>(released.size());
  released_.insert(released_.end(), released.begin(), released.end());
}

SegmentedOdometry::Step SegmentedOdometry::process(const OdometryInput& input, PreparedFrame* prepared) {
  Step step;
  released_.clear();
  if (closed_) {
    retire(*odometry_);
    odometry_.reset();
    closed_ = false;
  }
  if (!odometry_ && !restart_.empty()) restart(&step);
  if (!odometry_) {
    // No session open: this frame starts one if it has enough features.
    auto candidate = std::make_unique<Odometry>(camera_, options_);
    step.update = candidate->process(input, prepared);
    if (step.update.status != FrameStatus::kFirstKeyframe || step.update.features < loss_.min_features) {
      retire(*candidate);
      if (sessions_ > 0) ++frames_lost_;
      if (step.update.status != FrameStatus::kSkipped) {
        step.update.reason = "no session: " + std::to_string(step.update.features) + " features, " +
                             std::to_string(loss_.min_features) + " needed to start one";
      }
      step.update.status = FrameStatus::kSkipped;
      step.update.keyframe_id = -1;
      return step;
    }
    begin(std::move(candidate), &step);
    rejoin(&step);
    return step;
  }
  step.update = odometry_->process(input, prepared);
  absorb(step.update);
  rejoin(&step);
  // A nav stream ends at once when neither vision nor the nav gives a motion past the bridged
  // frames (Odometry made none up); max_fallbacks 0 keeps the session open, unmatched. A frame
  // that registers with the unmatched one before it, not with the session, ends it at once too:
  // the next session starts at that unmatched frame (restartFrames), at the next process().
  const bool restarts = step.update.restart_index >= 0 && !odometry_->restartFrames().empty();
  if ((loss_.max_fallbacks > 0 && (consecutive_fallbacks_ >= loss_.max_fallbacks || step.update.nav_loss)) ||
      restarts) {
    step.session_closed = true;
    closed_ = true;
    ++losses_;
    pending_.clear();  // dropped: the session ends at its last measured keyframe
    previous_nav_ = lastNavKeyframe();
    anchor_ = odometry_->lastKeyframeAnchor();
    if (anchor_ && anchor_->keyframe >= kept_) anchor_.reset();  // not kept: no link can start there
    rejoin_left_ = loss_.rejoin_keyframes;
    if (rejoin_left_ <= 0) anchor_.reset();
    if (restarts) restart_ = odometry_->restartFrames();
  }
  return step;
}

std::optional<std::pair<int, NavRecord>> SegmentedOdometry::lastNavKeyframe() const {
  if (!odometry_) return std::nullopt;
  const std::vector<KeyframeInfo>& kfs = odometry_->keyframes();
  for (int k = std::min(kept_, static_cast<int>(kfs.size())) - 1; k >= 0; --k)
    if (kfs[k].nav) return std::make_pair(k, *kfs[k].nav);
  return std::nullopt;
}

}  // namespace core
}  // namespace uw_multislam
