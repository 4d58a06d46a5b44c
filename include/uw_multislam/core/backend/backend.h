// The multi-session back-end: sessions, maps, links, optimisation (paper 000 §8 and §9).
//
// A *session* is one continuous trajectory of keyframes, built from odometry motions (10)(11).
// A *map* is a chain of sessions [s_0, s_1, ..., s_m] joined by single links: link i is the motion
// from the LAST keyframe of s_i to the FIRST keyframe of s_{i+1}. The map's state is the
// concatenation (33)(34): s_0's motions, link 0, s_1's motions, ..., so that every keyframe of the
// map has one index and every loop inside the map is a measurement of X_j^i (14) over that chain.
// A map's id is the id of its first session and its frame is that session.s frame (doc/dataset_format.md).
//
// Joining two maps A and B (Algorithm 2) puts one after the other: "the end of the previous
// session" is the last keyframe of the last session of the map placed first, "the start of the
// current session" is the first keyframe of the first session of the map placed second. The map
// holding a session that is still recording is placed second (a recording session must stay at
// the end of its chain, where its new motions are appended); otherwise the map whose first session
// is older (smaller id) is placed first. The link is estimated from every stored global loop
// between the two maps (at least K = join_min_loops; the loops may involve any of their sessions,
// X_pe^pi and X_ci^cs are taken through the chains) by map_joining.h, after refusing loops that
// disagree with the others; those loops are then summarised by the link and not used again.
//
// Splitting session s off its map removes it from the chain; it becomes a map of its own and
// keeps its optimised motions, and so does the rest. If s was in the middle, its neighbours stay
// joined by the composed link L_in ⊕ X_s ⊕ L_out (its covariance propagated through the joint
// covariance), so the rest stays one chain. The global loops that tied s to the rest become
// inter-map loops again, available to join later; automatic joining will not use loops between
// a split pair again until the user joins them explicitly.
//
// The back-end is given the optimiser of its maps at construction (map_optimizer.h); it keeps each
// map's estimate in the form that optimiser chooses and hands it the map's graph (odometry motions,
// links, loops not summarised by a link) when the map is due. Two implement it, and
// makeMapOptimizer() makes the one BackendOptions::optimizer names:
//  - "iekf": the paper's intra-map IEKF (iekf_optimizer.h), a dense 3N x 3N covariance per map,
//    applying each loop once. A map larger than max_keyframes falls back to the sparse optimiser (logged).
//  - "sparse" (default): the Ceres pose graph (pose_graph_optimizer.h), re-solved over the whole
//    map, warm-started, with a robust loss on loops. Memory O(N + loops).
// Optimisation is delayed until optimise_every (M) loops are pending in a map, or a session
// ends, or flush() is called.
//
// Deferred optimisation (setDeferred): a host that serves other threads meanwhile (the back-end
// nodelet: services, the per-frame pose) does not let a request optimise. Requests only mark maps
// due; the host takes each due map's problem out (prepareOptimisation, a copy), solves it without
// holding its lock (solveOptimisation touches nothing but the job) and hands the result back
// (applyOptimisation), which writes it only if the map did not change in between (its revision:
// a new motion, loop, join, split or restore changes it), else the map stays due and is solved
// again. Prepare + solve + apply is also the synchronous path, so both give the same numbers.
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "uw_multislam/core/backend/iekf.h"
#include "uw_multislam/core/backend/loop_consistency.h"
#include "uw_multislam/core/backend/map_estimate.h"
#include "uw_multislam/core/backend/map_joining.h"
#include "uw_multislam/core/backend/map_optimizer.h"
#include "uw_multislam/core/backend/pose_graph.h"
#include "uw_multislam/core/common/status.h"
#include "uw_multislam/core/geometry/trajectory.h"

namespace uw_multislam {
namespace core {

enum class OptimizerKind { kIekf, kSparse };
const char* optimizerName(OptimizerKind k);
/// "session_<id>": the name of a session started without one (the one place that spells it; the
/// ROS frames' default prefix, topics::kDefaultSessionFramePrefix, is the same word).
std::string defaultSessionName(int id);
/// "iekf" or "sparse"; false otherwise.
bool parseOptimizer(const std::string& name, OptimizerKind* out);

/// How the global loops between two maps decide a join: kCount, K loops (join_min_loops) and a
/// metric gate on each (join_gate_m); kConsistent, the largest pairwise-consistent set
/// (core/backend/loop_consistency.h) with at least join_min_consistent loops, join_min_inliers
/// inliers in total and join_min_spread_m between its loops' keyframes.
enum class JoinPolicy { kCount, kConsistent };
const char* joinPolicyName(JoinPolicy p);
bool parseJoinPolicy(const std::string& name, JoinPolicy* out);

struct BackendOptions {
  bool optimise = true;  // false: trajectories stay the odometry's (joins still happen)
  OptimizerKind optimizer = OptimizerKind::kSparse;
  int optimise_every = 3;    // M: optimise a map when this many loops are pending in it
  int join_min_loops = 5;    // K: global loops needed to join two maps automatically (0 = never)
  double join_gate_m = 0.5;  // a loop whose position disagrees with the joined link by more
                             // than this is refused (metres, not χ²: odometry covariances are
                             // over-confident over long chains, a χ² gate refused true loops)
  JoinPolicy join_policy = JoinPolicy::kConsistent;
  int join_min_consistent = 2;     // kConsistent: loops in the consistent set
  int join_min_inliers = 60;       // kConsistent: their total RANSAC inliers
  double join_min_spread_m = 0.2;  // kConsistent: distance between their keyframes (both maps)
  ConsistencyOptions consistency;  // kConsistent: the pairwise test
  /// A loop inside one map is refused when it disagrees with the map's current estimate beyond
  /// the chi-square gate of consistency.confidence, the covariance being the chain's between its
  /// two keyframes plus the loop's plus the consistency floors (both optimisers; before the
  /// IEKF's update). A refused loop is kept as refused (store, loops.csv) and counted.
  bool intra_loop_gate = true;
  /// The chain's covariance is multiplied by this in the gate of a sparse map: odometry
  /// covariances are first order and over-confident over many motions (a loop closing a drifted
  /// square at 5 sigma of its own covariance is a true loop); wrong loops are metres off. Loose
  /// (100): the residual gate behind it switches off what gets through, and a true loop the
  /// entry gate refuses is lost (doc/benchmarks/outliers.md, 2026-11-25: no wrong join at 50 %).
  double intra_gate_inflation = 100.0;
  /// The same for a map the IEKF keeps (dense), whose gate uses the filter's joint covariance P of
  /// the two keyframes (TrajectoryIekf::relative) instead of the marginal chain: tight, because an
  /// IEKF update cannot be taken back. 3 is the tightest that still takes a drifted square's true
  /// loop at 5 sigma of the odometry's covariance (gtest SquareWithOneExactLoopClosesExactly: 2
  /// refuses it). bench_backend --outliers --optimizer iekf on the demo (doc/benchmarks/outliers.md,
  /// 2026-11-25): 3 keeps no wrong loop up to 30 % (1 run of 5 goes wrong at 50 %), 10 let one
  /// through at 10 % already; on clean data 3 refuses about 4 true loops of 131.
  double iekf_gate_inflation = 3.0;
  /// After each optimisation of a map (both optimisers), the loop whose residual in the solution
  /// exceeds the chi-square gate of consistency.confidence (covariance: the loop's times
  /// residual_gate_inflation plus the consistency floors) is switched off: refused, kept refused in
  /// the store and loops.csv, counted (loops_switched_off), and the map solved again from the same
  /// start without it; worst first, one at a time, until every loop left agrees with the solution.
  /// It catches what the gate above lets through: a wrong loop arriving while the chain between
  /// its keyframes is long and its covariance wide, which no later true loop would undo.
  bool loop_residual_gate = true;
  /// The loop's covariance is multiplied by this in that gate. Apart from intra_gate_inflation:
  /// the IEKF applies a loop without a robust loss, so this gate must stay tight for it even when
  /// the entry gate is loosened.
  double residual_gate_inflation = 10.0;
  /// With the residual gate: after a solve, a loop inside the map that was refused before (by the
  /// entry gate, switched off, or refused at a join) and agrees with the solution under the same
  /// residual gate is taken back (counted, loops_readmitted) and the map solved again with it;
  /// repeated until none is taken back. A true loop refused while a wrong one bent the map, or
  /// while the map was still metres off before its first loops, is not lost (bench_backend
  /// --outliers: doc/benchmarks/outliers.md, 2026-11-25 "Refused loops taken back"). A wrong loop
  /// metres off never agrees with a solution of the true ones.
  bool readmit_refused_loops = true;
  IekfOptions iekf;
  int max_keyframes = 1500;  // iekf: a larger map uses the sparse optimiser (dense P is 3N x 3N)
  SparseOptions sparse;

  std::string validate() const;
};

/// The optimiser `options.optimizer` names, with its options ("sparse" also when optimise is off:
/// nothing is solved then, and the maps keep the odometry's marginals). Throws
/// std::invalid_argument on bad options.
std::unique_ptr<MapOptimizer> makeMapOptimizer(const BackendOptions& options);

/// A loop as the back-end stores it: z is the pose of (session_b, keyframe_b) in (session_a, keyframe_a).
struct BackendLoop {
  int session_a = 0, keyframe_a = 0;
  int session_b = 0, keyframe_b = 0;
  UncertainPose2 z;
  int inliers = 0;  // RANSAC's (the consistency policy's support)
  /// The nav's placement of a new session (SessionManager::addNavPlacement), not a visual match:
  /// it joins the two maps it was made for, and is never evidence for an automatic join or a
  /// relocalisation (after a split, only a join the operator asks for may use it again).
  bool nav_placement = false;
};

using BackendStatus = Status;

struct SessionInfo {
  int id = 0;
  std::string name;
  bool recording = false;
  int map = 0;
  int keyframes = 0;
};

struct LinkInfo {
  int previous = 0;         // the session whose last keyframe the link starts from
  int current = 0;          // the session whose first keyframe it reaches
  UncertainPose2 measured;  // from the join (or composed by a split)
  Pose2 estimate;           // after optimisation
  int loops = 0;            // global loops it summarises
};

/// A loop with its state in the back-end (as it keeps it and the session store saves it).
struct LoopRecord {
  BackendLoop loop;
  bool summarised = false;  // used by a link
  bool applied = false;     // in its map's estimate for good (MapProblem::apply: the IEKF's)
  bool refused = false;     // refused as inconsistent at a join
};

/// An absolute position prior on a keyframe as the back-end keeps it (addPositionPrior): its
/// position and covariance in the current frame of the map that holds the keyframe (a join or a
/// split that moves that frame moves the prior with it). Not in its session's frame: a fix is
/// absolute, and a session's origin in its map is an estimate that the fix itself moves when the
/// map is solved; composed with it at each solve, the fix would follow it (gtest
/// APriorOnALaterSessionStaysWhereItWasPutWhenTheMapIsSolvedAgain). Only the map's first keyframe
/// is fixed, so only a join or a split (which re-roots frames) moves a prior.
struct PriorRecord {
  int session = 0, keyframe = 0;
  Eigen::Vector2d position = Eigen::Vector2d::Zero();
  Eigen::Matrix2d covariance = Eigen::Matrix2d::Identity();
  bool applied = false;  // in its map's estimate for good (MapProblem::apply: the IEKF's)
};

/// One link of a map (as the back-end keeps it and the store saves it): its measurement and the
/// ids of the loops it summarises.
struct MapLinkState {
  UncertainPose2 measured;
  std::vector<int> loops;
};

/// A map as the session store keeps it: its chain, links, and the current (optimised) motions
/// of the whole chain with their marginal covariances (concatenation (33): the sessions' motions
/// with each link between them), and the loops pending optimisation.
struct MapState {
  std::vector<int> chain;
  std::vector<MapLinkState> links;  // links[i] joins chain[i] -> chain[i+1]
  std::vector<UncertainPose2> motions;
  int pending = 0;
};

struct BackendStats {
  int loops = 0;               // loops received
  int loops_refused = 0;       // refused at a join as inconsistent with the others
  int joins_refused = 0;       // automatic joins the consistency policy refused (reason: last_join_refusal)
  int loops_gated = 0;         // loops inside a map refused by intra_loop_gate (also in loops_refused)
  int loops_switched_off = 0;  // loops refused by loop_residual_gate after a solve (also in loops_refused)
  int loops_readmitted = 0;    // refused loops taken back after a solve (readmit_refused_loops)
  std::string last_join_refusal;
  int joins = 0, splits = 0;
  int optimisations = 0;
  int priors = 0;                   // absolute position priors accepted (addPositionPrior)
  int optimisations_discarded = 0;  // deferred results dropped: their map changed while they were solved
  double optimise_ms_total = 0.0, optimise_ms_max = 0.0;
};

/// A join or a split as it happened, in back-end session ids (the session manager's audit trail
/// takes them with takeMapChanges()).
struct MapChange {
  bool join = true;
  std::vector<int> first, second;  // join: the two chains, second attached after first; split: {session}, the rest
  std::vector<int> loops;          // join: the loops its link was estimated from; split: the loops it released
  int refused = 0;                 // join: loops refused as inconsistent
  std::string message;
};

/// One map's optimisation problem taken out of the back-end (see "Deferred optimisation" above):
/// its optimiser's problem and the residual gate around the solve, the same for every optimiser.
struct OptimisationJob {
  int map = -1;
  std::uint64_t revision = 0;           // the map's revision when the job was prepared
  std::unique_ptr<MapProblem> problem;  // null: no loop to solve
  std::vector<MapLoop> loops;           // the loops the problem solves (after the solve: those kept)
  std::vector<int> priors;              // the ids of the position priors it solves with them
  // The residual gate (loop_residual_gate; threshold <= 0: off) and the loops it switched off.
  double residual_gate_chi2 = 0.0;
  double residual_gate_inflation = 1.0;
  ConsistencyOptions residual_gate_floors;
  std::vector<int> switched_off;  // loops that were in the map's solution
  std::vector<double> switched_off_chi2;
  // readmit_refused_loops: the map's refused loops, and those the solve took back with their distances.
  std::vector<MapLoop> refused;
  std::vector<int> readmitted;
  std::vector<double> readmitted_chi2;
  double solve_ms = 0.0;
  bool solved = false;
};

class MultiSessionBackend {
 public:
  using Log = std::function<void(const std::string&)>;
  /// Its maps optimised by `optimizer` (options.optimizer is not read). Throws
  /// std::invalid_argument on bad options or no optimiser. `log` receives one line per join,
  /// split, refused loop or optimiser fallback.
  MultiSessionBackend(const BackendOptions& options, std::unique_ptr<MapOptimizer> optimizer, Log log = {});
  /// With makeMapOptimizer(options).
  explicit MultiSessionBackend(const BackendOptions& options, Log log = {});

  /// A new recording session with one keyframe (its origin), alone in a new map. Returns its id.
  int startSession(const std::string& name = "");
  /// Stops recording: optimises its map if loops are pending, then tries again the automatic joins
  /// postponed while its map and another both held a recording session.
  void endSession(int session);
  /// Appends the odometry motion X_k^{k-1} to a recording session (10)(11).
  void addMotion(int session, const UncertainPose2& motion);
  /// Stores a loop (both keyframes must exist). Inside a map it is pending for optimisation;
  /// between maps it is stored and may trigger a join (K loops). Throws std::invalid_argument.
  void addLoop(const BackendLoop& loop);
  /// An absolute position prior (position_prior.h) on keyframe `keyframe` of session `s`: its (x, y)
  /// in the current frame of the map that holds the keyframe, with its covariance. Kept (priors()),
  /// given to every optimisation of that map from now on, and the map is optimised now (deferred:
  /// marked due). INVALID_ARGUMENT for an unknown session or keyframe, a position or covariance
  /// checkPositionPrior refuses; FAILED_PRECONDITION for the map's first keyframe (its frame: fixed);
  /// ALREADY_EXISTS when the keyframe has a prior (one per keyframe: close fixes share their errors).
  BackendStatus addPositionPrior(int s, int keyframe, const Eigen::Vector2d& position,
                                 const Eigen::Matrix2d& covariance);
  const std::vector<PriorRecord>& priors() const { return priors_; }
  /// A stored prior put back as it was (the session store): checked as addPositionPrior checks,
  /// nothing optimised, its map unchanged.
  BackendStatus restorePositionPrior(const PriorRecord& record);
  /// Optimises every map with pending loops, now (also when deferred).
  void flush();
  /// The operator's "optimise now": every map with pending loops (fewer than optimise_every) is
  /// optimised now, or (deferred) marked due. Returns how many; 0 when optimise is off.
  int optimisePending();
  /// false: no automatic join (the loops between maps are kept and counted towards the next one);
  /// joins asked for (join) still happen. The session manager's localisation mode.
  void setAutomaticJoins(bool on) { automatic_joins_ = on; }

  // --- Deferred optimisation ---
  /// true: requests only mark maps due (dueMaps); the host optimises them with the three calls below.
  void setDeferred(bool deferred) { deferred_ = deferred; }
  bool deferred() const { return deferred_; }
  /// Maps waiting for an optimisation, in id order.
  std::vector<int> dueMaps() const;
  /// A copy of map `map`'s problem. Throws std::invalid_argument for an unknown map.
  OptimisationJob prepareOptimisation(int map) const;
  /// Solves a prepared job; reads and writes nothing but `job` (call it without the host's lock).
  static void solveOptimisation(OptimisationJob* job);
  /// Writes a solved job's result into its map: true. false (nothing written, the map stays due)
  /// when the map changed or vanished since prepareOptimisation.
  bool applyOptimisation(const OptimisationJob& job);

  /// Joins the maps of two sessions from their stored global loops. min_loops 0: by the configured
  /// rule (count: join_min_loops, at least 1; consistent: the largest pairwise-consistent set with
  /// join_min_consistent loops, join_min_inliers inliers and join_min_spread_m spread). min_loops
  /// > 0: at least that many loops (count), or that many in the largest pairwise-consistent set,
  /// without the automatic rule's inliers and spread (consistent: the caller has judged those).
  BackendStatus join(int session_a, int session_b, int min_loops = 1);
  /// Splits a session off its map.
  BackendStatus split(int session);

  int numSessions() const { return static_cast<int>(sessions_.size()); }
  bool hasSession(int s) const { return s >= 0 && s < numSessions(); }
  SessionInfo session(int s) const;
  int mapOf(int s) const { return sessionAt(s).map; }
  std::vector<int> mapIds() const;
  const std::vector<int>& chain(int map) const;
  std::vector<LinkInfo> links(int map) const;
  /// The session's keyframe poses in its map's frame.
  std::vector<Pose2> sessionPoses(int s) const;
  /// Keyframe `keyframe` of session `s` in its map's frame with a covariance: the map's motions
  /// up to it composed to first order (uncertain_pose.h). The motions' covariances are marginals
  /// (the IEKF's diagonal blocks, or the odometry's with the sparse optimiser), their correlations
  /// left out. Throws std::invalid_argument for an unknown keyframe.
  UncertainPose2 keyframeInMap(int s, int keyframe) const;
  /// Keyframe `to` of session `s` in its keyframe `from`'s frame (from <= to), the motions between
  /// them composed the same way. Throws std::invalid_argument for unknown keyframes or from > to.
  UncertainPose2 keyframeChain(int s, int from, int to) const;
  /// Relocalisation: where session `s` is in another map, before (or without)
  /// a join. For every other map with global loops to the session's map, the link a join would
  /// take under the consistency rule (join_min_consistent loops, join_min_inliers, join_min_spread_m
  /// and the pairwise chi-square test, whatever join_policy is; the spread is the other map's: loops
  /// from one new keyframe to stored keyframes that agree on where it is relocalise it at once); the map whose
  /// consistent set is largest (then: most inliers) wins; loops between sessions the user split apart do not count.
  /// nullopt: no map passes. Nothing changes (localisation mode
  /// uses it while joins wait).
  struct Relocalisation {
    int map = -1;                // the other map
    int loops = 0, inliers = 0;  // the consistent set's
    UncertainPose2 origin;       // the session's map frame in `map`'s frame (the end of `map`'s chain, then the link)
    UncertainPose2 pose;         // the session's last keyframe in `map`'s frame
    int keyframe = -1;           // which keyframe that is
  };
  /// `eligible` (optional): only maps for which it says true are considered (by map id).
  std::optional<Relocalisation> relocalise(int s, const std::function<bool(int map)>& eligible = {}) const;
  /// Global loops stored between the maps of two sessions and not yet used by a join.
  int pendingJoinLoops(int session_a, int session_b) const;
  const BackendStats& stats() const { return stats_; }
  const BackendOptions& options() const { return options_; }
  /// The joins and splits since the last call, in order (restoreMap's are not among them).
  std::vector<MapChange> takeMapChanges() { return std::exchange(changes_, {}); }

  // --- Session store (session_store.h): export the state, put it back exactly. ---
  /// A map's chain, links, current motions and pending count. Throws std::invalid_argument.
  MapState mapState(int map) const;
  int numLoops() const { return static_cast<int>(loops_.size()); }
  /// Loop `id` (ids count addLoop/restoreLoop calls from 0). Throws std::invalid_argument.
  LoopRecord loopRecord(int id) const;
  /// Pairs of sessions split apart by the user (automatic joining leaves them apart).
  std::vector<std::pair<int, int>> splitPairs() const {
    return std::vector<std::pair<int, int>>(split_pairs_.begin(), split_pairs_.end());
  }
  /// A finished session from its stored odometry motions, alone in a new map whose estimate is
  /// the odometry (restoreMap puts the optimised motions back). Nothing is optimised. Returns its
  /// id. Throws std::invalid_argument on a bad motion.
  int restoreSession(const std::string& name, const std::vector<UncertainPose2>& odometry);
  /// A stored loop with its state, as it was: no optimisation, no join. Returns its id.
  /// Throws std::invalid_argument like addLoop.
  int restoreLoop(const LoopRecord& record);
  /// Puts a stored map back exactly: every session of `state.chain` must be finished and alone in
  /// its map; `state.motions` must hold the chain's motions and links (or be empty: the
  /// sessions' current motions and the links' measurements). The loops named by the links are
  /// marked summarised. Nothing is optimised. The map's id becomes chain.front().
  BackendStatus restoreMap(const MapState& state);
  /// Marks two sessions as split apart by the user.
  void restoreSplitPair(int session_a, int session_b);
  /// delete_session: removes a finished session that is alone in its map, its
  /// map and every loop on it. The sessions after it move down one index, their maps with them
  /// (a map's id is its first session's), and loop ids close up (links keep naming the same
  /// loops). Every map is touched, so an optimisation prepared before is dropped and done again.
  /// NOT_FOUND, FAILED_PRECONDITION (recording, or in a map with other sessions); nothing changes
  /// on a refusal.
  BackendStatus removeSession(int session);

 private:
  struct Session {
    std::string name;
    bool recording = false;
    int map = 0;
    std::vector<UncertainPose2> odometry;  // measured motions, odometry[k-1] = X_k^{k-1}
    int keyframes() const { return static_cast<int>(odometry.size()) + 1; }
  };
  struct Map {
    std::vector<int> chain;
    std::vector<MapLinkState> links;          // links[i] joins chain[i] -> chain[i+1]
    MapEstimate estimate;                     // in the form the optimiser keeps
    int pending = 0;                          // loops waiting for optimisation
    std::uint64_t revision = nextRevision();  // changes with every change of the map (touch)
    int numMotions() const { return estimate.numMotions(); }
    Pose2 motion(int k) const { return estimate.motion(k); }  // motion k reaches keyframe k+1
    Eigen::Matrix3d motionCov(int k) const { return estimate.motionCov(k); }
  };

  const Session& sessionAt(int s) const;
  Map& mapAt(int id);
  const Map& mapAt(int id) const;
  int offset(const Map& m, int session) const;  // index of the session's first keyframe in the map
  /// Per motion of `m`: whether it is a link whose every loop is a nav placement (no visual match).
  std::vector<bool> navPlacedMotions(const Map& m) const;
  int indexOf(int session, int keyframe) const { return offset(mapAt(mapOf(session)), session) + keyframe; }
  /// Every new map, and every change of one, takes a revision never used before (process-wide).
  static std::uint64_t nextRevision();
  static void touch(Map& m) { m.revision = nextRevision(); }
  /// Optimises map `map_id` now, or (deferred) marks it due.
  void optimise(int map_id);
  void optimiseNow(int map_id);
  /// The map's graph as its optimiser takes it (MapOptimizer::prepare); *prior_ids: the ids of
  /// graph.priors, in order.
  MapGraph graphOf(int map_id, std::vector<int>* prior_ids) const;
  /// Each prior's session origin in its map, taken before a join or a split; rebasePriors moves
  /// every prior by how its session's origin moved (a join re-roots the second map's frame, a split
  /// the rest's when the session split off was first).
  std::vector<Pose2> priorOrigins() const;
  void rebasePriors(const std::vector<Pose2>& before);
  /// `requested`: an explicit count of the caller's (estimateLink).
  BackendStatus joinMaps(int map_a, int map_b, int min_loops, bool automatic, bool requested = false);
  /// The link a join of map `second` to the end of map `first` would take from the loops `ids`
  /// (loopsBetween) under `policy` (min_loops as joinMaps's); nothing changes. Status not OK: the
  /// policy refuses (the reason). in[k]: whether loop ids[k] takes part. `spread_in_first`: the
  /// consistency policy's spread is measured in `first` alone (relocalisation: several stored
  /// keyframes that agree on where one new keyframe is), else in the map where it is smaller.
  /// `requested` (an operator's join, not the automatic rule): the consistency policy still keeps
  /// only the largest pairwise-consistent set and needs min_loops of it, but not the automatic
  /// rule's support (join_min_inliers, join_min_spread_m): the person asking has judged that.
  struct LinkEstimate {
    BackendStatus status;
    std::vector<bool> in;
    JoinResult result;
    int used = 0, inliers = 0;
  };
  LinkEstimate estimateLink(int first, int second, const std::vector<int>& ids, int min_loops, JoinPolicy policy,
                            bool spread_in_first = false, bool requested = false) const;
  std::vector<int> loopsBetween(int map_a, int map_b, bool automatic) const;
  /// The automatic join of two maps when the loops between them meet the rule (a refusal is
  /// counted and logged, the loops kept for later). true: joined.
  bool tryAutomaticJoin(int map_a, int map_b);
  /// Whether one of the map's sessions is recording.
  bool holdsRecording(int map) const;
  bool barred(int sa, int sb) const;
  void say(const std::string& line) const;

  BackendOptions options_;
  std::unique_ptr<MapOptimizer> optimizer_;
  Log log_;
  std::vector<Session> sessions_;
  std::map<int, Map> maps_;
  std::vector<LoopRecord> loops_;
  std::vector<PriorRecord> priors_;
  std::set<std::pair<int, int>> split_pairs_;  // sessions split apart by the user
  BackendStats stats_;
  bool deferred_ = false;
  bool automatic_joins_ = true;
  std::set<int> due_;               // maps marked for a deferred optimisation
  std::vector<MapChange> changes_;  // joins and splits not yet taken
};

}  // namespace core
}  // namespace uw_multislam
