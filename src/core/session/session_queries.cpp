#include "uw_multislam/core/session/session_queries.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <utility>

#include "session_detail.h"
#include "uw_multislam/core/store/interrupted_run.h"

namespace uw_multislam {
namespace core {

using namespace session_detail;  // NOLINT: the manager's own helpers

std::string SessionQueries::storeName() const {
  return std::filesystem::path(t_.options().store_path).filename().string();
}

HashSettings SessionQueries::hashSettings() const {
  const SessionManagerOptions& o = t_.options();
  return {o.hash_mode, o.projection_seed, o.num_features, t_.hasher().projections().toText(), o.features};
}

std::vector<int> SessionQueries::sessionIds() const {
  std::vector<int> ids;
  for (const auto& [id, s] : t_.sessions()) ids.push_back(id);
  return ids;
}

std::vector<int> SessionQueries::storedSessionsOf(const std::vector<FrameRecord>& frames) const {
  std::vector<int> ids;
  for (const auto& [id, s] : t_.sessions())
    if (restored(id) && keyframesAreFramesOf(s.frames, s.stamps, frames)) ids.push_back(id);
  return ids;
}

int SessionQueries::mapOf(int session) const { return t_.idOfBackend(t_.backend().mapOf(t_.at(session).backend())); }

std::vector<int> SessionQueries::mapIds() const {
  std::vector<int> ids;
  for (int m : t_.backend().mapIds()) ids.push_back(t_.idOfBackend(m));
  return ids;
}

std::vector<PriorRecord> SessionQueries::positionPriors() const {
  std::vector<PriorRecord> out = t_.backend().priors();
  for (PriorRecord& p : out) p.session = t_.idOfBackend(p.session);
  return out;
}

std::vector<Pose2> SessionQueries::poses(int session) const {
  return t_.backend().sessionPoses(t_.at(session).backend());
}

std::vector<Pose2> SessionQueries::posesInSessionFrame(int session) const {
  std::vector<Pose2> p = poses(session);
  const Pose2 origin_inv = invert(p.front());
  for (Pose2& x : p) x = compose(origin_inv, x);
  return p;
}

UncertainPose2 SessionQueries::lastKeyframeInMap(int session) const {
  const SessionTable::Session& s = t_.at(session);
  return t_.backend().keyframeInMap(s.backend(), static_cast<int>(s.stamps.size()) - 1);
}

UncertainPose2 SessionQueries::keyframeInMap(int session, int keyframe) const {
  return t_.backend().keyframeInMap(t_.at(session).backend(), keyframe);
}

UncertainPose2 SessionQueries::keyframeChain(int session, int from, int to) const {
  return t_.backend().keyframeChain(t_.at(session).backend(), from, to);
}

Pose2 SessionQueries::correction(int session) const {
  const SessionTable::Session& s = t_.at(session);
  return compose(t_.backend().sessionPoses(s.backend()).back(), invert(s.odometry.back()));
}

std::optional<SessionQueries::Relocalisation> SessionQueries::relocalise(int session) const {
  if (!has(session) || !t_.at(session).origin_received) return std::nullopt;
  const SessionTable::Session& s = t_.at(session);
  const auto r = t_.backend().relocalise(s.backend(), [this](int map) {
    for (int b : t_.backend().chain(map))
      if (restored(t_.idOfBackend(b))) return true;
    return false;
  });
  if (!r) return std::nullopt;
  Relocalisation out;
  out.map = t_.idOfBackend(r->map);
  out.loops = r->loops;
  out.inliers = r->inliers;
  out.keyframe = r->keyframe;
  out.pose = r->pose;
  out.correction = compose(r->origin.mean, correction(session));
  return out;
}

std::vector<SessionLink> SessionQueries::links() const {
  std::vector<SessionLink> out;
  for (int m : t_.backend().mapIds())
    for (const LinkInfo& l : t_.backend().links(m))
      out.push_back(
          {t_.idOfBackend(m), t_.idOfBackend(l.previous), t_.idOfBackend(l.current), l.loops, l.measured, l.estimate});
  return out;
}

std::vector<SessionSummary> SessionQueries::list() const {
  std::vector<SessionSummary> out;
  for (const auto& [id, s] : t_.sessions()) {
    SessionSummary x;
    x.id = id;
    x.name = s.name();
    const bool foreign_recording = !s.vehicle().empty() && foreignSession(s.vehicle(), s.remoteId()) == id;
    x.state = id == t_.active() || foreign_recording ? SessionState::kActive
              : s.unloaded                           ? SessionState::kUnloaded
                                                     : SessionState::kFinished;
    x.vehicle = s.vehicle();
    x.map = mapOf(id);
    x.keyframes = s.keyframes();
    x.loops = s.loops();
    x.first_stamp_s = s.stamps.front();
    x.last_stamp_s = s.stamps.back();
    out.push_back(x);
  }
  return out;
}

bool SessionQueries::loopRefused(std::size_t i) const {
  return i < loops().size() && t_.backend().loopRecord(static_cast<int>(i)).refused;
}

Status SessionQueries::checkLinkEnds(const Loop& l) const {
  for (int s : {l.session_a, l.session_b}) {
    if (!validSessionId(s)) return badSessionId("add_link", s);
    if (!has(s)) return notFound(s);
  }
  for (const auto& [s, k] : {std::pair<int, int>{l.session_a, l.keyframe_a}, {l.session_b, l.keyframe_b}}) {
    const int n = static_cast<int>(t_.at(s).stamps.size());
    if (k < 0) return {StatusCode::kInvalidArgument, "add_link: keyframe ids are >= 0"};
    if (k >= n)
      return {StatusCode::kNotFound, "add_link: session " + std::to_string(s) + " has no keyframe " +
                                         std::to_string(k) + " (it has " + std::to_string(n) + ")"};
    if (t_.at(s).phantoms.count(k))
      return {StatusCode::kFailedPrecondition, "add_link: keyframe " + std::to_string(k) + " of session " +
                                                   std::to_string(s) + " never arrived (bridged)"};
  }
  if (l.session_a == l.session_b && l.keyframe_a == l.keyframe_b)
    return {StatusCode::kInvalidArgument, "add_link: a keyframe cannot be linked to itself"};
  return Status::Ok();
}

Status SessionQueries::storedMapsMayChange(const std::string& what) const {
  if (!localising()) return Status::Ok();
  return {StatusCode::kFailedPrecondition,
          what + " is refused in localisation mode (no stored map changes): set_mode mapping first"};
}

namespace {
/// How far from its keyframe a camera sees the seabed: the half diagonal of its image on the
/// seabed (a 90 degree view for an unknown camera); 0 without an altitude.
double viewRadius(double altitude_m, const CameraIntrinsics& c) {
  const double altitude = std::isfinite(altitude_m) && altitude_m > 0.0 ? altitude_m : 0.0;
  if (c.unknown() || !(c.fx > 0.0) || !(c.fy > 0.0)) return altitude;
  return 0.5 * altitude * std::hypot(c.width / c.fx, c.height / c.fy);
}

std::string metres(double v) {
  char out[32];
  std::snprintf(out, sizeof out, "%.4g m", v);
  return out;
}
}  // namespace

double SessionQueries::mapExtent(int map) const {
  Eigen::Vector2d lo(0.0, 0.0), hi(0.0, 0.0);
  bool any = false;
  for (int b : t_.backend().chain(t_.at(map).backend()))
    for (const Pose2& p : t_.backend().sessionPoses(b)) {
      const Eigen::Vector2d x(p.x(), p.y());
      lo = any ? lo.cwiseMin(x) : x;
      hi = any ? hi.cwiseMax(x) : x;
      any = true;
    }
  return (hi - lo).norm();
}

double SessionQueries::linkReach(int session_a, int keyframe_a, int session_b, int keyframe_b, std::string* why) const {
  const int map_a = mapOf(session_a), map_b = mapOf(session_b);
  const double extent_a = mapExtent(map_a), extent_b = map_b == map_a ? 0.0 : mapExtent(map_b);
  const auto radius = [&](int s, int k) {
    const SessionTable::Session& x = t_.at(s);
    return viewRadius(k < static_cast<int>(x.altitudes.size()) ? x.altitudes[static_cast<std::size_t>(k)] : 0.0,
                      x.camera);
  };
  const double view = radius(session_a, keyframe_a) + radius(session_b, keyframe_b);
  if (why)
    *why = "map " + std::to_string(map_a) + "'s extent " + metres(extent_a) +
           (map_b == map_a ? std::string() : ", map " + std::to_string(map_b) + "'s " + metres(extent_b)) +
           ", and what the two cameras see around their keyframes, " + metres(view);
  return extent_a + extent_b + view;
}

Status SessionQueries::checkLink(const Loop& l) const {
  if (const Status ends = checkLinkEnds(l); !ends.ok()) return ends;
  if (const std::string bad = checkUncertainPose(l.z, true); !bad.empty())
    return {StatusCode::kInvalidArgument,
            "add_link: the pose: " + bad + " (x, y, yaw; m, rad; covariance m^2, rad^2, row-major)"};
  // Two keyframes a link joins see the same seabed, so they are no farther apart than the maps
  // that hold them reach (a 1,000 km link with a 1 cm sigma would drag a map across the sea).
  std::string terms;
  const double reach = linkReach(l.session_a, l.keyframe_a, l.session_b, l.keyframe_b, &terms);
  const double length = std::hypot(l.z.mean.x(), l.z.mean.y());
  if (length > reach)
    return {StatusCode::kInvalidArgument, "add_link: the link is " + metres(length) +
                                              " long, more than the maps can hold: at most " + metres(reach) + " (" +
                                              terms + ")"};
  if (l.inliers < 0) return {StatusCode::kInvalidArgument, "add_link: inliers must be >= 0"};
  // Inliers are matched features of both keyframes: no more than either keyframe has. Their stored
  // feature counts when both are in the store with features, else the extractor's cap
  // (num_features), which no keyframe of this configuration exceeds.
  int most = options().num_features;
  std::string bound = "num_features, the most features a keyframe has";
  if (l.inliers > 0 && l.inliers <= most && inStore(l.session_a, l.keyframe_a) && inStore(l.session_b, l.keyframe_b)) {
    try {
      const StoredKeyframe a = storedFeatures(l.session_a, l.keyframe_a);
      const StoredKeyframe b = storedFeatures(l.session_b, l.keyframe_b);
      // A keyframe stored without features (a sender that gives only poses) bounds nothing more.
      if (!a.points.empty() && !b.points.empty()) {
        most = static_cast<int>(std::min(a.points.size(), b.points.size()));
        bound = "the fewer features of the two keyframes";
      }
    } catch (const StoreError&) {  // unreadable: the cap still bounds it
    }
  }
  if (l.inliers > most)
    return {StatusCode::kInvalidArgument, "add_link: " + std::to_string(l.inliers) + " inliers is more than " +
                                              std::to_string(most) + " (" + bound + ")"};
  return storedMapsMayChange("add_link");
}

StoredKeyframe SessionQueries::storedFeatures(int session, int keyframe) const {
  if (!hasStore()) throw StoreError("no session store: no stored features");
  if (!has(session) || t_.at(session).storeRow() < 0 || !t_.keyframeStored(session, keyframe))
    throw StoreError("session store " + storePath() + ": keyframe " + std::to_string(keyframe) + " of session " +
                     std::to_string(session) + " is not stored");
  StoredKeyframe k = t_.store()->keyframeFeatures(t_.at(session).storeRow(), keyframe);
  k.session = session;
  return k;
}

std::vector<StoredKeyframe> SessionQueries::storedHashes(int session) const {
  if (!hasStore()) throw StoreError("no session store: no stored hashes");
  if (!has(session) || t_.at(session).storeRow() < 0 || !restored(session))
    throw StoreError("session store " + storePath() + ": session " + std::to_string(session) +
                     " is not a stored session");
  std::vector<StoredKeyframe> out =
      t_.store()->keyframes(t_.at(session).storeRow(), SessionStore::KeyframeColumns::kHash);
  for (StoredKeyframe& k : out) k.session = session;
  return out;
}

}  // namespace core
}  // namespace uw_multislam
