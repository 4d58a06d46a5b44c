#include "uw_multislam/core/frontend/odometry.h"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <sstream>
#include <stdexcept>

#include "uw_multislam/core/frontend/camera_model.h"
#include "uw_multislam/core/frontend/frame_skip.h"

namespace uw_multislam {
namespace core {

std::string KeyframeOptions::validate() const {
  std::ostringstream os;
  if (!(min_overlap >= 0.0 && min_overlap < 1.0)) {
    os << "min_overlap " << min_overlap << " must be in [0, 1)";
  } else if (!(max_rotation_rad > 0.0)) {
    os << "max_rotation_rad must be positive";
  } else if (!(max_interval_s >= 0.0)) {
    os << "max_interval_s must be >= 0 (0 = off)";
  } else if (min_tracking_inliers < 0) {
    os << "min_tracking_inliers must be >= 0";
  }
  return os.str();
}

std::string FallbackOptions::validate() const {
  // Upper bounds keep the fallback's covariance (their squares) finite and invertible: 1e308 had
  // ended the run at the first fallback ("covariance has non-finite entries").
  if (!(min_sigma_m > 0 && min_sigma_m <= 1000) || !(relative_sigma >= 0 && relative_sigma <= 1000) ||
      !(sigma_yaw_rad > 0 && sigma_yaw_rad <= 10)) {
    return "min_sigma_m must be in (0, 1000], relative_sigma in [0, 1000], sigma_yaw_rad in (0, 10]";
  }
  if (bridge_frames < 0 || bridge_frames > 1000000) return "bridge_frames must be in [0, 1000000]";
  return {};
}

std::string OdometryOptions::validate() const {
  const std::pair<const char*, std::string> checks[] = {{"enhancement", enhancement.validate()},
                                                        {"features", features.validate()},
                                                        {"matching", matching.validate()},
                                                        {"ransac", ransac.validate()},
                                                        {"keyframes", keyframes.validate()},
                                                        {"fallback", fallback.validate()},
                                                        {"nav", nav.validate()},
                                                        {"klt", klt.validate()},
                                                        {"dense", dense.validate()}};
  for (const auto& c : checks) {
    if (!c.second.empty()) return std::string(c.first) + ": " + c.second;
  }
  if (!(max_altitude_m > 0.0) || !std::isfinite(max_altitude_m)) return "max_altitude_m must be positive and finite";
  // More inliers than features can never be found: every frame was a fallback, without a word.
  if (ransac.min_inliers > features.num_features)
    return "ransac: min_inliers " + std::to_string(ransac.min_inliers) + " is more than features.num_features " +
           std::to_string(features.num_features);
  return {};
}

std::string statusName(FrameStatus s) {
  switch (s) {
    case FrameStatus::kFirstKeyframe:
      return "first_keyframe";
    case FrameStatus::kTracked:
      return "tracked";
    case FrameStatus::kKeyframe:
      return "keyframe";
    case FrameStatus::kFallback:
      return "fallback";
    case FrameStatus::kSkipped:
      return "skipped";
  }
  return "unknown";
}

namespace {
const OdometryOptions& checked(const OdometryOptions& o, const CameraIntrinsics& c) {
  std::string bad = o.validate();
  if (bad.empty()) bad = c.validate();
  if (!bad.empty()) throw std::invalid_argument("odometry: " + bad);
  return o;
}
}  // namespace

Odometry::Odometry(const CameraIntrinsics& camera, const OdometryOptions& options)
    : camera_(camera),
      feature_camera_(camera.pinhole()),
      options_(checked(options, camera)),
      preparer_(camera, options_),
      klt_(options.klt) {
  if (options_.dense.enabled) dense_.emplace(options_.dense, options_.features);
}

FramePreparer::FramePreparer(const CameraIntrinsics& camera, const OdometryOptions& options)
    : camera_(camera),
      extract_all_(!options.klt.enabled),
      enhancer_(options.enhancement),
      extractor_(options.features) {}

cv::Mat FramePreparer::enhance(const cv::Mat& image) { return enhancer_.enhance(image); }

FrameFeatures FramePreparer::extract(const cv::Mat& grey) const {
  FrameFeatures f = extractor_.extract(grey);
  undistortKeypoints(&f.keypoints, camera_);  // only the points, never the image
  return f;
}

PreparedFrame FramePreparer::prepare(const cv::Mat& image) {
  PreparedFrame p;
  if (image.empty() || image.cols != camera_.width || image.rows != camera_.height) return p;
  p.done = true;
  using Clock = std::chrono::steady_clock;
  const auto ms = [](Clock::time_point a, Clock::time_point b) {
    return std::chrono::duration<double, std::milli>(b - a).count();
  };
  try {
    const auto t0 = Clock::now();
    p.grey = enhance(image);
    const auto t1 = Clock::now();
    p.enhance_ms = ms(t0, t1);
    if (extract_all_) {
      p.features = extract(p.grey);
      p.features_ms = ms(t1, Clock::now());
    }
  } catch (const std::invalid_argument& e) {
    p.error = e.what();
  }
  return p;
}

std::optional<MotionPrior> Odometry::ransacPrior(const std::optional<NavRecord>& nav) const {
  // (a) With the nav at both frames, its motion gates RANSAC's hypotheses (nav.gate_ransac).
  if (!(options_.nav.gate_ransac && options_.nav.gate_confidence > 0 && nav && last_kf_.nav)) return std::nullopt;
  const UncertainPose2 m = navMotion(*last_kf_.nav, *nav, options_.nav);
  return MotionPrior{m.mean, m.covariance, navGateThreshold(options_.nav)};
}

PairMotion Odometry::matchToKeyframe(const FrameFeatures& f, double altitude_m, const std::optional<NavRecord>& nav) {
  const std::optional<MotionPrior> prior = ransacPrior(nav);
  PairMotion p = estimatePairMotion({&last_kf_.features, last_kf_.altitude_m, &feature_camera_},
                                    {&f, altitude_m, &feature_camera_}, options_.matching, options_.ransac, &times_,
                                    prior ? &*prior : nullptr);
  stats_.hypotheses_gated += p.ransac.hypotheses_gated;
  return p;
}

const FrameFeatures& Odometry::denseFeatures(const TrackedFrame& frame) {
  static const FrameFeatures none;
  if (!dense_ || !frame.images || frame.images->grey.empty()) return none;
  if (!frame.images->dense) {
    ScopedStage s(&times_, "dense_features");
    frame.images->dense = dense_->extract(frame.images->grey, camera_);
  }
  return *frame.images->dense;
}

PairMotion Odometry::matchDense(const TrackedFrame& a, const TrackedFrame& b, const MotionPrior* prior) {
  ++stats_.dense_tries;
  const FrameFeatures& fa = denseFeatures(a);
  const FrameFeatures& fb = denseFeatures(b);
  ScopedStage s(&times_, "dense_match");
  MatchOptions matching = options_.matching;
  matching.ratio = options_.dense.ratio;
  matching.mutual = true;
  RansacOptions ransac = options_.ransac;
  ransac.min_inliers = options_.dense.min_inliers;
  PairMotion p = estimatePairMotion({&fa, a.altitude_m, &feature_camera_}, {&fb, b.altitude_m, &feature_camera_},
                                    matching, ransac, nullptr, prior);
  stats_.hypotheses_gated += p.ransac.hypotheses_gated;
  if (p.ransac.success) {
    std::vector<cv::Point2f> inliers;
    inliers.reserve(p.ransac.inliers.size());
    for (int i : p.ransac.inliers) inliers.push_back(fb.keypoints[p.correspondences[i].b].pt);
    const std::string refused =
        denseAccepts(static_cast<int>(inliers.size()), convexHullArea(inliers),
                     footprintOverlap(p.ransac.motion, a.altitude_m, b.altitude_m), feature_camera_, options_.dense);
    if (refused.empty()) {
      ++stats_.dense_matches;
      return p;
    }
    p.ransac.success = false;
    p.ransac.failure = refused;
  }
  p.ransac.failure = "dense pass: " + p.ransac.failure;
  return p;
}

namespace {
// The dense pass needs texture: a blank frame (no normal feature) would only give it noise to match.
bool hasTexture(const FrameFeatures& f, const DenseMatchOptions& o) {
  return static_cast<int>(f.size()) >= o.min_inliers;
}
}  // namespace

bool Odometry::registersWithUnmatched(const TrackedFrame& cur) {
  const TrackedFrame& u = *unmatched_frame_;
  PairMotion p = estimatePairMotion({&u.features, u.altitude_m, &feature_camera_},
                                    {&cur.features, cur.altitude_m, &feature_camera_}, options_.matching,
                                    options_.ransac, &times_);
  if (!p.ransac.success && dense_ && hasTexture(u.features, options_.dense) && hasTexture(cur.features, options_.dense))
    p = matchDense(u, cur, nullptr);
  if (!p.ransac.success || !u.images || !cur.images) return false;
  for (const TrackedFrame* f : {&u, &cur}) {
    RestartFrame r;
    r.input.index = f->index;
    r.input.stamp_s = f->stamp_s;
    r.input.altitude_m = f->altitude_m;
    r.input.image = f->images->grey;
    r.input.nav = f->nav;
    r.prepared.done = true;
    r.prepared.grey = f->images->enhanced;
    r.prepared.features = f->features;
    restart_frames_.push_back(std::move(r));
  }
  return true;
}

std::optional<Odometry::Anchor> Odometry::lastKeyframeAnchor() const {
  if (keyframes_.empty() || keyframes_.back().fallback || last_kf_.features.empty()) return std::nullopt;
  return Anchor{static_cast<int>(keyframes_.size()) - 1, last_kf_.index, last_kf_.altitude_m, last_kf_.features,
                last_kf_.images};
}

std::optional<UncertainPose2> Odometry::registerAnchor(const Anchor& anchor) {
  if (keyframes_.empty() || keyframes_.back().fallback || last_kf_.features.empty()) return std::nullopt;
  TrackedFrame a;
  a.index = anchor.frame_index;
  a.altitude_m = anchor.altitude_m;
  a.features = anchor.features;
  a.images = anchor.images;
  PairMotion p = estimatePairMotion({&a.features, a.altitude_m, &feature_camera_},
                                    {&last_kf_.features, last_kf_.altitude_m, &feature_camera_}, options_.matching,
                                    options_.ransac, &times_);
  if (!p.ransac.success && dense_ && hasTexture(a.features, options_.dense) &&
      hasTexture(last_kf_.features, options_.dense))
    p = matchDense(a, last_kf_, nullptr);
  if (!p.ransac.success) return std::nullopt;
  return UncertainPose2(p.ransac.motion, p.ransac.covariance);
}

FrameFeatures Odometry::extractFeatures(const cv::Mat& grey) {
  ScopedStage s(&times_, "features");
  return preparer_.extract(grey);
}

bool Odometry::trackBetweenKeyframes(const cv::Mat& grey, TrackedFrame* cur, OdometryUpdate* up) {
  KltTracker::Tracks t;
  {
    ScopedStage s(&times_, "klt");
    t = klt_.track(grey);
  }
  up->tracks = static_cast<int>(t.current_px.size());
  const auto degraded = [&] {
    ++stats_.klt_extracted;
    ++stats_.klt_degraded;
    return false;
  };
  if (up->tracks < options_.klt.min_tracks) return degraded();
  // The same metres as for SIFT matches: undistorted pixels of the pinhole feature camera scaled
  // by each frame's altitude, then the same RANSAC (Algorithm 1) with the same options.
  const std::vector<cv::Point2f> kf_px = undistortPixels(t.keyframe_px, camera_);
  const std::vector<cv::Point2f> cur_px = undistortPixels(t.current_px, camera_);
  std::vector<Eigen::Vector2d> a, b;
  a.reserve(kf_px.size());
  b.reserve(cur_px.size());
  for (std::size_t i = 0; i < kf_px.size(); ++i) {
    a.push_back(pixelToMetres(kf_px[i], feature_camera_, last_kf_.altitude_m));
    b.push_back(pixelToMetres(cur_px[i], feature_camera_, cur->altitude_m));
  }
  const std::optional<MotionPrior> prior = ransacPrior(cur->nav);
  RansacResult r;
  {
    ScopedStage s(&times_, "ransac");
    const double metres_per_px = cur->altitude_m / (0.5 * (feature_camera_.fx + feature_camera_.fy));
    r = estimateRigidRansac(a, b, metres_per_px, options_.ransac, prior ? &*prior : nullptr);
  }
  stats_.hypotheses_gated += r.hypotheses_gated;
  if (!r.success) return degraded();
  UncertainPose2 motion(r.motion, r.covariance);
  const bool nav = cur->nav && last_kf_.nav;
  double d2 = -1.0;
  UncertainPose2 nav_motion;
  if (nav) {
    nav_motion = navMotion(*last_kf_.nav, *cur->nav, options_.nav);
    if (options_.nav.gate_confidence > 0) {
      d2 = navGateDistance2(motion, nav_motion);
      if (d2 > navGateThreshold(options_.nav)) return degraded();  // the full way decides and counts
    }
  }
  const double overlap = footprintOverlap(r.motion, last_kf_.altitude_m, cur->altitude_m);
  if (needsKeyframe(r, overlap, cur->stamp_s) ||
      dueAhead(compose(last_kf_.pose, r.motion), cur->stamp_s, cur->altitude_m)) {
    ++stats_.klt_extracted;  // a keyframe is due: SIFT measures it
    return false;
  }
  if (d2 >= 0) ++stats_.gate_checks;
  up->gate_distance2 = d2;
  if (nav && options_.nav.fuse) {
    motion = fuseMotions(motion, nav_motion);
    cur->source = MotionSource::kFused;
    up->source = MotionSource::kFused;
    ++stats_.fused;
  }
  cur->motion = motion;
  cur->pose = compose(last_kf_.pose, motion.mean);
  last_step_ = between(prev_.pose, cur->pose);
  up->klt = true;
  up->matches = up->tracks;
  up->inliers = static_cast<int>(r.inliers.size());
  up->scale = r.scale;
  up->overlap = overlap;
  up->covariance = compose(UncertainPose2(last_kf_.pose, last_kf_covariance_), motion).covariance;
  up->status = FrameStatus::kTracked;
  up->pose = cur->pose;
  ++stats_.tracked;
  ++stats_.klt_tracked;
  return true;
}

double Odometry::footprintOverlap(const Pose2& motion, double kf_altitude, double altitude) const {
  return core::footprintOverlap(camera_, motion, kf_altitude, altitude);  // one rule, shared with FrameSkipRule
}

bool Odometry::needsKeyframe(const RansacResult& r, double overlap, double stamp_s) const {
  const KeyframeOptions& k = options_.keyframes;
  return k.takes(overlap, r.motion.yaw(), stamp_s - last_kf_.stamp_s) ||
         static_cast<int>(r.inliers.size()) < k.min_tracking_inliers;
}

bool Odometry::dueAhead(const Pose2& pose, double stamp_s, double altitude_m) const {
  const double dt = stamp_s - prev_.stamp_s;
  if (!(lookahead_s_ > 0) || !(dt > 0)) return false;
  // Constant velocity from the previous frame, as FrameSkipRule predicts the frames waiting.
  const Pose2 motion = between(last_kf_.pose, extrapolate(pose, between(prev_.pose, pose), lookahead_s_ / dt));
  return options_.keyframes.takes(footprintOverlap(motion, last_kf_.altitude_m, altitude_m), motion.yaw(),
                                  stamp_s + lookahead_s_ - last_kf_.stamp_s);
}

void Odometry::addKeyframe(const TrackedFrame& frame, const UncertainPose2& motion, bool fallback,
                           MotionSource source) {
  // Incremental: Trajectory::absolute(k) would compose all k motions again at every frame.
  last_kf_covariance_ =
      compose(UncertainPose2(trajectory_.absolutePoses().back(), last_kf_covariance_), motion).covariance;
  trajectory_.append(motion);
  new_keyframes_.push_back({static_cast<int>(keyframes_.size()), frame.features});
  keyframes_.push_back({frame.index, frame.stamp_s, frame.altitude_m, fallback,
                        fallback ? MotionSource::kFallback : source, fallback ? MatchSummary() : frame.match});
  last_kf_ = frame;
  if (fallback) last_kf_.nav.reset();  // an extrapolated pose is never the nav's anchor
  if (!fallback && source != MotionSource::kNav && !frame.nav && refused_nav_ && refused_nav_->first == frame.index) {
    // Vision measured this pose and the nav has stayed where it jumped: it anchors the nav again.
    last_kf_.nav = refused_nav_->second;
    prev_nav_accepted_ = refused_nav_->second;
  }
  last_kf_.pose = trajectory_.absolutePoses().back();
  last_kf_.motion = motion;
  keyframes_.back().nav = last_kf_.nav;
  ++stats_.keyframes;
}

void Odometry::unmatchedFrame(OdometryUpdate* up) {
  predicted_ = compose(unmatched_ > 0 ? predicted_ : prev_.pose, last_step_);
  ++unmatched_;
  ++stats_.fallbacks;
  up->pose = predicted_;
  up->covariance = last_kf_covariance_;
  up->status = FrameStatus::kFallback;
  up->source = MotionSource::kFallback;
}

void Odometry::carryByNav(TrackedFrame* cur, const UncertainPose2& m, OdometryUpdate* up) {
  cur->motion = m;
  cur->source = MotionSource::kNav;
  cur->pose = compose(last_kf_.pose, m.mean);
  last_step_ = between(prev_.pose, cur->pose);
  up->source = MotionSource::kNav;
  up->overlap = footprintOverlap(m.mean, last_kf_.altitude_m, cur->altitude_m);  // predicted by the nav
  up->covariance = compose(UncertainPose2(last_kf_.pose, last_kf_covariance_), m).covariance;
  ++stats_.nav_frames;
  const KeyframeOptions& k = options_.keyframes;
  const int restart = options_.nav.min_features_to_restart;
  if (up->overlap < k.min_overlap || std::abs(m.mean.yaw()) > k.max_rotation_rad ||
      (static_cast<int>(cur->features.size()) >= restart && static_cast<int>(last_kf_.features.size()) < restart)) {
    addKeyframe(*cur, m, false, MotionSource::kNav);
    up->status = FrameStatus::kKeyframe;
    up->keyframe_id = static_cast<int>(keyframes_.size()) - 1;
  } else {
    up->status = FrameStatus::kTracked;
  }
}

OdometryUpdate Odometry::process(const OdometryInput& in, PreparedFrame* prepared) {
  ScopedStage total(&times_, "odometry_total");
  ++stats_.frames;
  new_keyframes_.clear();
  restart_frames_.clear();
  lookahead_s_ = std::isfinite(in.keyframe_lookahead_s) ? std::max(0.0, in.keyframe_lookahead_s) : 0.0;
  OdometryUpdate up;
  up.index = in.index;
  if (in.image.empty()) {
    ++stats_.skipped_image;
    up.reason = "empty image";
    return up;
  }
  if (in.image.cols != camera_.width || in.image.rows != camera_.height) {
    // The intrinsics would scale every feature wrongly: a silently wrong trajectory.
    ++stats_.skipped_image;
    up.reason = "image is " + std::to_string(in.image.cols) + "x" + std::to_string(in.image.rows) + ", the camera " +
                std::to_string(camera_.width) + "x" + std::to_string(camera_.height);
    return up;
  }
  double alt = in.altitude_m;
  if (std::isfinite(alt) && alt > options_.max_altitude_m) ++stats_.altitude_out_of_range;  // NaN, inf: invalid
  if (std::isfinite(alt) && alt > 0.0 && alt <= options_.max_altitude_m) {
    last_altitude_ = alt;
  } else if (last_altitude_ > 0.0) {
    alt = last_altitude_;
    ++stats_.altitude_reused;
  } else {
    ++stats_.skipped_altitude;
    up.reason = "no valid altitude yet";
    return up;
  }

  TrackedFrame cur;
  cur.index = in.index;
  cur.stamp_s = in.stamp_s;
  cur.altitude_m = alt;
  if (options_.nav.enabled) cur.nav = in.nav;
  if (cur.nav) {
    // A glitch of the nav (one bad row, a reset) must not overrule the camera through the gate
    // or carry the frame: this frame is processed as one without nav. Checked against the last
    // keyframe (the motion's other end) and against the last ACCEPTED reading, never a refused
    // one, over one frame's interval: a glitch that comes back is accepted where it ends, one of
    // several rows is refused on each of them (each is as far from the last accepted reading).
    // The anchor (last_kf_.nav) is kept through a refusal: the next accepted reading's motion is
    // taken from it, so no heading change is dropped. A jump that stays (a turn faster than the
    // limit, a reset) is refused until a keyframe vision measured takes it as the new anchor
    // (addKeyframe); with vision blind the session ends first (processExtracted).
    nav_seen_ = true;
    const NavRecord reading = *cur.nav;
    std::string bad;
    if (last_kf_.nav) bad = navStepImplausible(*last_kf_.nav, reading, options_.nav);
    if (bad.empty() && prev_nav_accepted_) {
      NavRecord from = *prev_nav_accepted_;
      if (prev_nav_received_) from.stamp_s = prev_nav_received_->stamp_s;
      bad = navStepImplausible(from, reading, options_.nav);
    }
    refused_nav_.reset();
    if (!bad.empty()) {
      cur.nav.reset();
      ++stats_.nav_implausible;
      up.nav_note = bad;
      // Steady since the previous reading: a jump that stays, which a visual keyframe may anchor.
      if (prev_nav_received_ && navStepImplausible(*prev_nav_received_, reading, options_.nav).empty())
        refused_nav_ = std::make_pair(cur.index, reading);
    } else {
      prev_nav_accepted_ = reading;
    }
    prev_nav_received_ = reading;
  } else {
    prev_nav_received_.reset();
  }
  cv::Mat grey;
  try {
    if (prepared && prepared->done) {
      times_.add("enhance", prepared->enhance_ms);
      if (!prepared->error.empty()) throw std::invalid_argument(prepared->error);
      grey = prepared->grey;
    } else {
      ScopedStage s(&times_, "enhance");
      grey = preparer_.enhance(in.image);
    }
    // Kept with the frame: the dense pass extracts from the camera's grey image (flat-fielded, not
    // the enhanced one), and a restart processes the frame again. A copy: the caller's buffer may be reused.
    cur.images = std::make_shared<FrameImages>();
    if (in.image.channels() == 3) {
      cv::cvtColor(in.image, cur.images->grey, cv::COLOR_BGR2GRAY);
    } else {
      cur.images->grey = in.image.clone();
    }
    cur.images->enhanced = grey;
    if (options_.klt.enabled && !keyframes_.empty() && klt_.active(static_cast<int>(keyframes_.size()) - 1) &&
        trackBetweenKeyframes(grey, &cur, &up)) {
      finishFrame(&cur, up);
      prev_grey_ = grey;  // its features are extracted only if it is ever promoted
      return up;
    }
    if (prepared && prepared->done && prepared->features) {
      times_.add("features", prepared->features_ms);
      cur.features = std::move(*prepared->features);
    } else {
      cur.features = extractFeatures(grey);
    }
  } catch (const std::invalid_argument& e) {
    ++stats_.skipped_image;
    up.reason = e.what();
    return up;
  }
  up.features = static_cast<int>(cur.features.size());
  const int keyframes_before = static_cast<int>(keyframes_.size());
  OdometryUpdate done = processExtracted(&cur, &up);
  if (options_.klt.enabled) {
    const int last = static_cast<int>(keyframes_.size()) - 1;
    // Tracks start only at a keyframe vision measured and SIFT found texture in: corners are
    // chosen relative to the image's strongest, so a blank or featureless frame (a fallback or
    // nav-carried keyframe) would give corners on noise and vignetting that "track" a motion.
    const bool textured = static_cast<int>(cur.features.size()) >= options_.klt.min_tracks;
    if (done.keyframe_id >= 0 && keyframes_[last].frame_index == cur.index && textured &&
        done.status != FrameStatus::kFallback && done.source != MotionSource::kNav) {
      klt_.reset(grey, last);  // the new keyframe is this frame: tracks start here
    } else if (last + 1 != keyframes_before) {
      klt_.invalidate();  // another new keyframe (promoted, fallback, the nav's): no tracks from it
    }
  }
  prev_grey_.release();
  return done;
}

OdometryUpdate Odometry::processExtracted(TrackedFrame* cur_ptr, OdometryUpdate* up_ptr) {
  TrackedFrame& cur = *cur_ptr;
  OdometryUpdate& up = *up_ptr;
  const double alt = cur.altitude_m;
  if (keyframes_.empty()) {
    new_keyframes_.push_back({0, cur.features});
    cur.pose = Pose2();
    keyframes_.push_back({cur.index, cur.stamp_s, cur.altitude_m, false});
    keyframes_.back().nav = cur.nav;
    last_kf_ = cur;
    prev_ = cur;
    ++stats_.keyframes;
    up.status = FrameStatus::kFirstKeyframe;
    up.keyframe_id = 0;
    return up;
  }

  PairMotion m = matchToKeyframe(cur.features, alt, cur.nav);
  if (!m.ransac.success && prev_.index != last_kf_.index && prev_.source != MotionSource::kNav) {
    // Promote the last tracked frame and try again from there (not a frame the nav carried: it
    // was not matched either). A frame tracked by KLT has no features yet: extracted now.
    if (prev_.features.empty() && !prev_grey_.empty()) prev_.features = extractFeatures(prev_grey_);
    addKeyframe(prev_, prev_.motion, false, prev_.source);
    ++stats_.promotions;
    m = matchToKeyframe(cur.features, alt, cur.nav);
  }
  if (!m.ransac.success && dense_ && hasTexture(cur.features, options_.dense)) {
    const std::optional<MotionPrior> prior = ransacPrior(cur.nav);
    PairMotion d = matchDense(last_kf_, cur, prior ? &*prior : nullptr);
    if (d.ransac.success) {
      m = std::move(d);
      up.dense = true;
    } else {
      m.ransac.failure += "; " + d.ransac.failure;
    }
  }
  up.matches = m.matches;
  const bool nav = cur.nav && last_kf_.nav;
  const UncertainPose2 nav_motion = nav ? navMotion(*last_kf_.nav, *cur.nav, options_.nav) : UncertainPose2();
  if (m.ransac.success && nav && options_.nav.gate_confidence > 0) {
    // (c) The visual motion against the nav's: refused beyond the chi-square gate.
    ++stats_.gate_checks;
    up.gate_distance2 = navGateDistance2(UncertainPose2(m.ransac.motion, m.ransac.covariance), nav_motion);
    const double threshold = navGateThreshold(options_.nav);
    if (up.gate_distance2 > threshold) {
      ++stats_.gate_refusals;
      up.gate_refused = true;
      char why[160];
      std::snprintf(why, sizeof why, "visual motion refused by the nav gate (d2 %.1f > %.1f)", up.gate_distance2,
                    threshold);
      up.reason = why;
    }
  }
  if (nav &&
      (up.gate_refused || (!m.ransac.success && options_.nav.on_tracking_loss == TrackingLossPolicy::kDeadReckoning))) {
    // (b) The nav carries the frame: vision failed (dead reckoning) or was refused.
    if (!up.gate_refused) up.reason = "dead reckoning: " + m.ransac.failure;
    up.inliers = m.ransac.success ? static_cast<int>(m.ransac.inliers.size()) : 0;
    carryByNav(&cur, nav_motion, &up);
  } else if (m.ransac.success) {
    cur.motion = UncertainPose2(m.ransac.motion, m.ransac.covariance);
    if (nav && options_.nav.fuse) {
      cur.motion = fuseMotions(cur.motion, nav_motion);
      cur.source = MotionSource::kFused;
      up.source = MotionSource::kFused;
      ++stats_.fused;
    }
    cur.pose = compose(last_kf_.pose, cur.motion.mean);
    last_step_ = between(prev_.pose, cur.pose);
    up.inliers = static_cast<int>(m.ransac.inliers.size());
    up.scale = m.ransac.scale;
    up.overlap = footprintOverlap(cur.motion.mean, last_kf_.altitude_m, alt);
    up.covariance = compose(UncertainPose2(last_kf_.pose, last_kf_covariance_), cur.motion).covariance;
    // A frame the dense pass matched is kept as a keyframe: the next frame is matched to it rather
    // than to the keyframe it barely registered with.
    const bool due = up.dense || needsKeyframe(m.ransac, up.overlap, cur.stamp_s);
    if (due || dueAhead(cur.pose, cur.stamp_s, alt)) {
      up.early_keyframe = !due;
      stats_.early_keyframes += !due;
      addKeyframe(cur, cur.motion, false, cur.source);
      up.status = FrameStatus::kKeyframe;
      up.keyframe_id = static_cast<int>(keyframes_.size()) - 1;
    } else {
      ++stats_.tracked;
      up.status = FrameStatus::kTracked;
    }
  } else if (unmatched_frame_ && registersWithUnmatched(cur)) {
    // The frame before was unmatched and this one registers with it, not with the session: the
    // chain breaks before that frame, and matching the next frames against a keyframe that falls
    // further behind would only fail them too. The session ends; the next starts at that frame.
    unmatchedFrame(&up);
    ++stats_.restarts;
    up.restart_index = unmatched_frame_->index;
    up.reason = "registers with the unmatched frame " + std::to_string(up.restart_index) + ", not with the session (" +
                m.ransac.failure + "): the next session starts there";
    unmatched_frame_.reset();
    return up;
  } else if (unmatched_ < options_.fallback.bridge_frames) {
    // Bridged: no motion is made up. The next frame is matched to the last keyframe (the previous
    // frame, promoted above when it was only tracked); the session's state stays that of the last
    // matched frame. The pose reported is the constant-step prediction, for display only.
    unmatchedFrame(&up);
    ++stats_.bridged;
    up.reason = "unmatched, bridged to the next frame: " + m.ransac.failure;
    unmatched_frame_ = cur;
    return up;
  } else if (navStream()) {
    // A nav stream whose reading is refused or missing beyond the bridged frames: the piece ends
    // (the tracking loss a run without nav makes; loops rejoin it). Reusing the previous motion
    // here would extrapolate across whatever the vehicle did (a turn the nav's refused reading
    // saw), and the nav's later motions would be chained onto that wrong pose for good.
    unmatchedFrame(&up);
    ++stats_.nav_losses;
    up.nav_loss = true;
    up.reason = "no visual motion and no usable nav reading for " + std::to_string(unmatched_) +
                " frames: tracking lost (" + m.ransac.failure + ")";
    unmatched_frame_ = cur;
    return up;
  } else {
    // Reuse the previous frame-to-frame motion (paper §5), with a deliberately large covariance,
    // from the prediction of the frames bridged before (one step each, as many steps' variance).
    const int steps = unmatched_ > 0 && unmatched_ <= options_.fallback.bridge_frames ? unmatched_ + 1 : 1;
    cur.pose = compose(unmatched_ > 0 ? predicted_ : prev_.pose, last_step_);
    predicted_ = cur.pose;
    ++unmatched_;
    const FallbackOptions& f = options_.fallback;
    const double sxy = std::max(f.min_sigma_m, f.relative_sigma * last_step_.translation().norm());
    const Eigen::Matrix3d cov =
        steps * Eigen::Vector3d(sxy * sxy, sxy * sxy, f.sigma_yaw_rad * f.sigma_yaw_rad).asDiagonal().toDenseMatrix();
    addKeyframe(cur, UncertainPose2(between(last_kf_.pose, cur.pose), cov), true);
    up.covariance = last_kf_covariance_;
    ++stats_.fallbacks;
    up.status = FrameStatus::kFallback;
    up.source = MotionSource::kFallback;
    up.reason = m.ransac.failure;
    up.keyframe_id = static_cast<int>(keyframes_.size()) - 1;
  }
  up.pose = cur.pose;
  finishFrame(&cur, up);
  return up;
}

void Odometry::finishFrame(TrackedFrame* cur, const OdometryUpdate& up) {
  if (up.status != FrameStatus::kFallback) unmatched_ = 0;  // matched (or carried by the nav) again
  unmatched_frame_.reset();  // this frame is in the session (matched, carried or a reused motion)
  cur->match = {up.matches, up.inliers, up.overlap, up.scale};
  if (!keyframes_.empty() && keyframes_.back().frame_index == cur->index && !keyframes_.back().fallback)
    keyframes_.back().match = cur->match;
  prev_ = *cur;
}

}  // namespace core
}  // namespace uw_multislam
