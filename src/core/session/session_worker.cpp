#include "uw_multislam/core/session/session_worker.h"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <stdexcept>
#include <utility>

#include "uw_multislam/core/common/thread_priority.h"

namespace uw_multislam {
namespace core {

std::string SessionWorkerOptions::validate() const {
  if (queue_size < 1) return "queue_size must be >= 1";
  if (max_waiting_loops < 0) return "max_waiting_loops must be >= 0";
  if (nice < 0 || nice > 19) return "nice must be in [0, 19]";
  return "";
}

namespace {

const SessionWorkerOptions& checked(const SessionWorkerOptions& o) {
  const std::string bad = o.validate();
  if (!bad.empty()) throw std::invalid_argument("session worker: " + bad);
  return o;
}

}  // namespace

std::optional<SessionQueries::Relocalisation> RelocalisationTracker::update(const SessionQueries& manager, int session,
                                                                            std::string* said) {
  std::optional<SessionQueries::Relocalisation> r = manager.relocalise(session);
  const int map = r ? r->map : -1;
  said->clear();
  if (session != state_.session || map != state_.map) {
    if (r)
      *said = "session " + std::to_string(session) + " relocalised in map " + std::to_string(map) +
              " at its keyframe " + std::to_string(r->keyframe) + " from " + std::to_string(r->loops) +
              " consistent global loops (" + std::to_string(r->inliers) + " inliers)";
    else if (session == state_.session && state_.map >= 0 && manager.mapOf(session) != state_.map)  // not by a join
      *said = "session " + std::to_string(session) + " no longer relocalised in map " + std::to_string(state_.map);
  }
  if (session != state_.session) state_.published = 0;
  state_.session = session;
  state_.map = map;
  state_.loops = r ? r->loops : 0;
  state_.keyframe = r ? r->keyframe : -1;
  return r;
}

SessionWorker::SessionWorker(std::unique_ptr<SessionManager> manager, const SessionWorkerOptions& options, Log log)
    : SessionWorker(manager.get(), options, std::move(log)) {
  owned_ = std::move(manager);
}

SessionWorker::SessionWorker(SessionManager* manager, const SessionWorkerOptions& options, Log log)
    : manager_(manager),
      options_(checked(options)),
      log_(std::move(log)),
      queue_(static_cast<std::size_t>(options_.queue_size)) {
  if (!manager_) throw std::invalid_argument("session worker: no session manager");
  manager_->setDeferredOptimisation(true);  // optimised here, outside the mutex
}

SessionWorker::~SessionWorker() { stop(); }

void SessionWorker::say(Severity s, const std::string& line) const {
  if (log_) log_(s, line);
}

// --- Driving ------------------------------------------------------------------------------------

void SessionWorker::start(AfterItem after_item) {
  if (thread_.joinable()) throw std::logic_error("session worker: started twice");
  after_item_ = std::move(after_item);
  thread_ = std::thread([this] { run(); });
}

void SessionWorker::stop() {
  queue_.close();
  if (thread_.joinable()) thread_.join();
}

bool SessionWorker::submit(Item item) {
  if (!thread_.joinable()) {
    if (queue_.closed()) return false;
    process(item);  // synchronous: now, in the caller's thread
    return true;
  }
  // When full the oldest is dropped: live, the newest data matters most.
  return std::holds_alternative<OptimiseItem>(item) ? queue_.pushPriority(std::move(item))
                                                    : queue_.push(std::move(item));
}

void SessionWorker::run() {
  std::string why;
  if (!setThisThreadNice(options_.nice, &why)) say(Severity::kWarn, "worker nice not applied: " + why);
  for (Item item; queue_.pop(&item); item = Item()) process(item);  // until closed and drained
}

template <typename F>
void SessionWorker::step(F f) {
  {
    MutexLock lock(&mutex_);
    try {
      f();
    } catch (const std::exception& e) {
      if (!asynchronous()) throw;
      {
        MutexLock s(&stats_mutex_);
        ++stats_.skipped;
      }
      say(Severity::kError, std::string("message skipped: ") + e.what());
    }
  }
  optimiseDueNow();  // after each keyframe or loop, whichever way the worker is driven
}

void SessionWorker::process(Item& item) {
  if (std::holds_alternative<OptimiseItem>(item)) {
    optimiseDueNow();
  } else if (auto* l = std::get_if<LoopItem>(&item)) {
    step([&] {
      mutex_.assertHeld();
      {
        MutexLock s(&stats_mutex_);
        ++stats_.loops;
      }
      tryLoop(l->loop);
    });
  } else {  // a keyframe (ours or another vehicle's) or a session's end: the waiting loops are tried again
    std::deque<Loop> retry;
    step([&] {
      mutex_.assertHeld();
      if (auto* k = std::get_if<KeyframeItem>(&item)) {
        {
          MutexLock s(&stats_mutex_);
          ++stats_.keyframes;
        }
        const Status st = manager_->addKeyframe(k->keyframe, k->loops);
        if (st.ok() && k->keyframe.nav_placement) {
          // The piece is placed once its first keyframe is in (offline and live alike).
          Loop l;
          l.session_a = k->keyframe.nav_placement->session;
          l.keyframe_a = k->keyframe.nav_placement->keyframe;
          l.session_b = k->keyframe.session;
          l.keyframe_b = k->keyframe.keyframe;
          l.z = k->keyframe.nav_placement->z;
          const Status placed = manager_->addNavPlacement(l, k->keyframe.nav_placement->visual);
          if (!placed.ok()) say(Severity::kWarn, placed.message);
        }
        if (k->done) k->done(manager_->view(), k->keyframe, st);
      } else if (auto* f = std::get_if<ForeignKeyframeItem>(&item)) {
        std::string why;
        Status st;
        int local = -1;
        bool opens = false;
        if (!HashSettings::compatible(f->settings, manager_->view().hashSettings(), &why)) {
          st = {StatusCode::kFailedPrecondition, why + " (ours): its hashes cannot be compared with ours"};
        } else {
          opens = manager_->view().foreignSession(f->vehicle, f->keyframe.session) < 0;
          st = manager_->fleet().addKeyframe(f->vehicle, f->keyframe, &local);
        }
        if (f->done) f->done(manager_->view(), f->keyframe, st, local, opens && st.ok());
      } else if (auto* e = std::get_if<ForeignEndItem>(&item)) {
        const Status st = manager_->fleet().endSession(e->vehicle, e->remote_session, e->stamp_s);
        if (e->done) e->done(manager_->view(), st);
      }
      retry = std::exchange(waiting_, {});
    });
    for (const Loop& l : retry) {  // their keyframe may be here
      step([&] {
        mutex_.assertHeld();
        tryLoop(l);
      });
    }  // their keyframe may be here
  }
  if (after_item_) {
    MutexLock lock(&mutex_);
    after_item_(*manager_);
  }
}

void SessionWorker::tryLoop(const Loop& loop) {
  bool waiting = false;
  const Status st = manager_->addLoop(loop, &waiting);
  if (waiting) {
    const bool full = static_cast<int>(waiting_.size()) >= options_.max_waiting_loops;
    if (full && !waiting_.empty()) waiting_.pop_front();  // the oldest, counted
    if (options_.max_waiting_loops > 0) waiting_.push_back(loop);
    MutexLock s(&stats_mutex_);
    stats_.waiting_dropped += full ? 1 : 0;
  } else if (!st.ok()) {
    say(Severity::kWarn, st.message);
  }
  MutexLock s(&stats_mutex_);
  stats_.waiting = waiting_.size();
}

void SessionWorker::optimiseDueNow() {
  for (;;) {
    std::optional<MapOptimisation> o;
    {
      MutexLock lock(&mutex_);
      o = manager_->nextOptimisation();
    }
    if (!o) return;
    try {  // without the mutex: requests and queries go on meanwhile
      if (options_.solve)
        options_.solve(&*o);
      else
        SessionManager::solveOptimisation(&*o);
    } catch (const std::exception& e) {  // the map stays due: tried again after the next item
      if (!asynchronous()) throw;
      say(Severity::kError, "optimising map " + std::to_string(o->map) + " failed: " + e.what());
      return;
    }
    MutexLock lock(&mutex_);
    const bool applied = manager_->applyOptimisation(*o);  // false: the map changed meanwhile, still due
    MutexLock s(&stats_mutex_);
    ++stats_.solves;
    stats_.solved_again += applied ? 0 : 1;
  }
}

bool SessionWorker::addKeyframe(KeyframeInput keyframe, std::vector<Loop> loops, KeyframeDone done) {
  return submit(KeyframeItem{std::move(keyframe), std::move(loops), std::move(done)});
}

bool SessionWorker::addLoop(const Loop& loop) { return submit(LoopItem{loop}); }

bool SessionWorker::addForeignKeyframe(const std::string& vehicle, const HashSettings& settings, KeyframeInput keyframe,
                                       ForeignDone done) {
  return submit(ForeignKeyframeItem{vehicle, settings, std::move(keyframe), std::move(done)});
}

bool SessionWorker::endForeignSession(const std::string& vehicle, int remote_session, double stamp_s, Done done) {
  return submit(ForeignEndItem{vehicle, remote_session, stamp_s, std::move(done)});
}

void SessionWorker::optimiseDue() { submit(OptimiseItem{}); }

SessionWorkerStats SessionWorker::stats() const {
  SessionWorkerStats s;
  {
    MutexLock lock(&stats_mutex_);
    s = stats_;
  }
  s.pushed = queue_.pushed();
  s.dropped_queue_full = queue_.dropped();
  s.queued = queue_.size();
  return s;
}

// --- Stored sessions and the loop detectors -----------------------------------------------------

std::pair<int, long> SessionWorker::reloadStored() {
  MutexLock lock(&mutex_);
  int sessions = 0;
  long keyframes = 0;
  for (const SessionSummary& s : manager_->view().list()) {
    if (s.state != SessionState::kUnloaded) continue;
    ReloadedSession r;
    // Nothing read here: the handover reads each session's hashes when a loop detector
    // subscribes, one session per lock, so that the host maps from its start (reading the hashes
    // here held a start-up for 9.4 s at 100 k keyframes from a cold disk, 2 s warm). Features
    // (and thumbnails: the live mosaic lacks these keyframes) stay in the store.
    const Status st = manager_->reload(std::to_string(s.id), &r, SessionManager::ReloadRead::kNothing);
    if (!st.ok()) {
      say(Severity::kError,
          "~reload_stored: session " + std::to_string(s.id) + " '" + s.name + "' not reloaded: " + st.message);
      continue;
    }
    MutexLock h(&handover_mutex_);
    handed_.push_back(r.id);
    ++sessions;
    keyframes += s.keyframes;
  }
  say(Severity::kInfo, "~reload_stored: " + std::to_string(sessions) + " stored sessions (" +
                           std::to_string(keyframes) + " keyframes) go to every loop detector that subscribes");
  return {sessions, keyframes};
}

Status SessionWorker::reloadSession(const std::string& name_or_id, ReloadedSession* out,
                                    const std::function<void(const ReloadedSession&, const StoredKeyframe&)>& send) {
  MutexLock lock(&mutex_);
  const Status st = manager_->reload(name_or_id, out);
  if (!st.ok()) return st;
  {
    MutexLock h(&handover_mutex_);
    handed_.push_back(out->id);  // and to every loop detector that subscribes later
  }
  for (const StoredKeyframe& k : out->keyframes) {
    if (!options_.page_stored) {
      send(*out, k);
      continue;
    }
    StoredKeyframe paged = k;  // the loop detector reads the features again when needed (keyframe_features)
    paged.points.clear();
    paged.descriptors.release();
    send(*out, paged);
  }
  return st;
}

HandoverStats SessionWorker::handOver(const std::string& to,
                                      const std::function<void(const ReloadedSession&, const StoredKeyframe&)>& send) {
  std::vector<int> ids;
  {
    MutexLock lock(&mutex_);
    MutexLock h(&handover_mutex_);
    ids = handed_;
    handover_.total = 0;
    for (int id : ids) handover_.total += static_cast<long>(manager_->view().frames(id).size());
    handover_.sent = handover_.without_features = 0;
    ++handover_.subscribers;
  }
  const auto start = std::chrono::steady_clock::now();
  long sent = 0, failed = 0;
  for (int id : ids) {
    MutexLock lock(&mutex_);
    {
      MutexLock h(&handover_mutex_);
      if (std::find(handed_.begin(), handed_.end(), id) == handed_.end()) continue;  // unloaded meanwhile
    }
    ReloadedSession r;
    r.id = id;
    r.camera = manager_->view().camera(id);
    try {
      r.keyframes = manager_->view().storedHashes(id);
    } catch (const std::exception& e) {
      ++failed;
      say(Severity::kError, "stored session " + std::to_string(id) + " not sent to " + to + ": " + e.what());
      continue;
    }
    for (StoredKeyframe& k : r.keyframes) {
      if (!options_.page_stored) {  // paging: hashes only, the loop detector asks keyframe_features
        try {
          const StoredKeyframe f = manager_->view().storedFeatures(id, k.keyframe);
          k.points = f.points;
          k.descriptors = f.descriptors;
          k.image_size = f.image_size;
        } catch (const std::exception& e) {  // sent without features: no candidate, as a keyframe never received
          ++failed;
          say(Severity::kWarn, "stored keyframe " + std::to_string(id) + "/" + std::to_string(k.keyframe) +
                                   " sent without features: " + e.what());
        }
      }
      send(r, k);
      ++sent;
    }
    MutexLock h(&handover_mutex_);
    handover_.sent = sent;
  }
  MutexLock h(&handover_mutex_);
  handover_.without_features = failed;
  handover_.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (!ids.empty()) {
    char line[200];
    std::snprintf(line, sizeof line, "%ld stored keyframes of %zu sessions sent to ", sent, ids.size());
    char tail[100];
    std::snprintf(tail, sizeof tail, " in %.1f s (%ld without features)", handover_.seconds, failed);
    say(Severity::kInfo, line + to + tail);
  }
  return handover_;
}

void SessionWorker::forgetHandedOver(int session) {
  MutexLock h(&handover_mutex_);
  handed_.erase(std::remove(handed_.begin(), handed_.end(), session), handed_.end());
}

HandoverStats SessionWorker::handoverStats() const {
  MutexLock h(&handover_mutex_);
  return handover_;
}

std::vector<int> SessionWorker::handedOver() const {
  MutexLock h(&handover_mutex_);
  return handed_;
}

Status SessionWorker::keyframeFeatures(int session, int keyframe, bool check_only, KeyframeFeaturesAnswer* out) const {
  if (session < 0 || session > kMaxSessionId)
    return {StatusCode::kInvalidArgument, "keyframe_features names session " + std::to_string(session) +
                                              ", outside the ids [0, " + std::to_string(kMaxSessionId) + "]"};
  if (keyframe < 0)
    return {StatusCode::kInvalidArgument,
            "keyframe_features: keyframe ids are >= 0 (got " + std::to_string(keyframe) + ")"};
  MutexLock lock(&mutex_);
  const SessionQueries& m = manager_->view();
  if (m.has(session) && !m.vehicleOf(session).empty()) {  // another vehicle's: that vehicle has the features
    out->vehicle = m.vehicleOf(session);
    out->remote_session = m.remoteIdOf(session);
    return Status::Ok();
  }
  const bool no_store = !m.hasStore();
  if (check_only) {  // whether it is there: a loop detector about to page a live keyframe out
    if (no_store) return {StatusCode::kFailedPrecondition, "no session store"};
    if (m.inStore(session, keyframe)) return Status::Ok();
    return {StatusCode::kNotFound, "keyframe " + std::to_string(keyframe) + " of session " + std::to_string(session) +
                                       " is not in the store (yet)"};
  }
  if (!m.has(session)) return {StatusCode::kNotFound, "no session " + std::to_string(session) + " (see list_sessions)"};
  out->session.id = session;
  out->session.camera = m.camera(session);
  try {
    out->keyframe = m.storedFeatures(session, keyframe);
  } catch (const std::exception& e) {
    // No store; a keyframe not (yet) in it; an unreadable record.
    const bool stored = !no_store && m.inStore(session, keyframe);
    return {no_store ? StatusCode::kFailedPrecondition
            : stored ? StatusCode::kDataLoss
                     : StatusCode::kNotFound,
            e.what()};
  }
  out->keyframe.thumbnail.clear();
  return Status::Ok();
}

}  // namespace core
}  // namespace uw_multislam
