#include "uw_multislam/core/loops/loop_detector.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace uw_multislam {
namespace core {

std::string LocalLoopOptions::validate() const {
  std::ostringstream os;
  if (!(radius_m > 0) || !(max_radius_m >= radius_m)) {
    os << "radius_m must be positive and max_radius_m >= radius_m";
  } else if (!(sigma_widening >= 0)) {
    os << "sigma_widening must be >= 0";
  } else if (exclude_recent < 1 || max_candidates < 1 || min_inliers < 3) {
    os << "exclude_recent >= 1, max_candidates >= 1 and min_inliers >= 3 are required";
  }
  return os.str();
}

std::string GlobalLoopOptions::validate() const {
  std::ostringstream os;
  if (best_k < 1 || best_k > 100) {
    os << "best_k must be in [1, 100]";
  } else if (!(max_l1 >= 0)) {
    os << "max_l1 must be >= 0 (0 = no threshold)";
  } else if (min_inliers < 3) {
    os << "min_inliers must be >= 3";
  }
  return os.str();
}

std::string LoopOptions::validate() const {
  std::string bad = local.validate();
  if (!bad.empty()) return "local: " + bad;
  bad = global.validate();
  if (!bad.empty()) return "global: " + bad;
  if (!(ratio > 0.0 && ratio <= 1.0)) return "ratio must be in (0, 1]";
  if (!(feature_cache_mb >= 0) || feature_cache_mb > 1e6) return "feature_cache_mb must be in [0, 1e6] (MiB)";
  if (page_live_after < 0) return "page_live_after must be >= 0 (0: never)";
  return {};
}

std::string loopKindName(Loop::Kind k) { return k == Loop::Kind::kLocal ? "local" : "global"; }

MatchOptions loopMatching(const MatchOptions& odometry, const LoopOptions& loops) {
  MatchOptions m = odometry;
  m.ratio = loops.ratio;
  return m;
}

namespace {
const LoopOptions& checked(const LoopOptions& o) {
  const std::string bad = o.validate();
  if (!bad.empty()) throw std::invalid_argument("loops: " + bad);
  return o;
}
}  // namespace

LoopDetector::LoopDetector(const LoopOptions& options, const MatchOptions& matching, const RansacOptions& ransac,
                           int num_features)
    : options_(checked(options)),
      matching_(loopMatching(matching, options)),
      ransac_(ransac),
      hasher_(options.global.hash_mode, num_features, options.global.projection_seed),
      hashes_(hashCodeRange(options.global.hash_mode)) {}

namespace {
// A held (byte) copy of features as the extractor gives them, for matching.
FrameFeatures forMatching(const FrameFeatures& held) {
  FrameFeatures f;
  f.keypoints = held.keypoints;
  f.image_size = held.image_size;
  f.descriptors = extractorDescriptors(held.descriptors);
  return f;
}
}  // namespace

bool LoopDetector::verify(const Stored& old, const View& now, Loop* loop) {
  const FrameFeatures* stored = &old.features;
  std::shared_ptr<const FrameFeatures> paged;
  if (old.paged) {
    try {
      ScopedStage s(&times_, "feature_read");
      paged = cache_->get(old.session, old.keyframe);
    } catch (const std::exception& e) {
      ++stats_.feature_read_failures;
      last_read_error_ = e.what();
      return false;
    }
    stored = paged.get();
  }
  const FrameFeatures f = forMatching(*stored);
  if (!f.descriptors.empty() && !now.features->descriptors.empty() &&
      descriptorType(f.descriptors) != descriptorType(now.features->descriptors)) {
    // Another feature kind (another vehicle's configuration): not comparable, counted as unread.
    ++stats_.feature_read_failures;
    last_read_error_ = "keyframe " + std::to_string(old.keyframe) + " of session " + std::to_string(old.session) +
                       " has " + featureTypeName(descriptorType(f.descriptors)) + " features, this keyframe " +
                       featureTypeName(descriptorType(now.features->descriptors));
    return false;
  }
  const PairMotion m = estimatePairMotion({&f, old.altitude_m, old.camera}, now, matching_, ransac_, &times_);
  const int needed = loop->kind == Loop::Kind::kLocal ? options_.local.min_inliers : options_.global.min_inliers;
  if (!m.ransac.success || static_cast<int>(m.ransac.inliers.size()) < needed) return false;
  loop->session_a = old.session;
  loop->keyframe_a = old.keyframe;
  loop->frame_a = old.frame_index;
  loop->z = UncertainPose2(m.ransac.motion, m.ransac.covariance);
  loop->inliers = static_cast<int>(m.ransac.inliers.size());
  return true;
}

std::vector<int> LoopDetector::localCandidates(int session, int keyframe, const Trajectory& t) const {
  std::vector<std::pair<double, int>> near;
  if (session >= static_cast<int>(by_session_.size())) return {};
  const auto& mine = by_session_[session];
  const int newest = keyframe - options_.local.exclude_recent - 1;
  if (newest < 0) return {};
  const Pose2& now = t.absolutePose(keyframe);
  // X_t^i with its covariance, built backwards: X_t^i = X_{i+1}^i ⊕ X_t^{i+1}. Its position
  // variance includes the heading uncertainty times the lever arm, which dominates after turns
  // and odometry fallbacks. O(1) per step.
  UncertainPose2 rel = UncertainPose2::exact(Pose2());
  for (int i = keyframe - 1; i >= 0; --i) {
    rel = compose(t.motion(i + 1), rel);
    if (i > newest || i >= static_cast<int>(mine.size()) || mine[i] < 0) continue;
    const double sigma = std::sqrt(std::max(0.0, rel.covariance.topLeftCorner<2, 2>().trace()));
    const double radius =
        std::min(options_.local.max_radius_m, options_.local.radius_m + options_.local.sigma_widening * sigma);
    const double d = (t.absolutePose(i).translation() - now.translation()).norm();
    if (d <= radius) near.push_back({d, mine[i]});
  }
  std::sort(near.begin(), near.end());
  std::vector<int> out;
  for (std::size_t i = 0; i < near.size() && static_cast<int>(i) < options_.local.max_candidates; ++i) {
    out.push_back(near[i].second);
  }
  return out;
}

std::vector<Loop> LoopDetector::addKeyframe(int session, int keyframe, int frame_index, double altitude_m,
                                            const CameraIntrinsics* camera, const FrameFeatures& features,
                                            const Trajectory& trajectory, const Eigen::VectorXf* given_hash) {
  if (session < 0 || keyframe < 0 || keyframe >= static_cast<int>(trajectory.numKeyframes())) {
    throw std::invalid_argument("loops: keyframe " + std::to_string(keyframe) + " of session " +
                                std::to_string(session) + " is not in its trajectory");
  }
  ++stats_.keyframes;
  std::vector<Loop> loops;
  const View now{&features, altitude_m, camera};
  Eigen::VectorXf hash;
  if (given_hash && given_hash->size() == HalocProjections::kHashSize) {
    hash = *given_hash;
  } else {
    ScopedStage s(&times_, "hash");
    hash = hasher_.hash(features.descriptors);
  }
  if (options_.local.enabled) {
    std::vector<int> candidates;
    {
      ScopedStage s(&times_, "local_candidates");
      candidates = localCandidates(session, keyframe, trajectory);
    }
    ScopedStage s(&times_, "local_verify");
    for (int c : candidates) {
      ++stats_.local_candidates;
      Loop l;
      l.kind = Loop::Kind::kLocal;
      if (verify(keyframes_[c], now, &l)) loops.push_back(l);
    }
  }
  if (queryGlobal(hash, session)) verifyGlobal(now, &loops);
  if (options_.global.enabled && options_.global.follow_loops) {
    ScopedStage s(&times_, "global_follow");
    followLoops(session, keyframe, trajectory, now, &loops);
  }
  nameNewKeyframe(&loops, session, keyframe, frame_index);

  // Store the keyframe for later queries, with its pose for the other sessions' followed loops.
  last_hash_ = hash;
  store(session, keyframe, frame_index, altitude_m, camera, &features, hash);
  keyframes_.back().has_pose = true;
  keyframes_.back().pose = trajectory.absolutePose(keyframe);
  return loops;
}

void LoopDetector::followLoops(int session, int keyframe, const Trajectory& t, const View& now,
                               std::vector<Loop>* loops) {
  const LocalLoopOptions& radius = options_.local;
  const Pose2& here = t.absolutePose(keyframe);
  // This keyframe's place in each other session by its best global loop there (most inliers).
  const auto placed = [&]() {
    std::map<int, Pose2> out;
    std::map<int, int> inliers;
    for (const Loop& l : *loops) {
      if (l.kind != Loop::Kind::kGlobal || !has(l.session_a, l.keyframe_a)) continue;
      const Stored& a = keyframes_[by_session_[l.session_a][l.keyframe_a]];
      if (!a.has_pose || (inliers.count(l.session_a) && inliers[l.session_a] >= l.inliers)) continue;
      inliers[l.session_a] = l.inliers;
      out[l.session_a] = compose(a.pose, l.z.mean);
    }
    return out;
  };
  // Per other session: the predicted pose of this keyframe in its frame and the search radius.
  std::map<int, std::pair<Pose2, double>> predicted;
  for (const auto& [other, at] : placed()) predicted[other] = {at, radius.radius_m};
  for (auto it = anchors_.begin(); it != anchors_.end();) {
    const int other = it->first.second;
    if (it->first.first != session || predicted.count(other)) {
      ++it;
      continue;
    }
    // The odometry from the anchor keyframe to this one, with its uncertainty (as localCandidates).
    const Anchor& anchor = it->second;
    UncertainPose2 rel = UncertainPose2::exact(Pose2());
    for (int i = anchor.keyframe + 1; i <= keyframe && i < static_cast<int>(t.numKeyframes()); ++i)
      rel = compose(rel, t.motion(i));
    const double sigma = std::sqrt(std::max(0.0, rel.covariance.topLeftCorner<2, 2>().trace()));
    const double r = radius.radius_m + radius.sigma_widening * sigma;
    if (r >= radius.max_radius_m) {
      it = anchors_.erase(it);  // the prediction says no more than the radius: the anchor is spent
      continue;
    }
    predicted[other] = {compose(anchor.in_other, between(t.absolutePose(anchor.keyframe), here)), r};
    ++it;
  }
  std::vector<int> verified;  // entries this keyframe was already verified against
  for (const HashCandidate& c : scratch_) verified.push_back(c.entry);
  for (const auto& [other, place] : predicted) {
    if (other < 0 || other >= static_cast<int>(by_session_.size())) continue;
    std::vector<std::pair<double, int>> near;
    for (const int entry : by_session_[other]) {
      if (entry < 0 || !keyframes_[entry].has_pose) continue;
      if (std::find(verified.begin(), verified.end(), entry) != verified.end()) continue;
      bool looped = false;
      for (const Loop& l : *loops)
        looped = looped || (l.session_a == other && l.keyframe_a == keyframes_[entry].keyframe);
      if (looped) continue;
      const double d = (keyframes_[entry].pose.translation() - place.first.translation()).norm();
      if (d <= place.second) near.push_back({d, entry});
    }
    std::sort(near.begin(), near.end());
    if (static_cast<int>(near.size()) > radius.max_candidates) near.resize(radius.max_candidates);
    for (const auto& [d, entry] : near) {
      ++stats_.global_candidates;
      ++stats_.followed_candidates;
      Loop l;
      l.kind = Loop::Kind::kGlobal;
      if (!verify(keyframes_[entry], now, &l)) continue;
      // A loop that puts the keyframe far from where it was looked for is not the revisit followed.
      const Pose2 at = compose(keyframes_[entry].pose, l.z.mean);
      if ((at.translation() - place.first.translation()).norm() > place.second) continue;
      ++stats_.followed_accepted;
      loops->push_back(l);
    }
  }
  for (const auto& [other, at] : placed()) anchors_[{session, other}] = {keyframe, at};
}

bool LoopDetector::queryGlobal(const Eigen::VectorXf& hash, int session) {
  if (!options_.global.enabled || hashes_.size() == 0) return false;
  ScopedStage s(&times_, "hash_query");
  return !globalCandidates(hash, session).empty();
}

void LoopDetector::verifyGlobal(const View& now, std::vector<Loop>* loops) {
  ScopedStage s(&times_, "global_verify");
  for (const HashCandidate& c : scratch_) {
    ++stats_.global_candidates;
    Loop l;
    if (verifyCandidate(c, now, &l)) loops->push_back(l);
  }
}

void LoopDetector::nameNewKeyframe(std::vector<Loop>* loops, int session, int keyframe, int frame_index) {
  for (Loop& l : *loops) {
    l.session_b = session;
    l.keyframe_b = keyframe;
    l.frame_b = frame_index;
    (l.kind == Loop::Kind::kLocal ? stats_.local_accepted : stats_.global_accepted) += 1;
  }
}

const std::vector<HashCandidate>& LoopDetector::globalCandidates(const Eigen::VectorXf& hash, int session) {
  const float max_l1 =
      options_.global.max_l1 > 0 ? static_cast<float>(options_.global.max_l1) : std::numeric_limits<float>::infinity();
  hashes_.query(hash, session, options_.global.best_k, max_l1, &scratch_);
  return scratch_;
}

bool LoopDetector::verifyCandidate(const HashCandidate& candidate, const View& now, Loop* loop) {
  if (candidate.entry < 0 || candidate.entry >= static_cast<int>(keyframes_.size()))
    throw std::invalid_argument("loops: candidate " + std::to_string(candidate.entry) + " is not a stored keyframe");
  loop->kind = Loop::Kind::kGlobal;
  loop->hash_l1 = candidate.l1;
  return verify(keyframes_[candidate.entry], now, loop);
}

void LoopDetector::addStoredKeyframe(int session, int keyframe, int frame_index, double altitude_m,
                                     const CameraIntrinsics* camera, const FrameFeatures& features,
                                     const Eigen::VectorXf& hash) {
  checkStored(session, keyframe, hash);
  store(session, keyframe, frame_index, altitude_m, camera, &features, hash);
}

int LoopDetector::dropSession(int session) {
  if (cache_) cache_->eraseSession(session);
  for (auto it = anchors_.begin(); it != anchors_.end();)
    it = (it->first.first == session || it->first.second == session) ? anchors_.erase(it) : std::next(it);
  const int removed = hashes_.removeSession(session);
  // keyframes_[i] <-> hash entry i: remove the same entries, then index the rest again.
  keyframes_.erase(
      std::remove_if(keyframes_.begin(), keyframes_.end(), [session](const Stored& k) { return k.session == session; }),
      keyframes_.end());
  keyframes_.shrink_to_fit();
  if (static_cast<int>(keyframes_.size()) != static_cast<int>(hashes_.size()))
    throw std::logic_error("loops: keyframes and hashes drifted apart");
  for (std::vector<int>& ids : by_session_) std::fill(ids.begin(), ids.end(), -1);
  if (session >= 0 && session < static_cast<int>(by_session_.size())) std::vector<int>().swap(by_session_[session]);
  for (std::size_t i = 0; i < keyframes_.size(); ++i)
    by_session_[keyframes_[i].session][keyframes_[i].keyframe] = static_cast<int>(i);
  return removed;
}

void LoopDetector::setFeatureLoader(FeatureCache::Loader loader) {
  cache_ = std::make_unique<FeatureCache>(static_cast<std::size_t>(options_.feature_cache_mb * 1024.0 * 1024.0),
                                          std::move(loader));
}

void LoopDetector::addPagedKeyframe(int session, int keyframe, int frame_index, double altitude_m,
                                    const CameraIntrinsics* camera, const Eigen::VectorXf& hash) {
  if (!cache_) throw std::invalid_argument("loops: a paged keyframe needs setFeatureLoader first");
  checkStored(session, keyframe, hash);
  store(session, keyframe, frame_index, altitude_m, camera, nullptr, hash);
}

std::vector<Loop> LoopDetector::addForeignKeyframe(int session, int keyframe, int frame_index, double altitude_m,
                                                   const CameraIntrinsics* camera, const Eigen::VectorXf& hash) {
  if (!cache_) throw std::invalid_argument("loops: another vehicle's keyframe needs setFeatureLoader first");
  checkStored(session, keyframe, hash);
  ++stats_.keyframes;
  std::vector<Loop> loops;
  if (queryGlobal(hash, session)) {
    // Its features cross the link only now, for a keyframe with candidates (and stay in the
    // cache: this vehicle's keyframes that find it later read them from there).
    std::shared_ptr<const FrameFeatures> theirs;
    try {
      ScopedStage s(&times_, "feature_read");
      theirs = cache_->get(session, keyframe);
    } catch (const std::exception& e) {
      ++stats_.feature_read_failures;
      last_read_error_ = e.what();
    }
    if (theirs) {
      const FrameFeatures f = forMatching(*theirs);
      verifyGlobal({&f, altitude_m, camera}, &loops);
    }
  }
  nameNewKeyframe(&loops, session, keyframe, frame_index);
  store(session, keyframe, frame_index, altitude_m, camera, nullptr, hash);
  return loops;
}

bool LoopDetector::pageOut(int session, int keyframe) {
  if (!cache_ || !has(session, keyframe)) return false;
  Stored& k = keyframes_[by_session_[session][keyframe]];
  if (k.paged) return false;
  k.features = FrameFeatures();  // its keypoints and descriptors freed
  k.paged = true;
  return true;
}

void LoopDetector::checkStored(int session, int keyframe, const Eigen::VectorXf& hash) const {
  if (hash.size() != HalocProjections::kHashSize)
    throw std::invalid_argument("loops: stored keyframe " + std::to_string(keyframe) + " of session " +
                                std::to_string(session) + ": hash of " + std::to_string(hash.size()) + " values, " +
                                std::to_string(HalocProjections::kHashSize) + " expected");
  if (session < 0 || keyframe < 0 ||
      (session < static_cast<int>(by_session_.size()) && keyframe < static_cast<int>(by_session_[session].size()) &&
       by_session_[session][keyframe] >= 0))
    throw std::invalid_argument("loops: stored keyframe " + std::to_string(keyframe) + " of session " +
                                std::to_string(session) + " is already there");
}

void LoopDetector::store(int session, int keyframe, int frame_index, double altitude_m, const CameraIntrinsics* camera,
                         const FrameFeatures* features, const Eigen::VectorXf& hash) {
  Stored st{session, keyframe, frame_index, altitude_m, camera, FrameFeatures(), features == nullptr, false, Pose2()};
  if (features) {
    st.features.keypoints = features->keypoints;
    st.features.image_size = features->image_size;
    features->descriptors.convertTo(st.features.descriptors, CV_8U);
  }
  const int index = static_cast<int>(keyframes_.size());
  hashes_.add({session, keyframe}, hash);  // first: it throws on a bad hash, and the two must stay parallel
  keyframes_.push_back(std::move(st));
  if (session >= static_cast<int>(by_session_.size())) by_session_.resize(session + 1);
  auto& mine = by_session_[session];
  if (keyframe >= static_cast<int>(mine.size())) mine.resize(keyframe + 1, -1);
  mine[keyframe] = index;
}

}  // namespace core
}  // namespace uw_multislam
