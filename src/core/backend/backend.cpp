#include "uw_multislam/core/backend/backend.h"

#include <Eigen/Dense>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <set>
#include <sstream>
#include <stdexcept>

#include "uw_multislam/core/backend/iekf_optimizer.h"
#include "uw_multislam/core/backend/pose_graph_optimizer.h"

namespace uw_multislam {
namespace core {

std::string defaultSessionName(int id) { return "session_" + std::to_string(id); }

const char* optimizerName(OptimizerKind k) { return k == OptimizerKind::kIekf ? "iekf" : "sparse"; }

bool parseOptimizer(const std::string& name, OptimizerKind* out) {
  if (name == "iekf")
    *out = OptimizerKind::kIekf;
  else if (name == "sparse")
    *out = OptimizerKind::kSparse;
  else
    return false;
  return true;
}

const char* joinPolicyName(JoinPolicy p) { return p == JoinPolicy::kCount ? "count" : "consistent"; }

bool parseJoinPolicy(const std::string& name, JoinPolicy* out) {
  if (name == "count")
    *out = JoinPolicy::kCount;
  else if (name == "consistent")
    *out = JoinPolicy::kConsistent;
  else
    return false;
  return true;
}

std::string BackendOptions::validate() const {
  // Named by their keys in the configuration's backend block (iekf.*, sparse.*, consistency.*).
  std::string bad = iekf.validate();
  if (!bad.empty()) return "iekf." + bad;
  bad = sparse.validate();
  if (!bad.empty()) return "sparse." + bad;
  if (optimise_every < 1) return "optimise_every must be >= 1";
  if (join_min_loops < 0) return "join_min_loops must be >= 0 (0 = no automatic joining)";
  if (!(join_gate_m > 0)) return "join_gate_m must be positive";
  if (max_keyframes < 2) return "iekf.max_keyframes must be >= 2";
  if (join_min_consistent < 1) return "join_min_consistent must be >= 1";
  if (!(intra_gate_inflation >= 1 && std::isfinite(intra_gate_inflation))) return "intra_gate_inflation must be >= 1";
  if (!(iekf_gate_inflation >= 1 && std::isfinite(iekf_gate_inflation))) return "iekf_gate_inflation must be >= 1";
  if (!(residual_gate_inflation >= 1 && std::isfinite(residual_gate_inflation)))
    return "residual_gate_inflation must be >= 1";
  if (join_min_inliers < 0) return "join_min_inliers must be >= 0";
  if (!(join_min_spread_m >= 0 && std::isfinite(join_min_spread_m))) return "join_min_spread_m must be >= 0";
  bad = consistency.validate();
  if (!bad.empty()) return "consistency." + bad;
  return {};
}

std::unique_ptr<MapOptimizer> makeMapOptimizer(const BackendOptions& o) {
  const std::string bad = o.validate();
  if (!bad.empty()) throw std::invalid_argument("backend: " + bad);
  PoseGraphOptimizer sparse(o.sparse, o.intra_gate_inflation);
  if (!o.optimise || o.optimizer == OptimizerKind::kSparse) return std::make_unique<PoseGraphOptimizer>(sparse);
  return std::make_unique<IekfOptimizer>(o.iekf, o.max_keyframes, o.iekf_gate_inflation, sparse);
}

namespace {

std::string describe(const Pose2& p) {
  char buf[96];
  std::snprintf(buf, sizeof buf, "(%.3f m, %.3f m, %.4f rad)", p.x(), p.y(), p.yaw());
  return buf;
}

// The squared Mahalanobis distance of a loop's measurement from its prediction in a solution,
// under the residual gate's covariance (the loop's, inflated, plus the floors).
double residualDistance2(const Pose2& predicted, const UncertainPose2& z, const OptimisationJob& job) {
  return mahalanobis2(between(predicted, z.mean), job.residual_gate_inflation * z.covariance, job.residual_gate_floors);
}

// The index of the loop with the largest distance beyond the job's residual gate, or -1.
int worstBeyondGate(const std::vector<double>& d2, double gate) {
  int worst = -1;
  for (int k = 0; k < static_cast<int>(d2.size()); ++k)
    if (d2[k] > gate && (worst < 0 || d2[k] > d2[worst])) worst = k;
  return worst;
}

}  // namespace

MultiSessionBackend::MultiSessionBackend(const BackendOptions& options, std::unique_ptr<MapOptimizer> optimizer,
                                         Log log)
    : options_(options), optimizer_(std::move(optimizer)), log_(std::move(log)) {
  const std::string bad = options.validate();
  if (!bad.empty()) throw std::invalid_argument("backend: " + bad);
  if (!optimizer_) throw std::invalid_argument("backend: no optimiser");
}

MultiSessionBackend::MultiSessionBackend(const BackendOptions& options, Log log)
    : MultiSessionBackend(options, makeMapOptimizer(options), std::move(log)) {}

void MultiSessionBackend::say(const std::string& line) const {
  if (log_) log_(line);
}

const MultiSessionBackend::Session& MultiSessionBackend::sessionAt(int s) const {
  if (!hasSession(s)) throw std::invalid_argument("backend: no session " + std::to_string(s));
  return sessions_[s];
}

MultiSessionBackend::Map& MultiSessionBackend::mapAt(int id) { return maps_.at(id); }
const MultiSessionBackend::Map& MultiSessionBackend::mapAt(int id) const { return maps_.at(id); }

int MultiSessionBackend::offset(const Map& m, int session) const {
  int o = 0;
  for (int s : m.chain) {
    if (s == session) return o;
    o += sessions_[s].keyframes();
  }
  throw std::logic_error("backend: session not in its map's chain");
}

int MultiSessionBackend::startSession(const std::string& name) {
  const int id = numSessions();
  Session s;
  s.name = name.empty() ? defaultSessionName(id) : name;
  s.recording = true;
  s.map = id;
  sessions_.push_back(s);
  Map m;
  m.chain = {id};
  m.estimate = optimizer_->start();
  maps_.emplace(id, std::move(m));
  return id;
}

void MultiSessionBackend::endSession(int session) {
  sessionAt(session);
  sessions_[session].recording = false;
  Map& m = mapAt(mapOf(session));
  if (m.pending > 0) optimise(mapOf(session));
  // Joins postponed while both maps held a recording session (two vehicles' sessions growing side
  // by side) are tried again now that one has ended: the loops between them
  // arrived while the join could not be made, and no new loop may come to trigger it.
  bool joined = true;
  while (joined) {
    joined = false;
    std::set<int> others;
    for (const LoopRecord& r : loops_) {
      const int ma = mapOf(r.loop.session_a), mb = mapOf(r.loop.session_b);
      if (ma == mb || barred(r.loop.session_a, r.loop.session_b)) continue;
      // Only maps still recording: a join with a finished map was already tried with these loops.
      if (ma == mapOf(session) && holdsRecording(mb)) others.insert(mb);
      if (mb == mapOf(session) && holdsRecording(ma)) others.insert(ma);
    }
    for (int other : others)
      if (tryAutomaticJoin(mapOf(session), other)) {
        joined = true;  // the maps changed: the candidates are found again
        break;
      }
  }
}

void MultiSessionBackend::addMotion(int session, const UncertainPose2& motion) {
  const Session& s = sessionAt(session);
  if (!s.recording) throw std::invalid_argument("backend: session " + std::to_string(session) + " is not recording");
  if (const std::string bad = checkUncertainPose(motion); !bad.empty())
    throw std::invalid_argument("backend: motion: " + bad);
  Map& m = mapAt(s.map);
  if (m.chain.back() != session) throw std::logic_error("backend: a recording session is not at the end of its map");
  std::string note;
  optimizer_->addMotion(&m.estimate, motion, &note);
  if (!note.empty()) say("map " + std::to_string(m.chain.front()) + ": " + note);
  touch(m);
  sessions_[session].odometry.push_back(motion);
}

void MultiSessionBackend::addLoop(const BackendLoop& l) {
  auto check = [&](int s, int k) {
    if (!hasSession(s)) throw std::invalid_argument("backend: loop: no session " + std::to_string(s));
    if (k < 0 || k >= sessions_[s].keyframes())
      throw std::invalid_argument("backend: loop: session " + std::to_string(s) + " has no keyframe " +
                                  std::to_string(k));
  };
  check(l.session_a, l.keyframe_a);
  check(l.session_b, l.keyframe_b);
  if (l.session_a == l.session_b && l.keyframe_a == l.keyframe_b)
    throw std::invalid_argument("backend: loop from a keyframe to itself");
  if (const std::string bad = checkUncertainPose(l.z, true); !bad.empty())
    throw std::invalid_argument("backend: loop: " + bad);
  loops_.push_back({l, false, false, false});
  ++stats_.loops;
  const int ma = mapOf(l.session_a), mb = mapOf(l.session_b);
  if (ma == mb) {
    Map& m = mapAt(ma);
    if (options_.intra_loop_gate) {
      // The loop against the map's estimate of the pose of b in a, with the covariance its
      // optimiser gates against (MapOptimizer::gateChain).
      const int ia = indexOf(l.session_a, l.keyframe_a), ib = indexOf(l.session_b, l.keyframe_b);
      const UncertainPose2 chain = optimizer_->gateChain(m.estimate, ia, ib, navPlacedMotions(m));
      const Pose2 e = between(chain.mean, l.z.mean);
      const double d2 = mahalanobis2(e, chain.covariance + l.z.covariance, options_.consistency);
      if (!(d2 <= chiSquare3Quantile(options_.consistency.confidence))) {
        loops_.back().refused = true;
        ++stats_.loops_refused;
        ++stats_.loops_gated;
        std::ostringstream os;
        os << "loop " << l.session_a << ":" << l.keyframe_a << " -> " << l.session_b << ":" << l.keyframe_b
           << " refused: it disagrees with map " << ma << " by " << e.translation().norm() << " m, "
           << std::abs(normalizeAngle(e.yaw())) << " rad (chi-square " << d2 << ")";
        say(os.str());
        return;
      }
    }
    ++m.pending;
    touch(m);
    if (options_.optimise && m.pending >= options_.optimise_every) optimise(ma);
    return;
  }
  if (!barred(l.session_a, l.session_b)) tryAutomaticJoin(ma, mb);
}

bool MultiSessionBackend::tryAutomaticJoin(int ma, int mb) {
  // The count policy waits for K loops; the consistency policy tries from its minimum set on
  // (join_min_loops 0 turns automatic joining off for both).
  const int needed =
      options_.join_policy == JoinPolicy::kCount ? options_.join_min_loops : options_.join_min_consistent;
  if (!automatic_joins_ || options_.join_min_loops <= 0 || static_cast<int>(loopsBetween(ma, mb, true).size()) < needed)
    return false;
  // Both growing (two vehicles' sessions side by side): not a refusal; endSession tries again.
  if (holdsRecording(ma) && holdsRecording(mb)) return false;
  const BackendStatus st = joinMaps(ma, mb, needed, true);
  if (st.ok()) return true;
  if (options_.join_policy == JoinPolicy::kConsistent) {
    ++stats_.joins_refused;
    stats_.last_join_refusal = "maps " + std::to_string(ma) + " and " + std::to_string(mb) + ": " + st.message;
  }
  say("automatic join of maps " + std::to_string(ma) + " and " + std::to_string(mb) + " postponed: " + st.message);
  return false;
}

void MultiSessionBackend::flush() {
  for (auto& [id, m] : maps_)
    if (m.pending > 0) optimiseNow(id);
}

int MultiSessionBackend::optimisePending() {
  if (!options_.optimise) return 0;
  std::vector<int> ids;
  for (const auto& [id, m] : maps_)
    if (m.pending > 0) ids.push_back(id);
  for (int id : ids) optimise(id);
  return static_cast<int>(ids.size());
}

bool MultiSessionBackend::holdsRecording(int map) const {
  for (int s : mapAt(map).chain)
    if (sessions_[s].recording) return true;
  return false;
}

bool MultiSessionBackend::barred(int sa, int sb) const {
  return split_pairs_.count({std::min(sa, sb), std::max(sa, sb)}) > 0;
}

std::vector<int> MultiSessionBackend::loopsBetween(int map_a, int map_b, bool automatic) const {
  std::vector<int> ids;
  for (int k = 0; k < static_cast<int>(loops_.size()); ++k) {
    const LoopRecord& st = loops_[k];
    if (st.summarised || st.refused) continue;
    const int ma = mapOf(st.loop.session_a), mb = mapOf(st.loop.session_b);
    if (!((ma == map_a && mb == map_b) || (ma == map_b && mb == map_a))) continue;
    if (automatic && (barred(st.loop.session_a, st.loop.session_b) || st.loop.nav_placement)) continue;
    ids.push_back(k);
  }
  return ids;
}

int MultiSessionBackend::pendingJoinLoops(int session_a, int session_b) const {
  const int ma = mapOf(session_a), mb = mapOf(session_b);
  return ma == mb ? 0 : static_cast<int>(loopsBetween(ma, mb, false).size());
}

std::uint64_t MultiSessionBackend::nextRevision() {
  static std::atomic<std::uint64_t> next{1};
  return next++;
}

void MultiSessionBackend::optimise(int map_id) {
  Map& m = mapAt(map_id);
  if (!options_.optimise) {
    m.pending = 0;
    return;
  }
  if (deferred_) {
    due_.insert(map_id);
    return;
  }
  optimiseNow(map_id);
}

void MultiSessionBackend::optimiseNow(int map_id) {
  if (!options_.optimise) {
    mapAt(map_id).pending = 0;
    return;
  }
  OptimisationJob job = prepareOptimisation(map_id);
  solveOptimisation(&job);
  if (!applyOptimisation(job)) throw std::logic_error("backend: a map changed during its own optimisation");
}

std::vector<int> MultiSessionBackend::dueMaps() const {
  std::vector<int> ids;
  for (int id : due_) {
    const auto it = maps_.find(id);
    if (it != maps_.end() && it->second.pending > 0) ids.push_back(id);
  }
  return ids;
}

BackendStatus MultiSessionBackend::addPositionPrior(int s, int keyframe, const Eigen::Vector2d& position,
                                                    const Eigen::Matrix2d& covariance) {
  if (!hasSession(s)) return {StatusCode::kInvalidArgument, "position prior: no session " + std::to_string(s)};
  if (keyframe < 0 || keyframe >= sessions_[s].keyframes())
    return {StatusCode::kInvalidArgument,
            "position prior: session " + std::to_string(s) + " has no keyframe " + std::to_string(keyframe)};
  const int map_id = mapOf(s);
  Map& m = mapAt(map_id);
  const int index = indexOf(s, keyframe);
  if (index == 0)
    return {StatusCode::kFailedPrecondition, "position prior: keyframe " + std::to_string(keyframe) + " of session " +
                                                 std::to_string(s) + " is map " + std::to_string(map_id) +
                                                 "'s origin (its frame, fixed)"};
  if (const std::string bad = checkPositionPrior({index, position, covariance}, m.numMotions() + 1); !bad.empty())
    return {StatusCode::kInvalidArgument, "position prior: " + bad};
  // One per keyframe: fixes a fraction of a second apart share most of their error (a GPS's is
  // correlated over seconds), and ten of them would count as ten independent ones.
  for (const PriorRecord& p : priors_)
    if (p.session == s && p.keyframe == keyframe)
      return {StatusCode::kAlreadyExists, "position prior: keyframe " + std::to_string(keyframe) + " of session " +
                                              std::to_string(s) + " has one already (one fix per keyframe)"};
  priors_.push_back({s, keyframe, position, covariance, false});
  ++stats_.priors;
  ++m.pending;
  touch(m);
  optimise(map_id);  // a fix is rare and absolute: not held back for optimise_every
  return BackendStatus::Ok();
}

BackendStatus MultiSessionBackend::restorePositionPrior(const PriorRecord& r) {
  if (!hasSession(r.session) || r.keyframe < 0 || r.keyframe >= sessions_[r.session].keyframes())
    return {StatusCode::kInvalidArgument,
            "position prior: no keyframe " + std::to_string(r.keyframe) + " of session " + std::to_string(r.session)};
  const Map& m = mapAt(mapOf(r.session));
  if (const std::string bad =
          checkPositionPrior({indexOf(r.session, r.keyframe), r.position, r.covariance}, m.numMotions() + 1);
      !bad.empty())
    return {StatusCode::kInvalidArgument, "position prior: " + bad};
  priors_.push_back(r);
  return BackendStatus::Ok();
}

std::vector<Pose2> MultiSessionBackend::priorOrigins() const {
  std::vector<Pose2> origins;
  for (const PriorRecord& p : priors_) origins.push_back(sessionPoses(p.session).front());
  return origins;
}

void MultiSessionBackend::rebasePriors(const std::vector<Pose2>& before) {
  for (std::size_t k = 0; k < priors_.size(); ++k) {
    PriorRecord& p = priors_[k];
    // new <- old = (new <- session origin) (session origin <- old): the session's own poses
    // relative to its origin are what a join or a split keeps.
    const Pose2 t = compose(sessionPoses(p.session).front(), invert(before[k]));
    const Eigen::Matrix2d r = t.rotation();
    p.position = r * p.position + t.translation();
    p.covariance = r * p.covariance * r.transpose();
  }
}

MapGraph MultiSessionBackend::graphOf(int map_id, std::vector<int>* prior_ids) const {
  const Map& m = mapAt(map_id);
  MapGraph g;
  int o = 0;
  for (std::size_t c = 0; c < m.chain.size(); ++c) {
    const Session& s = sessions_[m.chain[c]];
    for (int k = 1; k < s.keyframes(); ++k) g.chain.push_back({o + k - 1, o + k, s.odometry[k - 1], false});
    o += s.keyframes();
    if (c + 1 < m.chain.size()) g.chain.push_back({o - 1, o, m.links[c].measured, false});
  }
  for (int id = 0; id < static_cast<int>(loops_.size()); ++id) {
    const LoopRecord& st = loops_[id];
    if (st.summarised || st.refused) continue;
    if (mapOf(st.loop.session_a) != map_id || mapOf(st.loop.session_b) != map_id) continue;
    g.loops.push_back({id, indexOf(st.loop.session_a, st.loop.keyframe_a),
                       indexOf(st.loop.session_b, st.loop.keyframe_b), st.loop.z});
    g.applied.push_back(st.applied);
  }
  prior_ids->clear();
  for (int id = 0; id < static_cast<int>(priors_.size()); ++id) {
    const PriorRecord& p = priors_[id];
    if (mapOf(p.session) != map_id) continue;
    const int index = indexOf(p.session, p.keyframe);
    if (index == 0) continue;  // its session became the map's first (a split): the map's frame is fixed there
    g.priors.push_back({index, p.position, p.covariance});
    g.priors_applied.push_back(p.applied);
    prior_ids->push_back(id);
  }
  return g;
}

OptimisationJob MultiSessionBackend::prepareOptimisation(int map_id) const {
  chain(map_id);  // throws for an unknown map
  const Map& m = mapAt(map_id);
  OptimisationJob job;
  job.map = map_id;
  job.revision = m.revision;
  if (options_.loop_residual_gate) {
    job.residual_gate_chi2 = chiSquare3Quantile(options_.consistency.confidence);
    job.residual_gate_inflation = options_.residual_gate_inflation;
    job.residual_gate_floors = options_.consistency;
    // The refused loops inside the map, candidates to be taken back after the solve.
    for (int id = 0; options_.readmit_refused_loops && id < static_cast<int>(loops_.size()); ++id) {
      const LoopRecord& st = loops_[id];
      if (st.refused && !st.summarised && !st.applied && mapOf(st.loop.session_a) == map_id &&
          mapOf(st.loop.session_b) == map_id)
        job.refused.push_back({id, indexOf(st.loop.session_a, st.loop.keyframe_a),
                               indexOf(st.loop.session_b, st.loop.keyframe_b), st.loop.z});
    }
  }
  job.problem = optimizer_->prepare(m.estimate, graphOf(map_id, &job.priors), &job.loops);
  return job;
}

void MultiSessionBackend::solveOptimisation(OptimisationJob* job) {
  const auto t0 = std::chrono::steady_clock::now();
  const bool gate = job->residual_gate_chi2 > 0.0;
  // Solve; with the residual gate, switch off the loop that disagrees most with the solution and
  // solve again from the same start, until none is beyond the gate (loop_residual_gate). Then
  // take back the refused loops that agree with that solution (readmit_refused_loops) and solve
  // again; each refused loop is taken back at most once per job, so this ends.
  std::vector<bool> tried(job->refused.size(), false);
  MapProblem* problem = job->problem.get();
  auto distance2 = [&](const MapLoop& l) { return residualDistance2(problem->relative(l.i, l.j), l.z, *job); };
  while (problem) {
    if (job->loops.empty()) problem->solve(job->loops);  // a problem without loops has priors: solved with them alone
    while (!job->loops.empty()) {
      problem->solve(job->loops);
      if (!gate) break;
      std::vector<double> d2;
      for (const MapLoop& l : job->loops) d2.push_back(distance2(l));
      const int worst = worstBeyondGate(d2, job->residual_gate_chi2);
      if (worst < 0) break;
      job->switched_off.push_back(job->loops[worst].id);
      job->switched_off_chi2.push_back(d2[worst]);
      job->loops.erase(job->loops.begin() + worst);
      if (job->loops.empty()) {
        if (job->priors.empty())
          problem->reset();
        else
          problem->solve(job->loops);  // the priors alone
      }
    }
    // The refused loops within the gate of the solution.
    bool back = false;
    for (std::size_t k = 0; gate && k < tried.size(); ++k) {
      if (tried[k]) continue;
      const double d2 = distance2(job->refused[k]);
      if (!(d2 <= job->residual_gate_chi2)) continue;
      tried[k] = back = true;
      job->readmitted.push_back(job->refused[k].id);
      job->readmitted_chi2.push_back(d2);
      job->loops.push_back(job->refused[k]);
    }
    if (!back) break;
  }
  // A loop taken back and switched off again in the same job stays as it was: refused.
  for (std::size_t k = job->readmitted.size(); k-- > 0;) {
    const auto off = std::find(job->switched_off.begin(), job->switched_off.end(), job->readmitted[k]);
    if (off == job->switched_off.end()) continue;
    job->switched_off_chi2.erase(job->switched_off_chi2.begin() + (off - job->switched_off.begin()));
    job->switched_off.erase(off);
    job->readmitted.erase(job->readmitted.begin() + static_cast<std::ptrdiff_t>(k));
    job->readmitted_chi2.erase(job->readmitted_chi2.begin() + static_cast<std::ptrdiff_t>(k));
  }
  job->solve_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  job->solved = true;
}

bool MultiSessionBackend::applyOptimisation(const OptimisationJob& job) {
  if (!job.solved) throw std::invalid_argument("backend: applyOptimisation of a job that was not solved");
  const auto it = maps_.find(job.map);
  if (it == maps_.end() || it->second.revision != job.revision) {
    ++stats_.optimisations_discarded;
    return false;
  }
  Map& m = it->second;
  for (std::size_t k = 0; k < job.switched_off.size(); ++k) {
    LoopRecord& st = loops_[job.switched_off[k]];
    st.refused = true;
    ++stats_.loops_refused;
    ++stats_.loops_switched_off;
    std::ostringstream os;
    os << "loop " << st.loop.session_a << ":" << st.loop.keyframe_a << " -> " << st.loop.session_b << ":"
       << st.loop.keyframe_b << " switched off: it disagrees with map " << job.map << "'s solution (chi-square "
       << job.switched_off_chi2[k] << " > " << job.residual_gate_chi2 << ")";
    say(os.str());
  }
  for (std::size_t k = 0; k < job.readmitted.size(); ++k) {
    LoopRecord& st = loops_[job.readmitted[k]];
    st.refused = false;
    ++stats_.loops_readmitted;
    std::ostringstream os;
    os << "loop " << st.loop.session_a << ":" << st.loop.keyframe_a << " -> " << st.loop.session_b << ":"
       << st.loop.keyframe_b << " taken back: refused before, it agrees with map " << job.map
       << "'s solution (chi-square " << job.readmitted_chi2[k] << " <= " << job.residual_gate_chi2 << ")";
    say(os.str());
  }
  if (job.problem && job.problem->apply(&m.estimate)) {
    for (const MapLoop& l : job.loops) loops_[l.id].applied = true;
    for (int id : job.priors) priors_[id].applied = true;
  }
  m.pending = 0;
  touch(m);
  due_.erase(job.map);
  ++stats_.optimisations;
  stats_.optimise_ms_total += job.solve_ms;
  stats_.optimise_ms_max = std::max(stats_.optimise_ms_max, job.solve_ms);
  return true;
}

BackendStatus MultiSessionBackend::join(int session_a, int session_b, int min_loops) {
  for (int s : {session_a, session_b})
    if (!hasSession(s))
      return {StatusCode::kNotFound, "no session " + std::to_string(s) + " (there are " +
                                         std::to_string(numSessions()) + "; see list_sessions)"};
  if (min_loops < 0) return {StatusCode::kInvalidArgument, "min_loops must be >= 0 (0: the configured rule)"};
  // 0: the configured rule, with its support (the count policy's K, at least 1; the consistency
  // policy's minimum set, inliers and spread); > 0: the caller's count, in the consistent set.
  const bool rule = min_loops == 0;
  const int k = !rule                                        ? min_loops
                : options_.join_policy == JoinPolicy::kCount ? std::max(1, options_.join_min_loops)
                                                             : std::max(1, options_.join_min_consistent);
  return joinMaps(mapOf(session_a), mapOf(session_b), k, false, !rule);
}

MultiSessionBackend::LinkEstimate MultiSessionBackend::estimateLink(int first, int second, const std::vector<int>& ids,
                                                                    int min_loops, JoinPolicy policy,
                                                                    bool spread_in_first, bool requested) const {
  LinkEstimate e;
  auto failed = [&e](const std::string& why) {
    e.status = {StatusCode::kFailedPrecondition, why};
    return e;
  };
  const Map& p = mapAt(first);
  const Map& c = mapAt(second);
  Trajectory tp, tc;  // the two chains with their motions' covariances
  for (int k = 0; k < p.numMotions(); ++k) tp.append(UncertainPose2(p.motion(k), p.motionCov(k)));
  for (int k = 0; k < c.numMotions(); ++k) tc.append(UncertainPose2(c.motion(k), c.motionCov(k)));
  const int pe = static_cast<int>(tp.numKeyframes()) - 1;

  struct Candidate {
    int id;
    UncertainPose2 pe_from_pi, ci_from_cs, z;
  };
  std::vector<Candidate> cand;
  for (int id : ids) {
    const BackendLoop& l = loops_[id].loop;
    const bool a_first = mapOf(l.session_a) == first;
    const int pi = a_first ? indexOf(l.session_a, l.keyframe_a) : indexOf(l.session_b, l.keyframe_b);
    const int ci = a_first ? indexOf(l.session_b, l.keyframe_b) : indexOf(l.session_a, l.keyframe_a);
    cand.push_back({id, tp.relative(pi, pe), tc.relative(0, ci), a_first ? l.z : invert(l.z)});
  }
  std::vector<bool> in(cand.size(), true);
  JoinResult res;
  if (policy == JoinPolicy::kConsistent) {
    // The largest pairwise-consistent set, if it is big, strong and spread enough; the link from it.
    std::vector<CrossLoop> cl;
    for (int id : ids) {
      const BackendLoop& l = loops_[id].loop;
      const bool a_first = mapOf(l.session_a) == first;
      cl.push_back({a_first ? indexOf(l.session_a, l.keyframe_a) : indexOf(l.session_b, l.keyframe_b),
                    a_first ? indexOf(l.session_b, l.keyframe_b) : indexOf(l.session_a, l.keyframe_a),
                    a_first ? l.z : invert(l.z), l.inliers});
    }
    const ConsistentSet set = largestConsistentSet(cl, tp, tc, options_.consistency);
    const double spread_m = spread_in_first ? set.spread_previous_m : set.spread_m;
    std::ostringstream why;
    why << "the largest consistent set of the " << cand.size() << " global loops between map " << first << " and map "
        << second << " (" << set.consistent_pairs << " of " << set.pairs << " pairs consistent) has "
        << set.loops.size() << " loops, " << set.inliers << " inliers, spread " << spread_m << " m; needed "
        << min_loops << " loops";
    if (!requested) why << ", " << options_.join_min_inliers << " inliers, " << options_.join_min_spread_m << " m";
    const bool supported =
        requested || (set.inliers >= options_.join_min_inliers && spread_m >= options_.join_min_spread_m);
    if (set.loops.empty() || static_cast<int>(set.loops.size()) < min_loops || !supported) return failed(why.str());
    std::fill(in.begin(), in.end(), false);
    std::vector<JoinLoop> jl;
    for (int k : set.loops) {
      in[k] = true;
      jl.push_back({cand[k].pe_from_pi.mean, cand[k].ci_from_cs.mean, cand[k].z});
    }
    res = estimateJoinLink(jl, options_.iekf);
  }
  // Count policy: estimate, refuse loops whose position disagrees by more than the gate,
  // re-estimate with the rest; a few rounds.
  for (int round = 0; policy == JoinPolicy::kCount && round < 4; ++round) {
    std::vector<JoinLoop> jl;
    for (std::size_t k = 0; k < cand.size(); ++k)
      if (in[k]) jl.push_back({cand[k].pe_from_pi.mean, cand[k].ci_from_cs.mean, cand[k].z});
    if (static_cast<int>(jl.size()) < min_loops) {
      return failed(std::to_string(jl.size()) + " of the " + std::to_string(cand.size()) +
                    " global loops between map " + std::to_string(first) + " and map " + std::to_string(second) +
                    " agree, " + std::to_string(min_loops) + " needed");
    }
    res = estimateJoinLink(jl, options_.iekf);
    bool changed = false;
    for (std::size_t k = 0; k < cand.size(); ++k) {
      const Pose2 pred = compose(compose(cand[k].pe_from_pi.mean, res.link.mean), cand[k].ci_from_cs.mean);
      const bool ok = poseError(cand[k].z.mean, pred).head<2>().norm() <= options_.join_gate_m;
      if (ok != in[k]) changed = true;
      in[k] = ok;
    }
    if (!changed) break;
  }
  e.in = in;
  e.result = res;
  for (std::size_t k = 0; k < cand.size(); ++k)
    if (in[k]) {
      ++e.used;
      e.inliers += loops_[cand[k].id].loop.inliers;
    }
  return e;
}

BackendStatus MultiSessionBackend::joinMaps(int map_a, int map_b, int min_loops, bool automatic, bool requested) {
  if (map_a == map_b)
    return {StatusCode::kFailedPrecondition, "the sessions are already in the same map " + std::to_string(map_a)};
  const bool rec_a = holdsRecording(map_a), rec_b = holdsRecording(map_b);
  if (rec_a && rec_b)
    return {StatusCode::kFailedPrecondition, "maps " + std::to_string(map_a) + " and " + std::to_string(map_b) +
                                                 " both hold a recording session; join them after one ends"};
  const int first = rec_a ? map_b : rec_b ? map_a : std::min(map_a, map_b);
  const int second = first == map_a ? map_b : map_a;
  std::vector<int> ids = loopsBetween(first, second, automatic);
  if (static_cast<int>(ids.size()) < min_loops)
    return {StatusCode::kFailedPrecondition, std::to_string(ids.size()) + " global loops stored between map " +
                                                 std::to_string(first) + " and map " + std::to_string(second) + ", " +
                                                 std::to_string(min_loops) + " needed"};
  const LinkEstimate e = estimateLink(first, second, ids, min_loops, options_.join_policy, false, requested);
  if (!e.status.ok()) return e.status;
  const std::vector<Pose2> prior_origins = priorOrigins();
  const Map& p = mapAt(first);
  const Map& c = mapAt(second);
  const std::vector<bool>& in = e.in;
  const JoinResult& res = e.result;

  Map j;
  j.chain = p.chain;
  j.chain.insert(j.chain.end(), c.chain.begin(), c.chain.end());
  j.links = p.links;
  MapLinkState link{res.link, {}};
  int used = 0, refused = 0;
  for (std::size_t k = 0; k < ids.size(); ++k) {
    if (in[k]) {
      link.loops.push_back(ids[k]);
      ++used;
    } else {
      ++refused;
    }
  }
  j.links.push_back(link);
  j.links.insert(j.links.end(), c.links.begin(), c.links.end());
  std::string note;
  j.estimate = optimizer_->join(p.estimate, res.link, c.estimate, &note);
  if (!note.empty()) say("map " + std::to_string(first) + ": " + note);
  j.pending = p.pending + c.pending;
  for (std::size_t k = 0; k < ids.size(); ++k) {
    if (in[k]) {
      loops_[ids[k]].summarised = true;
    } else {
      loops_[ids[k]].refused = true;
      ++stats_.loops_refused;
    }
  }
  if (!automatic) {
    for (int a : p.chain)
      for (int b : c.chain) split_pairs_.erase({std::min(a, b), std::max(a, b)});
  }
  const int prev_session = p.chain.back(), cur_session = c.chain.front();
  MapChange change{true, p.chain, c.chain, link.loops, refused, {}};
  const bool was_due = due_.erase(first) + due_.erase(second) > 0;
  maps_.erase(second);
  Map& joined = maps_[first] = std::move(j);
  if (was_due) due_.insert(first);  // what it waited for is still pending in the joined map
  for (int s : joined.chain) sessions_[s].map = first;
  rebasePriors(prior_origins);  // second's priors: now in first's frame
  // Loops between the two maps that did not take part (barred ones) are now intra-map.
  for (const LoopRecord& st : loops_)
    if (!st.summarised && !st.refused && !st.applied && mapOf(st.loop.session_a) == first &&
        mapOf(st.loop.session_b) == first && barred(st.loop.session_a, st.loop.session_b))
      ++joined.pending;
  ++stats_.joins;
  std::ostringstream msg;
  msg << "joined map " << second << " to map " << first << ": link from the end of session " << prev_session
      << " to the start of session " << cur_session << " = " << describe(res.link.mean) << " from " << used
      << " global loops (rms " << res.rms_residual_m << " m";
  if (refused > 0) msg << ", " << refused << " inconsistent loops refused";
  msg << ")";
  say(msg.str());
  change.message = msg.str();
  changes_.push_back(std::move(change));
  if (options_.optimise && joined.pending >= options_.optimise_every) optimise(first);
  return {StatusCode::kOk, msg.str()};
}

std::optional<MultiSessionBackend::Relocalisation> MultiSessionBackend::relocalise(
    int s, const std::function<bool(int map)>& eligible) const {
  if (!hasSession(s)) return std::nullopt;
  const int mine = mapOf(s);
  std::optional<Relocalisation> best;
  for (const auto& [id, m] : maps_) {
    if (id == mine || (eligible && !eligible(id))) continue;
    const std::vector<int> ids = loopsBetween(id, mine, true);  // not across a split the user asked for
    if (static_cast<int>(ids.size()) < options_.join_min_consistent) continue;
    const LinkEstimate e = estimateLink(id, mine, ids, options_.join_min_consistent, JoinPolicy::kConsistent, true);
    if (!e.status.ok()) continue;
    if (best && (e.used < best->loops || (e.used == best->loops && e.inliers <= best->inliers))) continue;
    Relocalisation r;
    r.map = id;
    r.loops = e.used;
    r.inliers = e.inliers;
    // The end of the other map's chain in its frame, then the link to this map's first keyframe.
    UncertainPose2 end = UncertainPose2::exact(Pose2());
    for (int k = 0; k < m.numMotions(); ++k) end = compose(end, UncertainPose2(m.motion(k), m.motionCov(k)));
    r.origin = compose(end, e.result.link);
    r.keyframe = sessionAt(s).keyframes() - 1;
    r.pose = compose(r.origin, keyframeInMap(s, r.keyframe));
    best = r;
  }
  return best;
}

BackendStatus MultiSessionBackend::split(int session) {
  if (!hasSession(session))
    return {StatusCode::kNotFound, "no session " + std::to_string(session) + " (there are " +
                                       std::to_string(numSessions()) + "; see list_sessions)"};
  const int old_id = mapOf(session);
  const Map& m = mapAt(old_id);
  if (m.chain.size() == 1)
    return {StatusCode::kFailedPrecondition,
            "session " + std::to_string(session) + " is alone in its map: nothing to split"};
  const std::vector<Pose2> prior_origins = priorOrigins();
  const int q = static_cast<int>(std::find(m.chain.begin(), m.chain.end(), session) - m.chain.begin());
  const int last = static_cast<int>(m.chain.size()) - 1;
  const int o = offset(m, session), n = sessions_[session].keyframes();
  const int d = m.numMotions();
  // Motion k (0-based) reaches keyframe k + 1. The session's own motions are [o, o + n - 1); the
  // link into it is motion o - 1, the link out of it motion o + n - 1.
  Map alone;
  alone.chain = {session};
  alone.estimate = m.estimate.slice({{o, o + n - 1}});

  Map rest;
  std::vector<int> released;  // loops summarised by removed links that involve the session
  auto release = [&](const MapLinkState& l) {
    for (int id : l.loops) {
      const BackendLoop& lp = loops_[id].loop;
      if (lp.session_a == session || lp.session_b == session) released.push_back(id);
    }
  };
  if (q == 0) {
    rest.chain.assign(m.chain.begin() + 1, m.chain.end());
    rest.links.assign(m.links.begin() + 1, m.links.end());
    release(m.links[0]);
    rest.estimate = m.estimate.slice({{o + n, d}});
  } else if (q == last) {
    rest.chain.assign(m.chain.begin(), m.chain.end() - 1);
    rest.links.assign(m.links.begin(), m.links.end() - 1);
    release(m.links.back());
    rest.estimate = m.estimate.slice({{0, o - 1}});
  } else {
    rest.chain.assign(m.chain.begin(), m.chain.begin() + q);
    rest.chain.insert(rest.chain.end(), m.chain.begin() + q + 1, m.chain.end());
    // The composed link over motions [o - 1, o + n]: link in, the session, link out.
    MapLinkState composed;
    const MapLinkState& lin = m.links[q - 1];
    const MapLinkState& lout = m.links[q];
    release(lin);
    release(lout);
    for (const MapLinkState* l : {&lin, &lout})
      for (int id : l->loops)
        if (std::find(released.begin(), released.end(), id) == released.end()) composed.loops.push_back(id);
    rest.links.assign(m.links.begin(), m.links.begin() + q - 1);
    rest.estimate = m.estimate.slice({{0, o - 1}, {o - 1, o + n}, {o + n, d}}, 1);
    composed.measured = UncertainPose2(rest.motion(o - 1), rest.motionCov(o - 1));
    rest.links.push_back(composed);
    rest.links.insert(rest.links.end(), m.links.begin() + q + 1, m.links.end());
  }
  for (int id : released) {
    loops_[id].summarised = false;
    loops_[id].applied = false;
  }
  // Loops between the session and the rest that the IEKF had applied are inter-map again.
  for (LoopRecord& st : loops_) {
    const bool a_in = st.loop.session_a == session, b_in = st.loop.session_b == session;
    if (a_in != b_in && mapOf(st.loop.session_a) == old_id && mapOf(st.loop.session_b) == old_id) st.applied = false;
  }
  for (int t : rest.chain) split_pairs_.insert({std::min(session, t), std::max(session, t)});
  const int rest_id = rest.chain.front();
  if (due_.erase(old_id) > 0) due_.insert({session, rest_id});  // dueMaps() skips those with nothing pending
  maps_.erase(old_id);
  maps_[session] = std::move(alone);
  sessions_[session].map = session;
  maps_[rest_id] = std::move(rest);
  for (int s : maps_[rest_id].chain) sessions_[s].map = rest_id;
  rebasePriors(prior_origins);  // the session's own frame, and the rest's first session's
  ++stats_.splits;
  const std::string msg = "split session " + std::to_string(session) + " off map " + std::to_string(old_id) +
                          ": maps " + std::to_string(session) + " and " + std::to_string(rest_id) + ", " +
                          std::to_string(released.size()) + " global loops between them kept for a later join";
  say(msg);
  changes_.push_back({false, {session}, maps_[rest_id].chain, released, 0, msg});
  return {StatusCode::kOk, msg};
}

SessionInfo MultiSessionBackend::session(int s) const {
  const Session& x = sessionAt(s);
  return {s, x.name, x.recording, x.map, x.keyframes()};
}

std::vector<int> MultiSessionBackend::mapIds() const {
  std::vector<int> ids;
  for (const auto& [id, m] : maps_) ids.push_back(id);
  return ids;
}

const std::vector<int>& MultiSessionBackend::chain(int map) const {
  const auto it = maps_.find(map);
  if (it == maps_.end()) throw std::invalid_argument("backend: no map " + std::to_string(map));
  return it->second.chain;
}

std::vector<bool> MultiSessionBackend::navPlacedMotions(const Map& m) const {
  std::vector<bool> placed(static_cast<std::size_t>(m.numMotions()), false);
  for (std::size_t i = 0; i + 1 < m.chain.size(); ++i) {
    const std::vector<int>& ids = m.links[i].loops;
    const bool nav = !ids.empty() && std::all_of(ids.begin(), ids.end(), [&](int id) {
      return id >= 0 && id < static_cast<int>(loops_.size()) && loops_[id].loop.nav_placement;
    });
    if (nav) placed[offset(m, m.chain[i + 1]) - 1] = true;
  }
  return placed;
}

std::vector<LinkInfo> MultiSessionBackend::links(int map) const {
  chain(map);
  const Map& m = mapAt(map);
  std::vector<LinkInfo> out;
  for (std::size_t i = 0; i + 1 < m.chain.size(); ++i) {
    const int at = offset(m, m.chain[i + 1]) - 1;
    out.push_back(
        {m.chain[i], m.chain[i + 1], m.links[i].measured, m.motion(at), static_cast<int>(m.links[i].loops.size())});
  }
  return out;
}

std::vector<Pose2> MultiSessionBackend::sessionPoses(int s) const {
  const Map& m = mapAt(mapOf(s));
  const int o = offset(m, s), n = sessions_[s].keyframes();
  std::vector<Pose2> out;
  Pose2 x;
  for (int k = 0; k < o + n; ++k) {
    if (k > 0) x = compose(x, m.motion(k - 1));
    if (k >= o) out.push_back(x);
  }
  return out;
}

UncertainPose2 MultiSessionBackend::keyframeInMap(int s, int keyframe) const {
  const Session& session = sessionAt(s);
  if (keyframe < 0 || keyframe >= session.keyframes())
    throw std::invalid_argument("backend: session " + std::to_string(s) + " has no keyframe " +
                                std::to_string(keyframe));
  const Map& m = mapAt(session.map);
  UncertainPose2 x = UncertainPose2::exact(Pose2());
  for (int k = 0; k < offset(m, s) + keyframe; ++k) x = compose(x, UncertainPose2(m.motion(k), m.motionCov(k)));
  return x;
}

UncertainPose2 MultiSessionBackend::keyframeChain(int s, int from, int to) const {
  const Session& session = sessionAt(s);
  if (from < 0 || from > to || to >= session.keyframes())
    throw std::invalid_argument("backend: session " + std::to_string(s) + " has no chain from keyframe " +
                                std::to_string(from) + " to " + std::to_string(to));
  const Map& m = mapAt(session.map);
  UncertainPose2 x = UncertainPose2::exact(Pose2());
  for (int k = offset(m, s) + from; k < offset(m, s) + to; ++k)
    x = compose(x, UncertainPose2(m.motion(k), m.motionCov(k)));
  return x;
}

// --- Session store: export and exact restore ---------------------------------------------------

MapState MultiSessionBackend::mapState(int map) const {
  chain(map);
  const Map& m = mapAt(map);
  MapState st;
  st.chain = m.chain;
  st.links = m.links;
  for (int k = 0; k < m.numMotions(); ++k) st.motions.emplace_back(m.motion(k), m.motionCov(k));
  st.pending = m.pending;
  return st;
}

LoopRecord MultiSessionBackend::loopRecord(int id) const {
  if (id < 0 || id >= numLoops()) throw std::invalid_argument("backend: no loop " + std::to_string(id));
  return loops_[id];
}

int MultiSessionBackend::restoreSession(const std::string& name, const std::vector<UncertainPose2>& odometry) {
  for (std::size_t k = 0; k < odometry.size(); ++k) {
    if (const std::string bad = checkUncertainPose(odometry[k]); !bad.empty())
      throw std::invalid_argument("backend: restored session '" + name + "': motion " + std::to_string(k + 1) + ": " +
                                  bad);
  }
  const int id = numSessions();
  Session s;
  s.name = name.empty() ? defaultSessionName(id) : name;
  s.recording = false;
  s.map = id;
  s.odometry = odometry;
  sessions_.push_back(s);
  Map m;
  m.chain = {id};
  for (const UncertainPose2& u : odometry) m.estimate.append(u);
  m.estimate = optimizer_->adopt(std::move(m.estimate));
  maps_.emplace(id, std::move(m));
  return id;
}

BackendStatus MultiSessionBackend::removeSession(int s) {
  if (!hasSession(s)) return {StatusCode::kNotFound, "no session " + std::to_string(s)};
  if (sessions_[s].recording)
    return {StatusCode::kFailedPrecondition, "session " + std::to_string(s) + " is recording"};
  if (mapAt(sessions_[s].map).chain.size() != 1)
    return {StatusCode::kFailedPrecondition, "session " + std::to_string(s) + " shares map " +
                                                 std::to_string(sessions_[s].map) + " with other sessions"};
  auto shift = [s](int t) { return t > s ? t - 1 : t; };
  std::vector<int> new_id(loops_.size(), -1);
  std::vector<LoopRecord> kept;
  for (std::size_t i = 0; i < loops_.size(); ++i) {
    LoopRecord r = loops_[i];
    if (r.loop.session_a == s || r.loop.session_b == s) continue;
    r.loop.session_a = shift(r.loop.session_a);
    r.loop.session_b = shift(r.loop.session_b);
    new_id[i] = static_cast<int>(kept.size());
    kept.push_back(std::move(r));
  }
  const int removed_loops = static_cast<int>(loops_.size() - kept.size());
  loops_ = std::move(kept);
  std::vector<PriorRecord> priors;
  for (PriorRecord p : priors_) {
    if (p.session == s) continue;
    p.session = shift(p.session);
    priors.push_back(p);
  }
  priors_ = std::move(priors);
  due_.erase(s);
  maps_.erase(s);  // its own map (alone in it: the map's id is s)
  std::map<int, Map> maps;
  for (auto& [id, m] : maps_) {
    for (int& c : m.chain) c = shift(c);
    for (MapLinkState& l : m.links) {
      for (int& i : l.loops) i = new_id[i];
      l.loops.erase(std::remove(l.loops.begin(), l.loops.end(), -1), l.loops.end());
    }
    touch(m);
    maps.emplace(shift(id), std::move(m));
  }
  maps_ = std::move(maps);
  std::set<int> due;
  for (int d : due_) due.insert(shift(d));
  due_ = std::move(due);
  std::set<std::pair<int, int>> pairs;
  for (const auto& [a, b] : split_pairs_)
    if (a != s && b != s) pairs.insert({shift(a), shift(b)});
  split_pairs_ = std::move(pairs);
  const std::string name = sessions_[s].name;
  sessions_.erase(sessions_.begin() + s);
  for (Session& t : sessions_) t.map = shift(t.map);
  const std::string msg = "session " + std::to_string(s) + " '" + name + "' removed with its map and " +
                          std::to_string(removed_loops) + " loops";
  say(msg);
  return {StatusCode::kOk, msg};
}

int MultiSessionBackend::restoreLoop(const LoopRecord& r) {
  const BackendLoop& l = r.loop;
  for (const auto& [s, k] : {std::pair<int, int>{l.session_a, l.keyframe_a}, {l.session_b, l.keyframe_b}}) {
    if (!hasSession(s) || k < 0 || k >= sessions_[s].keyframes())
      throw std::invalid_argument("backend: restored loop: no keyframe " + std::to_string(k) + " in session " +
                                  std::to_string(s));
  }
  if (const std::string bad = checkUncertainPose(l.z); !bad.empty())
    throw std::invalid_argument("backend: restored loop: " + bad);
  loops_.push_back({l, r.summarised, r.applied, r.refused});
  ++stats_.loops;
  return numLoops() - 1;
}

BackendStatus MultiSessionBackend::restoreMap(const MapState& state) {
  if (state.chain.empty()) return {StatusCode::kInvalidArgument, "restored map: empty chain"};
  if (state.links.size() + 1 != state.chain.size())
    return {StatusCode::kInvalidArgument, "restored map: " + std::to_string(state.chain.size()) + " sessions need " +
                                              std::to_string(state.chain.size() - 1) + " links, got " +
                                              std::to_string(state.links.size())};
  int motions = static_cast<int>(state.links.size());
  for (int s : state.chain) {
    if (!hasSession(s)) return {StatusCode::kNotFound, "restored map: no session " + std::to_string(s)};
    if (sessions_[s].recording || mapAt(sessions_[s].map).chain.size() != 1)
      return {StatusCode::kFailedPrecondition,
              "restored map: session " + std::to_string(s) + " is recording or already in a map of several sessions"};
    motions += sessions_[s].keyframes() - 1;
  }
  if (!state.motions.empty() && static_cast<int>(state.motions.size()) != motions)
    return {StatusCode::kInvalidArgument, "restored map " + std::to_string(state.chain.front()) + ": " +
                                              std::to_string(state.motions.size()) + " motions, its chain has " +
                                              std::to_string(motions)};
  for (const MapLinkState& l : state.links)
    for (int id : l.loops)
      if (id < 0 || id >= numLoops())
        return {StatusCode::kNotFound, "restored map: a link summarises loop " + std::to_string(id) + ", not restored"};
  Map m;
  m.chain = state.chain;
  m.pending = state.pending;
  for (std::size_t c = 0; c < state.chain.size(); ++c) {
    if (state.motions.empty()) {
      const Map& own = mapAt(sessions_[state.chain[c]].map);
      for (int k = 0; k < own.numMotions(); ++k) m.estimate.append(UncertainPose2(own.motion(k), own.motionCov(k)));
      if (c + 1 < state.chain.size()) m.estimate.append(state.links[c].measured);
    }
    if (c + 1 < state.chain.size()) m.links.push_back({state.links[c].measured, state.links[c].loops});
  }
  for (const UncertainPose2& u : state.motions) m.estimate.append(u);
  // The joint covariance is not stored: the optimiser's form from the marginals.
  m.estimate = optimizer_->adopt(std::move(m.estimate));
  for (const MapLinkState& l : state.links)
    for (int id : l.loops) loops_[id].summarised = true;
  for (int s : state.chain) maps_.erase(sessions_[s].map);
  const int id = state.chain.front();
  maps_[id] = std::move(m);
  for (int s : state.chain) sessions_[s].map = id;
  return {};
}

void MultiSessionBackend::restoreSplitPair(int session_a, int session_b) {
  sessionAt(session_a);
  sessionAt(session_b);
  split_pairs_.insert({std::min(session_a, session_b), std::max(session_a, session_b)});
}

}  // namespace core
}  // namespace uw_multislam
