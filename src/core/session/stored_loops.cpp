#include "uw_multislam/core/session/stored_loops.h"

#include <cmath>
#include <deque>
#include <set>
#include <stdexcept>
#include <tuple>

#include "uw_multislam/core/loops/loop_detector.h"

namespace uw_multislam {
namespace core {

StoredLoopSearch searchStoredLoops(SessionManager* manager, const SlamConfig& config,
                                   const std::vector<std::vector<int>>& groups,
                                   const std::function<void(const std::string&)>& log) {
  auto say = [&](const std::string& line) {
    if (log) log(line);
  };
  std::set<int> named;
  for (const std::vector<int>& g : groups)
    for (int s : g) {
      if (!manager->view().restored(s))
        throw std::invalid_argument("session " + std::to_string(s) + " is not a stored session");
      if (!named.insert(s).second) throw std::invalid_argument("session " + std::to_string(s) + " is named twice");
    }
  // The pairs the manager holds already (either direction): a stored session recorded after
  // another found its loops against it then.
  std::set<std::tuple<int, int, int, int>> held;
  for (const Loop& l : manager->view().loops()) {
    held.emplace(l.session_a, l.keyframe_a, l.session_b, l.keyframe_b);
    held.emplace(l.session_b, l.keyframe_b, l.session_a, l.keyframe_a);
  }
  StoredLoopSearch r;
  LoopDetector detector(config.loops, config.odometry.matching, config.odometry.ransac,
                        config.odometry.features.num_features);
  detector.setFeatureLoader(
      [manager](int session, int keyframe) { return manager->view().storedFeatures(session, keyframe).features(); });
  std::deque<CameraIntrinsics> cameras;  // the detector keeps pointers: never moved
  for (std::size_t g = 0; g < groups.size(); ++g) {
    std::vector<std::pair<int, std::vector<StoredKeyframe>>> group;
    for (int s : groups[g]) {
      cameras.push_back(manager->view().camera(s));
      group.emplace_back(s, manager->view().storedHashes(s));
    }
    const std::size_t first_camera = cameras.size() - group.size();
    for (std::size_t i = 0; i < group.size() && g > 0; ++i) {
      const int session = group[i].first;
      for (const StoredKeyframe& kf : group[i].second) {
        const std::vector<HashCandidate> candidates = detector.globalCandidates(kf.hash, session);
        ++r.queries;
        if (candidates.empty()) continue;
        FrameFeatures now = manager->view().storedFeatures(session, kf.keyframe).features();
        now.descriptors = extractorDescriptors(now.descriptors);  // as the extractor gives them
        const View view{&now, kf.altitude_m, &cameras[first_camera + i]};
        for (const HashCandidate& candidate : candidates) {
          ++r.candidates;
          Loop loop;
          if (!detector.verifyCandidate(candidate, view, &loop)) continue;
          loop.session_b = session;
          loop.keyframe_b = kf.keyframe;
          loop.frame_b = kf.frame_index;
          ++r.found;
          if (held.count({loop.session_a, loop.keyframe_a, loop.session_b, loop.keyframe_b})) {
            ++r.duplicates;
            continue;
          }
          const Status st = manager->addLoop(loop);
          if (st.ok()) {
            ++r.accepted;
            held.emplace(loop.session_a, loop.keyframe_a, loop.session_b, loop.keyframe_b);
            held.emplace(loop.session_b, loop.keyframe_b, loop.session_a, loop.keyframe_a);
          } else {
            ++r.refused;
            say("loop " + std::to_string(loop.session_a) + ":" + std::to_string(loop.keyframe_a) + " -> " +
                std::to_string(session) + ":" + std::to_string(kf.keyframe) + " refused: " + st.message);
          }
        }
        if (detector.stats().feature_read_failures > 0)
          throw StoreError("stored keyframes could not be read back: " + detector.lastReadError());
      }
    }
    for (std::size_t i = 0; i < group.size(); ++i)
      for (const StoredKeyframe& kf : group[i].second)
        detector.addPagedKeyframe(group[i].first, kf.keyframe, kf.frame_index, kf.altitude_m,
                                  &cameras[first_camera + i], kf.hash);
  }
  return r;
}

Status findStoredLink(const SessionQueries& manager, const SlamConfig& config, Loop* link) {
  if (!manager.hasStore()) return {StatusCode::kFailedPrecondition, "add_link find: no session store"};
  if (const Status mode = manager.storedMapsMayChange("add_link"); !mode.ok()) return mode;
  const Loop& l = *link;
  if (const Status ends = manager.checkLinkEnds(l); !ends.ok()) return ends;
  // The features come from the store: a restored session's, or this run's as written with each
  // keyframe (the loop detector node holds them too, but the back-end does not ask it).
  for (const auto& [s, k] : {std::pair<int, int>{l.session_a, l.keyframe_a}, {l.session_b, l.keyframe_b}}) {
    if (!manager.inStore(s, k))
      return {StatusCode::kFailedPrecondition,
              "add_link find: keyframe " + std::to_string(k) + " of session " + std::to_string(s) +
                  " is not in the store (localisation mode keeps it in memory only, or its write failed): "
                  "give the pose"};
  }
  StoredKeyframe a, b;
  try {
    a = manager.storedFeatures(l.session_a, l.keyframe_a);
    b = manager.storedFeatures(l.session_b, l.keyframe_b);
  } catch (const StoreError& e) {
    return {StatusCode::kDataLoss, std::string("add_link find: ") + e.what()};
  }
  FrameFeatures fa = a.features(), fb = b.features();
  fa.descriptors = extractorDescriptors(fa.descriptors);  // as the extractor gives them
  fb.descriptors = extractorDescriptors(fb.descriptors);
  const CameraIntrinsics& ca = manager.camera(l.session_a);
  const CameraIntrinsics& cb = manager.camera(l.session_b);
  const PairMotion m = estimatePairMotion({&fa, a.altitude_m, &ca}, {&fb, b.altitude_m, &cb}, config.odometry.matching,
                                          config.odometry.ransac);
  const int needed = l.session_a == l.session_b ? config.loops.local.min_inliers : config.loops.global.min_inliers;
  const int inliers = m.ransac.success ? static_cast<int>(m.ransac.inliers.size()) : 0;
  if (inliers < needed)
    return {StatusCode::kFailedPrecondition,
            "add_link find: no motion verified between " + std::to_string(l.session_a) + ":" +
                std::to_string(l.keyframe_a) + " and " + std::to_string(l.session_b) + ":" +
                std::to_string(l.keyframe_b) + " (" + std::to_string(m.matches) + " matches, " +
                std::to_string(inliers) + " inliers, " + std::to_string(needed) + " needed): give the pose"};
  link->z = UncertainPose2(m.ransac.motion, m.ransac.covariance);
  link->inliers = inliers;
  return Status::Ok();
}

Status detectStoredLoops(SessionManager* manager, const SlamConfig& config, const std::vector<int>& sessions,
                         StoredLoopSearch* out, const std::function<void(const std::string&)>& log) {
  *out = StoredLoopSearch();
  if (sessions.size() < 2)
    return {StatusCode::kInvalidArgument, "detect_loops needs two or more stored sessions (list_sessions ids)"};
  if (!manager->view().hasStore()) return {StatusCode::kFailedPrecondition, "detect_loops: no session store"};
  if (const Status mode = manager->view().storedMapsMayChange("detect_loops"); !mode.ok()) return mode;
  std::set<int> seen;
  for (int s : sessions) {
    if (!seen.insert(s).second)
      return {StatusCode::kInvalidArgument, "detect_loops names session " + std::to_string(s) + " twice"};
    if (!manager->view().has(s))
      return {StatusCode::kNotFound,
              "detect_loops: no session " + std::to_string(s) + " (call list_sessions for the ids)"};
    if (!manager->view().restored(s))
      return {StatusCode::kFailedPrecondition, "detect_loops: session " + std::to_string(s) +
                                                   " was recorded in this run (its loops were searched live); "
                                                   "only sessions restored from the store are searched"};
  }
  std::vector<std::vector<int>> groups;
  for (int s : sessions) groups.push_back({s});
  const int loops_before = static_cast<int>(manager->view().loops().size());
  try {
    *out = searchStoredLoops(manager, config, groups, log);
  } catch (const StoreError& e) {
    out->accepted = static_cast<int>(manager->view().loops().size()) - loops_before;
    return {StatusCode::kDataLoss, std::string("detect_loops: ") + e.what()};
  }
  return Status::Ok();
}

Status checkOperatorLink(const SessionQueries& manager, const SlamConfig& config, bool measure, Loop* link,
                         double given_yaw) {
  if (measure) return findStoredLink(manager, config, link);
  // The yaw as given, before Pose2 wrapped it (1e9 rad had gone in as 0.577 rad): an angle out of
  // range is a wrong unit or a typo, not a turn.
  if (!(std::abs(given_yaw) <= M_PI))
    return {StatusCode::kInvalidArgument,
            "add_link: yaw " + std::to_string(given_yaw) + " rad is outside [-pi, pi] (radians, not degrees)"};
  return manager.checkLink(*link);
}

Status addOperatorLink(SessionManager* manager, const SlamConfig& config, bool measure, Loop* link, double given_yaw) {
  if (const Status st = checkOperatorLink(manager->view(), config, measure, link, given_yaw); !st.ok()) return st;
  return manager->addLink(*link);
}

}  // namespace core
}  // namespace uw_multislam
