// The session manager's keyframes, loops and links: stored as they arrive, then into the back-end.
#include "uw_multislam/core/session/session_manager.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <utility>

#include "session_detail.h"

namespace uw_multislam {
namespace core {

using namespace session_detail;  // NOLINT: the manager's own helpers

namespace {
/// While alive, afterBackendChange leaves the map changes to the caller (hold_changes_), so an
/// audit-trail line goes in before the join it brings about; released also when a call throws.
class HeldChanges {
 public:
  explicit HeldChanges(bool* flag) : flag_(flag) { *flag_ = true; }
  ~HeldChanges() { *flag_ = false; }
  HeldChanges(const HeldChanges&) = delete;
  HeldChanges& operator=(const HeldChanges&) = delete;

 private:
  bool* flag_;
};
}  // namespace

void SessionManager::addStoreRow(Session& s, double stamp_s) {
  // Its row takes the session's id: a session's id is its store id for life.
  s.store_id = store_->addSession(s.name, s.camera, stamp_s, idOfBackend(s.backend));
  if (!s.vehicle.empty()) {  // another vehicle's: where it came from, as merge_stores records it
    SessionProvenance p;
    p.session = s.store_id;
    p.source_file = "fleet:" + s.vehicle;
    p.source_session = s.remote_id;
    p.source_name = s.name;
    p.vehicle = s.vehicle;
    store_->addProvenance(p);
  }
}

void SessionManager::storeKeyframe(Session& s, const KeyframeInput* k, int keyframe, const UncertainPose2* motion,
                                   double stamp_s, const std::vector<Loop>* loops, std::vector<StoredLoop>* stored,
                                   int gap, const UncertainPose2* gap_motion) {
  if (!store_) return;
  if (localising_ && !s.memory_only) {
    s.memory_only = true;
    say("localisation mode: session " + std::to_string(idOfBackend(s.backend)) + " '" + s.name + "': keyframes from " +
        std::to_string(keyframe) + " on are kept in memory only (" + std::to_string(s.stored) + " stored)");
  }
  if (s.memory_only) return;
  if (s.store_cut || keyframe - gap != s.stored) {  // after a failed write: not stored, counted
    ++stats_.store_failures;
    return;
  }
  const bool ok = storeWrite("writing a keyframe", [&] {
    if (s.store_id < 0) {
      addStoreRow(s, stamp_s);  // the camera is known before a placeholder origin too
    } else if (keyframe == 0) {
      // A row made before the session's first keyframe (saveMaps after start_session) has no
      // camera yet (0x0): it gets the one the origin (or the placeholder origin) brought.
      store_->setSessionCamera(s.store_id, s.camera);
    }
    // The loops in store ids only now: a new session's row is made with its first keyframe, and
    // the loops that keyframe closed name it (they were stored with session -1 and lost at the
    // next restart when converted before the row existed).
    if (loops && stored) {
      stored->clear();
      for (const Loop& l : *loops) stored->push_back(toStored(l));
    }
    std::vector<StoredKeyframe> lost(static_cast<std::size_t>(gap));  // minimal rows (SessionStore::addKeyframe)
    for (int i = 0; i < gap; ++i) {
      lost[i].session = s.store_id;
      lost[i].keyframe = keyframe - gap + i;
      lost[i].stamp_s = stamp_s;
      lost[i].hash = Eigen::VectorXf::Zero(HalocProjections::kHashSize);
    }
    StoredKeyframe sk;
    sk.session = s.store_id;
    sk.keyframe = keyframe;
    sk.stamp_s = stamp_s;
    sk.hash = Eigen::VectorXf::Zero(HalocProjections::kHashSize);
    if (k) {  // else a keyframe that never arrived: no features
      sk.frame_index = k->frame_index;
      sk.altitude_m = k->altitude_m;
      sk.image_size =
          k->features.image_size.area() > 0 ? k->features.image_size : cv::Size(k->camera.width, k->camera.height);
      for (const cv::KeyPoint& p : k->features.keypoints) sk.points.push_back(p.pt);
      sk.descriptors = k->features.descriptors;
      if (k->hash.size() == HalocProjections::kHashSize) sk.hash = k->hash;
      sk.thumbnail = k->thumbnail;
      sk.motion_source = k->motion_source;
    }
    store_->addKeyframe(sk, motion, stored, lost, gap_motion);
  });
  if (ok) {
    s.stored += gap + 1;
    return;
  }
  s.store_cut = true;
  say("session store " + options_.store_path + ": session '" + s.name + "': keyframes from " +
      std::to_string(keyframe) + " on are not stored (each counted a store failure); the " + std::to_string(s.stored) +
      " stored before stay restorable");
}

Status SessionManager::addKeyframe(const KeyframeInput& input, const std::vector<Loop>& loops) {
  if (!validSessionId(input.session)) {
    ++stats_.keyframes_refused;
    return badSessionId("keyframe " + std::to_string(input.keyframe), input.session);
  }
  if (input.keyframe < 0) {
    ++stats_.keyframes_refused;
    return {StatusCode::kInvalidArgument, "keyframe id " + std::to_string(input.keyframe) + " is negative"};
  }
  // The store keeps the session's camera (and refuses an unusable one): refused here, before it
  // could make the session's row, and with it every later save of the maps, fail.
  if (const std::string bad = unusableCamera(input.camera); !bad.empty()) {
    ++stats_.keyframes_refused;
    return {StatusCode::kInvalidArgument, "keyframe " + std::to_string(input.keyframe) + " of session " +
                                              std::to_string(input.session) + ": camera: " + bad};
  }
  KeyframeInput k = input;
  if (k.hash.size() != HalocProjections::kHashSize && !k.features.descriptors.empty())
    k.hash = hasher_.hash(k.features.descriptors);  // the one place a keyframe is hashed when nobody upstream did
  // The keyframe after a refused jump decides what the jump was.
  if (jump_) {
    KeyframeInput held = std::move(*jump_);
    jump_.reset();
    const long long step = static_cast<long long>(k.keyframe) - held.keyframe;
    if (held.session == k.session && step >= 1 && step <= options_.max_keyframe_gap + 1LL) {
      const Status st = startPiece(std::move(held));
      if (!st.ok()) return st;
    }
  }
  const auto piece_took =
      std::find_if(pieces_.begin(), pieces_.end(), [&](const Piece& p) { return p.to != p.from && p.to == k.session; });
  const bool renamed = std::any_of(pieces_.begin(), pieces_.end(), [&](const Piece& p) { return p.from == k.session; });
  if (piece_took != pieces_.end() && !renamed) {
    // The odometry's next session took the id a piece took (nobody told it the piece's), whether
    // that piece is still recording or finished: it is a session of its own, under the next free
    // id, its keyframe ids kept.
    const int id = nextId();
    if (id > kMaxSessionId) return badSessionId("keyframe " + std::to_string(k.keyframe), id);
    const int from = piece_took->from;
    if (const Status st = open(id, "", k.stamp_s); !st.ok()) return st;
    say("the odometry's session " + std::to_string(k.session) + " is session " + std::to_string(id) + " here (" +
        std::to_string(k.session) + " is the piece its session " + std::to_string(from) + " went on in)");
    pieces_.push_back({k.session, id, 0});
  }
  toPiece(&k.session, &k.keyframe);
  auto it = sessions_.find(k.session);
  if (it == sessions_.end()) {
    if (k.session < nextId()) {
      ++stats_.keyframes_stale;
      return {StatusCode::kFailedPrecondition, "keyframe of old session " + std::to_string(k.session) +
                                                   " skipped (session " + std::to_string(active_) + " is recording)"};
    }
    if (k.keyframe > options_.max_keyframe_gap) {
      const std::string why = "keyframe " + std::to_string(k.keyframe) + " starts session " +
                              std::to_string(k.session) + ": more than max_keyframe_gap (" +
                              std::to_string(options_.max_keyframe_gap) + ") keyframes missing";
      return refuseJump(std::move(k), why);
    }
    open(k.session, "", k.stamp_s);
    it = sessions_.find(k.session);
  }
  const int id = k.session;
  if (id != active_) {
    ++stats_.keyframes_stale;
    return {StatusCode::kFailedPrecondition, "keyframe of finished session " + std::to_string(id) + " skipped"};
  }
  if (pieces_.empty()) return appendKeyframe(std::move(k), loops);
  std::vector<Loop> named = loops;  // the odometry's ids after a jump, as this manager names them
  for (Loop& l : named) {
    toPiece(&l.session_a, &l.keyframe_a);
    toPiece(&l.session_b, &l.keyframe_b);
  }
  return appendKeyframe(std::move(k), named);
}

Status SessionManager::appendKeyframe(KeyframeInput k, const std::vector<Loop>& loops) {
  const int id = k.session;
  Session& s = at(id);
  const int expected = static_cast<int>(s.stamps.size());
  if (k.keyframe > expected && k.keyframe - expected > options_.max_keyframe_gap) {
    const std::string why = "keyframe " + std::to_string(k.keyframe) + " of session " + std::to_string(id) + ": " +
                            std::to_string(k.keyframe - expected) + " keyframes missing, more than max_keyframe_gap (" +
                            std::to_string(options_.max_keyframe_gap) + ")";
    return refuseJump(std::move(k), why);
  }
  UncertainPose2 motion = k.motion;
  const UncertainPose2* stored_motion = &motion;
  int gap = 0;  // keyframes lost just before this one
  const UncertainPose2 still(Pose2(), Eigen::Matrix3d::Identity() * 1e-8);
  if (!s.origin_received && k.keyframe == 0) {
    // The origin: the session's first keyframe, or fills in start_session's placeholder origin.
    s.origin_received = true;
    s.camera = k.camera;
    s.stamps[0] = k.stamp_s;
    s.frames[0] = k.frame_index;
    stored_motion = nullptr;
  } else {
    if (!s.origin_received) {  // keyframe 0 never arrived: a placeholder origin
      s.origin_received = true;
      s.camera = k.camera;
      s.phantoms.insert(0);
      storeKeyframe(s, nullptr, 0, nullptr, k.stamp_s, nullptr, nullptr);
    }
    if (k.keyframe < expected) {
      ++stats_.keyframes_stale;
      return {StatusCode::kFailedPrecondition, "keyframe " + std::to_string(k.keyframe) + " of session " +
                                                   std::to_string(id) + " received twice or out of order, skipped"};
    }
    if (k.keyframe > expected) {
      // Keyframes lost on the way (a queue overflow): they stay where the last received one is
      // (phantoms: no loop may use them) and this one gets the odometry's motion across the gap.
      ++stats_.keyframe_gaps;
      say("session " + std::to_string(id) + " keyframes " + std::to_string(expected) + ".." +
          std::to_string(k.keyframe - 1) + " never arrived, bridged by the odometry");
      const Pose2 last = s.odometry.back();
      for (int g = expected; g < k.keyframe; ++g) {
        backend_->addMotion(s.backend, still);
        s.phantoms.insert(g);
        s.stamps.push_back(k.stamp_s);
        s.odometry.push_back(last);
        s.frames.push_back(k.frame_index);
        s.sources.push_back(MotionSource::kVisual);
      }
      // Stored with this keyframe, in its transaction, as minimal rows: written one by one, each
      // had cost a transaction's WAL pages and a 1.5 kB zero hash (17 kB a lost keyframe).
      gap = k.keyframe - expected;
      motion = UncertainPose2(between(last, k.odometry_pose),
                              k.motion.covariance * static_cast<double>(k.keyframe - expected + 1));
    }
    backend_->addMotion(s.backend, motion);
    s.stamps.push_back(k.stamp_s);
    s.odometry.push_back(k.odometry_pose);
    s.frames.push_back(k.frame_index);
    s.sources.push_back(k.motion_source);
  }
  ++stats_.keyframes;
  // The loops it closed go into the store with it (one transaction), then into the back-end.
  // Only loops whose keyframes are (or are being) stored: a stored loop on a keyframe the store
  // lacks would make it unrestorable.
  std::vector<Loop> to_store;
  std::vector<int> stored_at(loops.size(), -1);
  for (std::size_t i = 0; i < loops.size(); ++i) {
    const Loop& l = loops[i];
    if (!keyframeStored(l.session_a, l.keyframe_a, id, k.keyframe) ||
        !keyframeStored(l.session_b, l.keyframe_b, id, k.keyframe))
      continue;
    stored_at[i] = static_cast<int>(to_store.size());
    to_store.push_back(l);
  }
  std::vector<StoredLoop> stored;  // to_store in store ids, their ids set when written
  const int stored_before = s.stored;
  storeKeyframe(s, &k, k.keyframe, stored_motion, k.stamp_s, &to_store, store_ ? &stored : nullptr, gap, &still);
  if (s.stored == stored_before) stored_at.assign(loops.size(), -1);  // the keyframe, and its loops, not written
  emit(SessionEvent::Kind::kKeyframeAdded, id, -1, mapOf(id), "");
  for (std::size_t i = 0; i < loops.size(); ++i) {
    ++stats_.loops;
    try {
      acceptLoop(loops[i]);
      store_loops_.push_back(store_ && stored_at[i] >= 0 ? stored[static_cast<std::size_t>(stored_at[i])].id : -1);
    } catch (const std::invalid_argument& e) {
      ++stats_.loops_refused;
      emit(SessionEvent::Kind::kLoopRefused, loops[i].session_b, loops[i].session_a, -1, e.what());
    }
  }
  afterBackendChange();
  return Status::Ok();
}

void SessionManager::toPiece(int* session, int* keyframe) const {
  // The piece of the odometry's session that holds this keyframe: the one that starts last at or
  // before it (one odometry session can jump more than once; earlier pieces keep their names).
  const Piece* in = nullptr;
  for (const Piece& p : pieces_)
    if (p.from == *session && p.base <= *keyframe && (!in || p.base >= in->base)) in = &p;
  if (!in) return;
  *session = in->to;
  *keyframe -= in->base;
}

Status SessionManager::refuseJump(KeyframeInput k, const std::string& why) {
  ++stats_.keyframes_refused;
  // Held in the odometry's own names: the next keyframe is compared with it before toPiece.
  for (const Piece& p : pieces_)
    if (p.to == k.session && p.from != p.to) {
      k.session = p.from;
      k.keyframe += p.base;
      break;
    }
  jump_ = std::move(k);
  return {StatusCode::kInvalidArgument,
          why + ": refused; if the next keyframe continues from it, a new session starts there"};
}

Status SessionManager::startPiece(KeyframeInput held) {
  const int raw = held.session;
  const auto open_raw = sessions_.find(raw);
  // The odometry's session if it never opened here (its first keyframe was the jump), else a new id.
  const int id = open_raw == sessions_.end() && raw >= nextId() ? raw : nextId();
  if (id > kMaxSessionId) return badSessionId("keyframe " + std::to_string(held.keyframe), id);
  const int ended = active_;
  const Status opened = open(id, "", held.stamp_s);
  if (!opened.ok()) return opened;
  pieces_.push_back({raw, id, held.keyframe});
  ++stats_.keyframe_jumps;
  say("session " + std::to_string(raw) + "'s keyframe ids jumped to " + std::to_string(held.keyframe) +
      ", past max_keyframe_gap (" + std::to_string(options_.max_keyframe_gap) +
      "): " + (ended >= 0 ? "session " + std::to_string(ended) + " ended, " : std::string()) + "session " +
      std::to_string(id) + " starts there (keyframe " + std::to_string(held.keyframe) + " is its 0)");
  const Pose2 origin = held.odometry_pose;
  held.session = id;
  held.keyframe = 0;
  const Status st = appendKeyframe(std::move(held), {});
  // The odometry's pose of the piece's origin: a gap right after it is bridged from there.
  if (st.ok()) at(id).odometry[0] = origin;
  return st;
}

StoredLoop SessionManager::toStored(const Loop& l) const {
  StoredLoop sl;
  const auto a = sessions_.find(l.session_a), b = sessions_.find(l.session_b);
  sl.session_a = a == sessions_.end() ? -1 : a->second.store_id;
  sl.session_b = b == sessions_.end() ? -1 : b->second.store_id;
  sl.keyframe_a = l.keyframe_a;
  sl.keyframe_b = l.keyframe_b;
  sl.global = l.kind == Loop::Kind::kGlobal;
  sl.inliers = l.inliers;
  sl.z = l.z;
  sl.nav_placement = l.nav_placement;
  return sl;
}

void SessionManager::acceptLoop(const Loop& l) {
  const Session& a = at(l.session_a);
  const Session& b = at(l.session_b);
  if (a.phantoms.count(l.keyframe_a) || b.phantoms.count(l.keyframe_b))
    throw std::invalid_argument("loop on a keyframe that never arrived");
  backend_->addLoop({a.backend, l.keyframe_a, b.backend, l.keyframe_b, l.z, l.inliers, l.nav_placement});
  Loop named = l;
  if (l.keyframe_a < static_cast<int>(a.frames.size())) named.frame_a = a.frames[l.keyframe_a];
  if (l.keyframe_b < static_cast<int>(b.frames.size())) named.frame_b = b.frames[l.keyframe_b];
  loops_.push_back(named);
  ++at(l.session_a).loops;
  if (l.session_b != l.session_a) ++at(l.session_b).loops;
  emit(SessionEvent::Kind::kLoopAccepted, l.session_b, l.session_a, mapOf(l.session_b), "");
}

Status SessionManager::addLoop(const Loop& in, bool* waiting) { return addLoopIn(in, true, waiting); }

Status SessionManager::addLoopIn(const Loop& in, bool odometry_ids, bool* waiting) {
  if (waiting) *waiting = false;
  Loop l = in;
  if (odometry_ids) {  // the odometry's ids after a jump, as this manager names them
    toPiece(&l.session_a, &l.keyframe_a);
    toPiece(&l.session_b, &l.keyframe_b);
  }
  if (!validSessionId(l.session_a) || !validSessionId(l.session_b) || l.keyframe_a < 0 || l.keyframe_b < 0) {
    ++stats_.loops_refused;
    return validSessionId(l.session_a) && validSessionId(l.session_b)
               ? Status{StatusCode::kInvalidArgument, "a loop names a negative keyframe id"}
               : badSessionId("a loop", validSessionId(l.session_a) ? l.session_b : l.session_a);
  }
  for (int s : {l.session_a, l.session_b}) {
    if (deleted_.count(s)) {  // deleted: nothing will arrive for it
      ++stats_.loops_refused;
      return {StatusCode::kNotFound, "a loop names session " + std::to_string(s) + ", which was deleted"};
    }
  }
  const auto a = sessions_.find(l.session_a), b = sessions_.find(l.session_b);
  if (a == sessions_.end() || b == sessions_.end() || l.keyframe_a >= static_cast<int>(a->second.stamps.size()) ||
      l.keyframe_b >= static_cast<int>(b->second.stamps.size())) {
    if (waiting) *waiting = true;
    return {StatusCode::kFailedPrecondition, "a keyframe of the loop has not arrived yet"};
  }
  ++stats_.loops;
  try {
    acceptLoop(l);
  } catch (const std::invalid_argument& e) {
    ++stats_.loops_refused;
    emit(SessionEvent::Kind::kLoopRefused, l.session_b, l.session_a, -1, e.what());
    return {StatusCode::kFailedPrecondition, std::string("loop refused: ") + e.what()};
  }
  std::int64_t stored_id = -1;
  auto memoryOnly = [&](int s, int k) { return !keyframeStored(s, k) && at(s).memory_only; };
  if (!store_ || localising_ || memoryOnly(l.session_a, l.keyframe_a) || memoryOnly(l.session_b, l.keyframe_b)) {
    // nothing written: no store, or localisation mode (not a failure)
  } else if (!keyframeStored(l.session_a, l.keyframe_a) || !keyframeStored(l.session_b, l.keyframe_b)) {
    ++stats_.store_failures;  // on a keyframe the store lacks (a failed write): kept in memory only
  } else {
    storeWrite("writing a loop", [&] {
      std::vector<StoredLoop> one{toStored(l)};
      store_->addLoops(&one);
      stored_id = one[0].id;
    });
  }
  store_loops_.push_back(stored_id);
  afterBackendChange();
  return Status::Ok();
}

Status SessionManager::addLink(Loop l) {
  if (const Status checked = checkLink(l); !checked.ok()) return checked;
  l.kind = l.session_a == l.session_b ? Loop::Kind::kLocal : Loop::Kind::kGlobal;
  l.frame_a = at(l.session_a).frames.at(l.keyframe_a);
  l.frame_b = at(l.session_b).frames.at(l.keyframe_b);
  l.hash_l1 = 0.0f;
  Status st;
  {
    // The link goes into the audit trail before a join it brings about (also when addLoop throws).
    const HeldChanges hold(&hold_changes_);
    st = addLoopIn(l, false, nullptr);  // already this manager's ids: never moved by a jump again
  }
  if (st.ok()) {
    const std::string link = loopText(l);
    const char* kind = l.kind == Loop::Kind::kLocal ? "local" : "global";
    say("add_link " + link + " (" + kind + ")");
    char pose[200];
    std::snprintf(pose, sizeof pose, "pose (%.4f m, %.4f m, %.4f rad), sigma (%.4g m, %.4g m, %.4g rad), %d inliers",
                  l.z.mean.x(), l.z.mean.y(), l.z.mean.yaw(), std::sqrt(l.z.covariance(0, 0)),
                  std::sqrt(l.z.covariance(1, 1)), std::sqrt(l.z.covariance(2, 2)), l.inliers);
    record("link",
           l.session_a == l.session_b ? std::to_string(l.session_a)
                                      : std::to_string(l.session_a) + "," + std::to_string(l.session_b),
           link, std::string(kind) + " link " + link + ": " + pose, options_.requester.c_str());
  }
  recordMapChanges();
  return st;
}

Status SessionManager::addNavPlacement(Loop l, bool visual) {
  // A visual bridge is a registration: stored as the visual loop it is. The nav's placement matched
  // no features: no support in any join rule.
  const std::string what = visual ? "visual bridge" : "nav placement";
  l.kind = Loop::Kind::kGlobal;
  l.nav_placement = !visual;
  if (!visual) l.inliers = 0;
  l.hash_l1 = 0.0f;
  // addLoop takes the odometry's ids and names them itself: given l's, a keyframe past a jump
  // whose piece kept its session's id would be moved back by the jump twice.
  const Loop odometry_ids = l;
  toPiece(&l.session_a, &l.keyframe_a);  // the odometry's ids after a jump, as this manager names them
  toPiece(&l.session_b, &l.keyframe_b);
  Status checked = checkLinkEnds(l);
  if (checked.ok() && l.session_a == l.session_b)
    checked = {StatusCode::kInvalidArgument, "it links a session to itself"};
  if (checked.ok()) {
    if (const std::string bad = checkUncertainPose(l.z, true); !bad.empty())
      checked = {StatusCode::kInvalidArgument, "the pose: " + bad};
  }
  if (checked.ok()) checked = storedMapsMayChange("a " + what);
  if (!checked.ok()) return {checked.code, what + ": " + checked.message};
  if (mapOf(l.session_a) == mapOf(l.session_b))
    return {StatusCode::kOk, what + ": sessions " + std::to_string(l.session_a) + " and " +
                                 std::to_string(l.session_b) + " are already in one map"};
  Status st;
  {
    // The placement goes into the audit trail before the join it brings about.
    const HeldChanges hold(&hold_changes_);
    st = addLoop(odometry_ids);
    if (st.ok()) {
      char pose[200];
      std::snprintf(pose, sizeof pose, "pose (%.4f m, %.4f m, %.4f rad), sigma (%.4g m, %.4g rad)", l.z.mean.x(),
                    l.z.mean.y(), l.z.mean.yaw(), std::sqrt(l.z.covariance(0, 0)), std::sqrt(l.z.covariance(2, 2)));
      const std::string link = loopText(l);
      say(what + " " + link + ": " + pose);
      record(visual ? "visual_bridge" : "nav_placement",
             std::to_string(l.session_a) + "," + std::to_string(l.session_b), link, what + " " + link + ": " + pose,
             visual ? "visual" : "nav");
      // One placement is the whole support the operator's join with one loop asks for.
      st = backend_->join(at(l.session_a).backend, at(l.session_b).backend, 1);
      if (st.ok()) {
        ++(visual ? stats_.visual_bridges : stats_.nav_placements);
      } else {
        say(what + " " + link + " stored but not joined: " + st.message);
        st = {st.code, what + ": " + st.message};
      }
    }
  }
  const char* cause = cause_;
  cause_ = visual ? "visual" : "nav";
  afterBackendChange();
  cause_ = cause;
  return st;
}

}  // namespace core
}  // namespace uw_multislam
