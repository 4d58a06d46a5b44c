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

void SessionManager::addStoreRow(int id, double stamp_s) {
  // Its row takes the session's id: a session's id is its store id for life.
  const Session& s = table_.at(id);
  table_.setStoreRow(id, table_.store()->addSession(s.name(), s.camera, stamp_s, id));
  if (!s.vehicle().empty()) {  // another vehicle's: where it came from, as merge_stores records it
    SessionProvenance p;
    p.session = s.storeRow();
    p.source_file = "fleet:" + s.vehicle();
    p.source_session = s.remoteId();
    p.source_name = s.name();
    p.vehicle = s.vehicle();
    table_.store()->addProvenance(p);
  }
}

void SessionManager::storeKeyframe(int id, const KeyframeInput* k, int keyframe, const UncertainPose2* motion,
                                   double stamp_s, const std::vector<Loop>* loops, std::vector<StoredLoop>* stored,
                                   int gap, const UncertainPose2* gap_motion) {
  SessionStore* store = table_.store();
  if (!store) return;
  Session& s = table_.at(id);
  if (table_.localising() && !s.memory_only) {
    s.memory_only = true;
    say("localisation mode: session " + std::to_string(id) + " '" + s.name() + "': keyframes from " +
        std::to_string(keyframe) + " on are kept in memory only (" + std::to_string(s.stored) + " stored)");
  }
  if (s.memory_only) return;
  if (s.store_cut || keyframe - gap != s.stored) {  // after a failed write: not stored, counted
    ++table_.stats().store_failures;
    return;
  }
  const bool ok = storeWrite("writing a keyframe", [&] {
    if (s.storeRow() < 0) {
      addStoreRow(id, stamp_s);  // the camera is known before a placeholder origin too
    } else if (keyframe == 0) {
      // A row made before the session's first keyframe (saveMaps after start_session) has no
      // camera yet (0x0): it gets the one the origin (or the placeholder origin) brought.
      store->setSessionCamera(s.storeRow(), s.camera);
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
      lost[i].session = s.storeRow();
      lost[i].keyframe = keyframe - gap + i;
      lost[i].stamp_s = stamp_s;
      lost[i].hash = Eigen::VectorXf::Zero(HalocProjections::kHashSize);
    }
    StoredKeyframe sk;
    sk.session = s.storeRow();
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
    store->addKeyframe(sk, motion, stored, lost, gap_motion);
  });
  if (ok) {
    s.stored += gap + 1;
    return;
  }
  s.store_cut = true;
  say("session store " + table_.options().store_path + ": session '" + s.name() + "': keyframes from " +
      std::to_string(keyframe) + " on are not stored (each counted a store failure); the " + std::to_string(s.stored) +
      " stored before stay restorable");
}

Status SessionManager::addKeyframe(const KeyframeInput& input, const std::vector<Loop>& loops) {
  SessionManagerStats& stats = table_.stats();
  const SessionManagerOptions& options = table_.options();
  if (!validSessionId(input.session)) {
    ++stats.keyframes_refused;
    return badSessionId("keyframe " + std::to_string(input.keyframe), input.session);
  }
  if (input.keyframe < 0) {
    ++stats.keyframes_refused;
    return {StatusCode::kInvalidArgument, "keyframe id " + std::to_string(input.keyframe) + " is negative"};
  }
  // The store keeps the session's camera (and refuses an unusable one): refused here, before it
  // could make the session's row, and with it every later save of the maps, fail.
  if (const std::string bad = unusableCamera(input.camera); !bad.empty()) {
    ++stats.keyframes_refused;
    return {StatusCode::kInvalidArgument, "keyframe " + std::to_string(input.keyframe) + " of session " +
                                              std::to_string(input.session) + ": camera: " + bad};
  }
  KeyframeInput k = input;
  // The one place a keyframe is hashed when nobody upstream did.
  if (k.hash.size() != HalocProjections::kHashSize && !k.features.descriptors.empty())
    k.hash = table_.hasher().hash(k.features.descriptors);
  // The keyframe after a refused jump decides what the jump was.
  if (table_.held()) {
    KeyframeInput held = std::move(*table_.held());
    table_.held().reset();
    const long long step = static_cast<long long>(k.keyframe) - held.keyframe;
    if (held.session == k.session && step >= 1 && step <= options.max_keyframe_gap + 1LL) {
      const Status st = startPiece(std::move(held));
      if (!st.ok()) return st;
    }
  }
  const std::vector<Piece>& pieces = table_.pieces();
  const auto piece_took =
      std::find_if(pieces.begin(), pieces.end(), [&](const Piece& p) { return p.to != p.from && p.to == k.session; });
  const bool renamed = std::any_of(pieces.begin(), pieces.end(), [&](const Piece& p) { return p.from == k.session; });
  if (piece_took != pieces.end() && !renamed) {
    // The odometry's next session took the id a piece took (nobody told it the piece's), whether
    // that piece is still recording or finished: it is a session of its own, under the next free
    // id, its keyframe ids kept.
    const int id = table_.nextId();
    if (id > kMaxSessionId) return badSessionId("keyframe " + std::to_string(k.keyframe), id);
    const int from = piece_took->from;
    if (const Status st = open(id, "", k.stamp_s); !st.ok()) return st;
    say("the odometry's session " + std::to_string(k.session) + " is session " + std::to_string(id) + " here (" +
        std::to_string(k.session) + " is the piece its session " + std::to_string(from) + " went on in)");
    table_.addPiece({k.session, id, 0});
  }
  table_.toPiece(&k.session, &k.keyframe);
  // Our odometry's keyframe naming another vehicle's session newer than every one of ours: a
  // stray message, or our odometry took that id in the instant the other vehicle's session took
  // it here (before active_session told it the next free id). The next keyframe tells which.
  if (table_.has(k.session) && !table_.at(k.session).vehicle().empty() && k.session > table_.newestOwnSession())
    return refuseUnopened(std::move(k));
  if (!table_.has(k.session)) {
    if (k.session > table_.nextId()) return refuseUnopened(std::move(k));
    if (k.session < table_.nextId()) {
      ++stats.keyframes_stale;
      return {StatusCode::kFailedPrecondition, "keyframe of old session " + std::to_string(k.session) +
                                                   " skipped (session " + std::to_string(table_.active()) +
                                                   " is recording)"};
    }
    if (k.keyframe > options.max_keyframe_gap) {
      const std::string why = "keyframe " + std::to_string(k.keyframe) + " starts session " +
                              std::to_string(k.session) + ": more than max_keyframe_gap (" +
                              std::to_string(options.max_keyframe_gap) + ") keyframes missing";
      return refuseJump(std::move(k), why);
    }
    open(k.session, "", k.stamp_s);
  }
  const int id = k.session;
  if (id != table_.active()) {
    ++stats.keyframes_stale;
    return {StatusCode::kFailedPrecondition, "keyframe of finished session " + std::to_string(id) + " skipped"};
  }
  if (pieces.empty()) return appendKeyframe(std::move(k), loops);
  std::vector<Loop> named = loops;  // the odometry's ids after a jump, as this manager names them
  for (Loop& l : named) {
    table_.toPiece(&l.session_a, &l.keyframe_a);
    table_.toPiece(&l.session_b, &l.keyframe_b);
  }
  return appendKeyframe(std::move(k), named);
}

Status SessionManager::appendKeyframe(KeyframeInput k, const std::vector<Loop>& loops) {
  const int id = k.session;
  Session& s = table_.at(id);
  SessionManagerStats& stats = table_.stats();
  const int max_gap = table_.options().max_keyframe_gap;
  const int expected = static_cast<int>(s.stamps.size());
  if (k.keyframe > expected && k.keyframe - expected > max_gap) {
    const std::string why = "keyframe " + std::to_string(k.keyframe) + " of session " + std::to_string(id) + ": " +
                            std::to_string(k.keyframe - expected) + " keyframes missing, more than max_keyframe_gap (" +
                            std::to_string(max_gap) + ")";
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
    s.altitudes[0] = k.altitude_m;
    stored_motion = nullptr;
  } else {
    if (!s.origin_received) {  // keyframe 0 never arrived: a placeholder origin
      s.origin_received = true;
      s.camera = k.camera;
      s.altitudes[0] = k.altitude_m;
      s.phantoms.insert(0);
      storeKeyframe(id, nullptr, 0, nullptr, k.stamp_s, nullptr, nullptr);
    }
    if (k.keyframe < expected) {
      ++stats.keyframes_stale;
      return {StatusCode::kFailedPrecondition, "keyframe " + std::to_string(k.keyframe) + " of session " +
                                                   std::to_string(id) + " received twice or out of order, skipped"};
    }
    if (k.keyframe > expected) {
      // Keyframes lost on the way (a queue overflow): they stay where the last received one is
      // (phantoms: no loop may use them) and this one gets the odometry's motion across the gap.
      ++stats.keyframe_gaps;
      say("session " + std::to_string(id) + " keyframes " + std::to_string(expected) + ".." +
          std::to_string(k.keyframe - 1) + " never arrived, bridged by the odometry");
      const Pose2 last = s.odometry.back();
      for (int g = expected; g < k.keyframe; ++g) {
        table_.backend().addMotion(s.backend(), still);
        s.phantoms.insert(g);
        s.stamps.push_back(k.stamp_s);
        s.odometry.push_back(last);
        s.frames.push_back(k.frame_index);
        s.altitudes.push_back(k.altitude_m);
        s.sources.push_back(MotionSource::kVisual);
      }
      // Stored with this keyframe, in its transaction, as minimal rows: written one by one, each
      // had cost a transaction's WAL pages and a 1.5 kB zero hash (17 kB a lost keyframe).
      gap = k.keyframe - expected;
      motion = UncertainPose2(between(last, k.odometry_pose),
                              k.motion.covariance * static_cast<double>(k.keyframe - expected + 1));
    }
    table_.backend().addMotion(s.backend(), motion);
    s.stamps.push_back(k.stamp_s);
    s.odometry.push_back(k.odometry_pose);
    s.frames.push_back(k.frame_index);
    s.altitudes.push_back(k.altitude_m);
    s.sources.push_back(k.motion_source);
  }
  ++stats.keyframes;
  // The loops it closed go into the store with it (one transaction), then into the back-end.
  // Only loops whose keyframes are (or are being) stored: a stored loop on a keyframe the store
  // lacks would make it unrestorable.
  std::vector<Loop> to_store;
  std::vector<int> stored_at(loops.size(), -1);
  for (std::size_t i = 0; i < loops.size(); ++i) {
    const Loop& l = loops[i];
    if (!table_.keyframeStored(l.session_a, l.keyframe_a, id, k.keyframe) ||
        !table_.keyframeStored(l.session_b, l.keyframe_b, id, k.keyframe))
      continue;
    stored_at[i] = static_cast<int>(to_store.size());
    to_store.push_back(l);
  }
  std::vector<StoredLoop> stored;  // to_store in store ids, their ids set when written
  const int stored_before = s.stored;
  const bool has_store = table_.store() != nullptr;
  storeKeyframe(id, &k, k.keyframe, stored_motion, k.stamp_s, &to_store, has_store ? &stored : nullptr, gap, &still);
  if (s.stored == stored_before) stored_at.assign(loops.size(), -1);  // the keyframe, and its loops, not written
  emit(SessionEvent::Kind::kKeyframeAdded, id, -1, view_.mapOf(id), "");
  for (std::size_t i = 0; i < loops.size(); ++i) {
    ++stats.loops;
    try {
      acceptLoop(loops[i], has_store && stored_at[i] >= 0 ? stored[static_cast<std::size_t>(stored_at[i])].id : -1);
    } catch (const std::invalid_argument& e) {
      ++stats.loops_refused;
      emit(SessionEvent::Kind::kLoopRefused, loops[i].session_b, loops[i].session_a, -1, e.what());
    }
  }
  afterBackendChange();
  return Status::Ok();
}

Status SessionManager::refuseJump(KeyframeInput k, const std::string& why) {
  ++table_.stats().keyframes_refused;
  // Held in the odometry's own names: the next keyframe is compared with it before toPiece.
  for (const Piece& p : table_.pieces())
    if (p.to == k.session && p.from != p.to) {
      k.session = p.from;
      k.keyframe += p.base;
      break;
    }
  table_.held() = std::move(k);
  return {StatusCode::kInvalidArgument,
          why + ": refused; if the next keyframe continues from it, a new session starts there"};
}

Status SessionManager::refuseUnopened(KeyframeInput k) {
  ++table_.stats().keyframes_unopened;
  const std::string s = std::to_string(k.session);
  const std::string whose = table_.has(k.session)
                                ? "session " + s + " is vehicle " + table_.at(k.session).vehicle() + "'s here"
                                : "no session " + s + " was opened";
  const std::string why = "keyframe " + std::to_string(k.keyframe) + " of session " + s + " refused: " + whose +
                          " (session ids are the back-end's to give: the next is " + std::to_string(table_.nextId()) +
                          "); held: if the next keyframe continues it, our odometry's session starts there";
  table_.held() = std::move(k);
  return {StatusCode::kFailedPrecondition, why};
}

Status SessionManager::startPiece(KeyframeInput held) {
  const int raw = held.session, next = table_.nextId(), max_gap = table_.options().max_keyframe_gap;
  const bool foreign = table_.has(raw) && !table_.at(raw).vehicle().empty();
  const bool unopened = !table_.has(raw) && raw > next;
  // The odometry's session if it never opened here (its first keyframe was the jump, or the
  // sessions before it were lost on the way: at most max_keyframe_gap of them, so that ids stay
  // dense), else the next id.
  const int id = !table_.has(raw) && raw >= next && raw - next <= max_gap ? raw : next;
  if (id > kMaxSessionId) return badSessionId("keyframe " + std::to_string(held.keyframe), id);
  const int ended = table_.active();
  const Status opened = open(id, "", held.stamp_s);
  if (!opened.ok()) return opened;
  table_.addPiece({raw, id, held.keyframe, foreign});
  const std::string was = ended >= 0 ? "session " + std::to_string(ended) + " ended, " : std::string();
  const std::string starts =
      "session " + std::to_string(id) + " starts there (keyframe " + std::to_string(held.keyframe) + " is its 0)";
  if (foreign) {
    say("the odometry's session " + std::to_string(raw) + " is vehicle " + table_.at(raw).vehicle() +
        "'s session here (both took the id at once): " + was + starts);
  } else if (unopened) {
    say("the odometry's session " + std::to_string(raw) + " went on past its refused keyframe " +
        std::to_string(held.keyframe) + ": its sessions from " + std::to_string(next) + " were lost on the way; " +
        was + starts);
  } else {
    ++table_.stats().keyframe_jumps;
    say("session " + std::to_string(raw) + "'s keyframe ids jumped to " + std::to_string(held.keyframe) +
        ", past max_keyframe_gap (" + std::to_string(max_gap) + "): " + was + starts);
  }
  const Pose2 origin = held.odometry_pose;
  held.session = id;
  held.keyframe = 0;
  const Status st = appendKeyframe(std::move(held), {});
  // The odometry's pose of the piece's origin: a gap right after it is bridged from there.
  if (st.ok()) table_.at(id).odometry[0] = origin;
  return st;
}

StoredLoop SessionManager::toStored(const Loop& l) const {
  StoredLoop sl;
  sl.session_a = table_.has(l.session_a) ? table_.at(l.session_a).storeRow() : -1;
  sl.session_b = table_.has(l.session_b) ? table_.at(l.session_b).storeRow() : -1;
  sl.keyframe_a = l.keyframe_a;
  sl.keyframe_b = l.keyframe_b;
  sl.global = l.kind == Loop::Kind::kGlobal;
  sl.inliers = l.inliers;
  sl.z = l.z;
  sl.nav_placement = l.nav_placement;
  return sl;
}

void SessionManager::acceptLoop(const Loop& l, std::int64_t store_row) {
  table_.acceptLoop(l, store_row);
  emit(SessionEvent::Kind::kLoopAccepted, l.session_b, l.session_a, view_.mapOf(l.session_b), "");
}

Status SessionManager::addLoop(const Loop& in, bool* waiting) { return addLoopIn(in, true, waiting); }

Status SessionManager::addLoopIn(const Loop& in, bool odometry_ids, bool* waiting) {
  if (waiting) *waiting = false;
  Loop l = in;
  if (odometry_ids) {  // the odometry's ids after a jump, as this manager names them
    table_.toPiece(&l.session_a, &l.keyframe_a, true);
    table_.toPiece(&l.session_b, &l.keyframe_b, true);
  }
  SessionManagerStats& stats = table_.stats();
  if (!validSessionId(l.session_a) || !validSessionId(l.session_b) || l.keyframe_a < 0 || l.keyframe_b < 0) {
    ++stats.loops_refused;
    return validSessionId(l.session_a) && validSessionId(l.session_b)
               ? Status{StatusCode::kInvalidArgument, "a loop names a negative keyframe id"}
               : badSessionId("a loop", validSessionId(l.session_a) ? l.session_b : l.session_a);
  }
  for (int s : {l.session_a, l.session_b}) {
    if (table_.deleted(s)) {  // deleted: nothing will arrive for it
      ++stats.loops_refused;
      return {StatusCode::kNotFound, "a loop names session " + std::to_string(s) + ", which was deleted"};
    }
  }
  if (!table_.has(l.session_a) || !table_.has(l.session_b) ||
      l.keyframe_a >= static_cast<int>(table_.at(l.session_a).stamps.size()) ||
      l.keyframe_b >= static_cast<int>(table_.at(l.session_b).stamps.size())) {
    if (waiting) *waiting = true;
    return {StatusCode::kFailedPrecondition, "a keyframe of the loop has not arrived yet"};
  }
  ++stats.loops;
  std::size_t index = 0;
  try {
    acceptLoop(l, -1);
    index = table_.loops().size() - 1;
  } catch (const std::invalid_argument& e) {
    ++stats.loops_refused;
    emit(SessionEvent::Kind::kLoopRefused, l.session_b, l.session_a, -1, e.what());
    return {StatusCode::kFailedPrecondition, std::string("loop refused: ") + e.what()};
  }
  auto memoryOnly = [&](int s, int k) { return !table_.keyframeStored(s, k) && table_.at(s).memory_only; };
  if (!table_.store() || table_.localising() || memoryOnly(l.session_a, l.keyframe_a) ||
      memoryOnly(l.session_b, l.keyframe_b)) {
    // nothing written: no store, or localisation mode (not a failure)
  } else if (!table_.keyframeStored(l.session_a, l.keyframe_a) || !table_.keyframeStored(l.session_b, l.keyframe_b)) {
    ++stats.store_failures;  // on a keyframe the store lacks (a failed write): kept in memory only
  } else {
    storeWrite("writing a loop", [&] {
      std::vector<StoredLoop> one{toStored(l)};
      table_.store()->addLoops(&one);
      table_.setLoopStoreRow(index, one[0].id);
    });
  }
  afterBackendChange();
  return Status::Ok();
}

Status SessionManager::addLink(Loop l) {
  if (const Status checked = view_.checkLink(l); !checked.ok()) return checked;
  l.kind = l.session_a == l.session_b ? Loop::Kind::kLocal : Loop::Kind::kGlobal;
  l.frame_a = table_.at(l.session_a).frames.at(l.keyframe_a);
  l.frame_b = table_.at(l.session_b).frames.at(l.keyframe_b);
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
           link, std::string(kind) + " link " + link + ": " + pose, table_.options().requester.c_str());
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
  // The odometry's ids after a jump or a renamed session, as this manager names them (every
  // piece: the nav's placement is the odometry's own, never a loop detector's).
  table_.toPiece(&l.session_a, &l.keyframe_a);
  table_.toPiece(&l.session_b, &l.keyframe_b);
  Status checked = view_.checkLinkEnds(l);
  if (checked.ok() && l.session_a == l.session_b)
    checked = {StatusCode::kInvalidArgument, "it links a session to itself"};
  if (checked.ok()) {
    if (const std::string bad = checkUncertainPose(l.z, true); !bad.empty())
      checked = {StatusCode::kInvalidArgument, "the pose: " + bad};
  }
  if (checked.ok()) checked = view_.storedMapsMayChange("a " + what);
  if (!checked.ok()) return {checked.code, what + ": " + checked.message};
  if (view_.mapOf(l.session_a) == view_.mapOf(l.session_b))
    return {StatusCode::kOk, what + ": sessions " + std::to_string(l.session_a) + " and " +
                                 std::to_string(l.session_b) + " are already in one map"};
  Status st;
  {
    // The placement goes into the audit trail before the join it brings about.
    const HeldChanges hold(&hold_changes_);
    st = addLoopIn(l, false, nullptr);  // named already: a piece must not move it twice
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
      st = table_.backend().join(table_.at(l.session_a).backend(), table_.at(l.session_b).backend(), 1);
      if (st.ok()) {
        ++(visual ? table_.stats().visual_bridges : table_.stats().nav_placements);
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
