// The session manager: the one object that owns sessions, their ids, maps, joins and splits, and
// the session store (doc/design.md; cf. cartographer's MapBuilder).
//
// Both heads drive it through a SessionWorker (session_worker.h: its lock, work queue and
// optimisation loop): offline_slam through core::Pipeline (pipeline.h, every stage in one
// process) synchronously, and the back-end nodelet, which feeds it the Keyframe and Loop
// messages of the odometry and loop-detector nodelets, on the worker's thread. Nothing else
// starts a session, assigns an id or writes the store.
//
// One id space. A session's id is what services, messages, the store's rows as the user sees
// them, CSV outputs, rviz frames and logs call it, and it is the session's store id for life:
// sessions restored from the store keep their store ids (after every restart, in export file
// names and in export_survey alike), and a session of this run takes an id past every id the
// store holds or held (SessionStore::nextSessionId, deleted sessions included), which its store
// row gets with the session's first keyframe. A new session takes nextId(), whoever starts it:
// the odometry continues from it (the back-end announces it), startSession, another vehicle's
// session. A keyframe naming a session not opened for our odometry is refused and spends no id
// (addKeyframe), so ids stay dense. Ids only grow, are never given twice (not after a deletion
// either), and never past kMaxSessionId: a keyframe, loop or request naming a larger (or
// negative) id is refused, so a corrupt message cannot make the ids wrap. A map is named by the
// id of its first session, its frame is that session's frame.
//
// What changed is reported through an EventSink: session started/ended, keyframe added, loop
// accepted/refused, maps joined/split, map optimised. The ROS layer turns events into messages
// and tf; offline_slam into log lines.
//
// Requests answer with a core::Status whose codes are Status.msg's; a request that fails changes
// nothing. Store writes that fail (disk full, I/O error) are counted and logged, never fatal: the
// map lives on in memory, and the next successful save of the maps writes it whole.
//
// Its state is one value it owns (session_table.h: the sessions, the id maps and their
// invariants, the loops, the audit trail, the back-end and the store); its queries are a const
// view of that value, reached by view() (session_queries.h); other vehicles' sessions (the hash
// exchange) by fleet(). Not thread-safe: one caller at a time (SessionWorker holds the lock every
// head takes).
#pragma once

#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "uw_multislam/core/session/session_queries.h"

namespace uw_multislam {
namespace core {

class SessionManager;

/// Other vehicles' sessions in this manager (the hash exchange between vehicles): each grows
/// beside this vehicle's active session from the keyframes that vehicle sends (hash, motion, pose,
/// camera; no features), is stored like any session, and joins our maps by the usual rule.
class FleetSessions {
 public:
  /// Another vehicle's keyframe (the hash exchange between vehicles): `keyframe.session` is its id
  /// on that vehicle. The first keyframe of (vehicle, session) opens a session of this manager
  /// (nextId(), named "<vehicle>_session_<id>", local_id says which), which grows beside the
  /// active one: both are recording, each in its own map, until loops join them once one has
  /// ended (MultiSessionBackend::endSession). Only what crosses the link is kept: hash, motion,
  /// odometry pose, camera, altitude (features and image are dropped; the vehicle is asked for
  /// features when a loop needs them). Written to the store (without features, with provenance
  /// "fleet:<vehicle>") like any session, finished at endSession or the manager's destruction. A name
  /// already taken (an earlier run's) gets _2, _3, ...; a keyframe 0 with another stamp for a
  /// session that records or has ended here is the vehicle starting over (a restart on a new
  /// store): the old one ends, a new one opens. Refused with nothing changed: INVALID_ARGUMENT
  /// (vehicle name not 1-64 of [A-Za-z0-9_-], ids, a gap past max_keyframe_gap),
  /// FAILED_PRECONDITION (stale: repeated or out of order, or the session ended).
  Status addKeyframe(const std::string& vehicle, const KeyframeInput& keyframe, int* local_id = nullptr);
  /// That vehicle's session ended (its last keyframe sent): recording stops, postponed joins are
  /// tried. NOT_FOUND when it is not recording here. Later keyframes of it are refused.
  Status endSession(const std::string& vehicle, int remote_session, double stamp_s);
  /// Ends every other vehicle's session still recording here (at its last keyframe's stamp), as
  /// endSession; returns how many. The destructor does it too (a host whose event sink
  /// must still be alive calls it first).
  int finishAll();

 private:
  friend class SessionManager;
  explicit FleetSessions(SessionManager* manager) : manager_(manager) {}
  SessionManager* manager_;
};

class SessionManager {
 public:
  using EventSink = SessionEventSink;
  using Log = SessionLog;
  using Relocalisation = SessionQueries::Relocalisation;

  /// Opens the store (if any), checks its hash settings and restores every stored session,
  /// loop and map (listed UNLOADED until reload()). Throws std::invalid_argument on bad options,
  /// StoreError on a store that cannot be used (the file is left untouched).
  SessionManager(const SessionManagerOptions& options, EventSink events = {}, Log log = {});
  ~SessionManager();
  SessionManager(const SessionManager&) = delete;
  SessionManager& operator=(const SessionManager&) = delete;

  /// Every query (sessions, maps, poses, loops, the store, counters): the read-only view.
  const SessionQueries& view() const { return view_; }
  /// Other vehicles' sessions.
  FleetSessions& fleet() { return fleet_; }

  // --- Requests ----------------------------------------------------------------------------
  /// Ends the active session and starts a new one, `id` or (-1) nextId(), named `name` (empty:
  /// "session_<id>"). ALREADY_EXISTS when the name is taken, INVALID_ARGUMENT for an id that is
  /// not new or past kMaxSessionId, a name longer than kMaxSessionNameLength or made only of
  /// digits (it would read as an id: nameIsAnId), RESOURCE_EXHAUSTED when
  /// max_empty_sessions sessions in a row have no keyframe or no id is left. The session has its origin keyframe; the
  /// next keyframe 0 given to it fills it in.
  Status startSession(const std::string& name, double stamp_s, int id = -1, int* started = nullptr);
  /// Stops the active session (its map may be optimised); the maps are saved.
  Status endSession(double stamp_s);
  /// A keyframe of the active session, or keyframe 0..k of a new session (ending the active one).
  /// A session id outside [0, kMaxSessionId] or a negative keyframe id is INVALID_ARGUMENT.
  /// `loops` (optional) are loops it closed, stored with it in one transaction (offline). A
  /// keyframe of an older session, or repeated, is FAILED_PRECONDITION (stale); lost keyframes
  /// (a gap in the ids) are bridged by placeholders that no loop may use, up to max_keyframe_gap.
  /// A new session must be nextId(): a keyframe naming a session not opened for our odometry
  /// (past nextId(), or another vehicle's newer than all of ours) is FAILED_PRECONDITION, counted
  /// keyframes_unopened and held, and opens its session only when the next keyframe continues it
  /// (refuseUnopened).
  Status addKeyframe(const KeyframeInput& keyframe, const std::vector<Loop>& loops = {});
  /// A loop in session ids. UNAVAILABLE-like answer through `waiting`: true when one of its
  /// keyframes has not arrived yet (try again after the next keyframe); else OK (accepted) or a
  /// refusal (FAILED_PRECONDITION / INVALID_ARGUMENT with the reason). A session id outside
  /// [0, kMaxSessionId] or a negative keyframe id is INVALID_ARGUMENT at once (never waiting).
  Status addLoop(const Loop& loop, bool* waiting = nullptr);
  /// The operator's manual link (add_link): a loop between two keyframes the manager holds (in
  /// memory or restored from the store), with the measured pose of b in a's frame and its
  /// covariance (`loop.z`) and the support it counts for in the join rule (`loop.inliers`, >= 0).
  /// Its kind follows the sessions (local inside one, global between two); it is then a loop like
  /// a detector's: stored, optimised, counted towards joins. Refused with nothing changed:
  /// INVALID_ARGUMENT (an id out of range, a keyframe linked to itself, a pose or covariance not
  /// finite, a covariance not symmetric positive definite, negative inliers), NOT_FOUND (an unknown
  /// session or keyframe), FAILED_PRECONDITION (a bridged keyframe that never arrived, or the
  /// back-end refusing the loop).
  Status addLink(Loop loop);
  /// The nav's placement of session `loop.session_b` (a new piece or session, its keyframe
  /// `keyframe_b`, usually 0) relative to keyframe `keyframe_a` of an earlier session: `loop.z`
  /// from the nav with the nav's covariance over the stretch between them (nav_prior.h
  /// navPlacement; the caller never gives a fixed small sigma). Stored as a global loop marked a
  /// nav placement (SessionStore table nav_placements), it joins the two maps at once (the link
  /// is the placement, through the chains), so the session is in its predecessor's map from its
  /// first keyframe; counted nav_placements, in the audit trail as "nav_placement". It is no visual
  /// evidence: never counted towards an automatic join or a relocalisation (BackendLoop::
  /// nav_placement), and later loops between the two go through the intra-map gate against the
  /// map that holds it, then refine the link in the solve. OK without a change when the two are
  /// already in one map (loops came first). Refused with nothing changed: INVALID_ARGUMENT (ids,
  /// one session, a pose or covariance not finite or not positive definite), NOT_FOUND,
  /// FAILED_PRECONDITION (a bridged keyframe, localisation mode); a join the back-end refuses
  /// (both maps hold a recording session) leaves the placement stored, unused, and says why.
  /// `visual`: `loop` is a visual bridge (a piece's keyframe registered with the piece before it,
  /// SegmentedOdometry's rejoin): stored as the visual loop it is, joins the maps the same way,
  /// counted visual_bridges, "visual_bridge" in the audit trail.
  Status addNavPlacement(Loop loop, bool visual = false);
  /// The operator's "optimise now": every map with loops waiting for optimisation (fewer than
  /// optimise_every) is optimised now, or (deferred) marked due. `maps`: how many.
  /// FAILED_PRECONDITION when optimisation is off (backend.optimise false).
  Status optimisePending(int* maps = nullptr);
  /// Localisation mode (set_mode): nothing is written to the store and no stored
  /// map changes, while sessions are still tracked. A session recording when it is switched on
  /// keeps what is stored and the rest in memory only; sessions started in it are memory only;
  /// neither is ever written later (a store keeps a prefix of each session). Automatic joins wait;
  /// join, split, add_link, optimise and detect_loops are refused (FAILED_PRECONDITION). Back in
  /// mapping mode everything goes on as before (the memory-only keyframes stay unstored).
  Status setLocalisation(bool on);
  /// Keeps the maps' geographic datum (its text, core/export/geo_datum.h datumText) in the store,
  /// so that a restart keeps a datum set at sea. FAILED_PRECONDITION without a store or in
  /// localisation mode (the store stays byte-identical), DATA_LOSS when the write failed: the
  /// store then holds what it held.
  Status storeDatum(const std::string& text);
  /// An absolute position prior (a GPS or USBL fix placed through the datum: core/export/geo_fix.h)
  /// on keyframe `keyframe` of session `session`: its (x, y) in the current frame of the session's
  /// map (the camera's position, image axes) and covariance (m^2). The back-end keeps it and
  /// optimises the map with it (deferred: the map is due); the store gets it at once, as a loop
  /// (a crash after this keeps it). Refused with nothing changed:
  /// NOT_FOUND (no such session or keyframe, or a bridged keyframe that never arrived),
  /// FAILED_PRECONDITION (the keyframe is its map's origin: the map's frame), ALREADY_EXISTS (the
  /// keyframe has a prior already: one per keyframe),
  /// INVALID_ARGUMENT (a position or covariance checkPositionPrior refuses).
  Status addPositionPrior(int session, int keyframe, const Eigen::Vector2d& position,
                          const Eigen::Matrix2d& covariance);
  /// Joins the maps of two sessions from the global loops between them (min_loops 0: K).
  /// INVALID_ARGUMENT for an id outside [0, kMaxSessionId], NOT_FOUND for an unknown one.
  Status join(int session_a, int session_b, int min_loops = 0);
  /// Splits a session off its map (INVALID_ARGUMENT, NOT_FOUND as join).
  Status split(int session);
  /// What reload() reads of a session's keyframes: everything (features, hash, thumbnail), the
  /// frame data and hashes only (paging: features are read later with storedFeatures), or nothing
  /// (the host hands the hashes over later with storedHashes, session by session).
  enum class ReloadRead { kFeatures, kHashes, kNothing };
  /// Brings a stored (UNLOADED) session back by name or id: its keyframes as `read` says, for the
  /// loop detector. NOT_FOUND, ALREADY_EXISTS (loaded), FAILED_PRECONDITION (no store), DATA_LOSS.
  Status reload(const std::string& name_or_id, ReloadedSession* out, ReloadRead read = ReloadRead::kFeatures);
  /// unload_session: a reloaded stored session goes back to UNLOADED, so the
  /// host drops its features from the loop detectors (it keeps its place in its map, its poses and
  /// loops; reload() brings it back). Nothing is lost: only sessions restored from the store,
  /// whose keyframes are all stored, qualify. NOT_FOUND (no such stored or recorded session),
  /// FAILED_PRECONDITION (no store, a session recorded in this run, already unloaded).
  Status unload(const std::string& name_or_id, int* id = nullptr);
  /// delete_session: removes a finished session alone in its map from the store
  /// (keyframes, motions, its loops, its map; one transaction) and from memory, for good. The ids
  /// of the others stay (also after a restart), ids are not
  /// reused. Recorded in the audit trail. Refused with nothing changed: NOT_FOUND,
  /// FAILED_PRECONDITION (no store, localisation mode, the recording session, a session sharing
  /// its map: split it off first, `confirm` false: the message says what would go), DATA_LOSS
  /// (the store could not be changed).
  Status deleteSession(const std::string& name_or_id, bool confirm, int* id = nullptr);
  /// Optimises every map with pending loops (now, also when deferred); saves the maps.
  void flush();

  // --- Deferred optimisation (the back-end nodelet) -----------------------------------------
  // With it on, requests never optimise: they leave the maps that need it due (backend.h,
  // "Deferred optimisation"). The host takes each due map's problem with nextOptimisation() under
  // its lock, solves it with solveOptimisation() without the lock (other requests and queries go
  // on meanwhile), and hands it back with applyOptimisation() under the lock again.
  void setDeferredOptimisation(bool on) { table_.backend().setDeferred(on); }
  /// The first due map's problem (its map in session ids), or nullopt when none is due.
  std::optional<MapOptimisation> nextOptimisation() const;
  static void solveOptimisation(MapOptimisation* o) { MultiSessionBackend::solveOptimisation(&o->job); }
  /// true: the result is in (kMapOptimised; the maps are saved when the map holds no recording
  /// session). false: the map changed while it was solved; nothing written, it is still due.
  bool applyOptimisation(const MapOptimisation& o);

 private:
  friend class FleetSessions;
  using Session = SessionTable::Session;
  using Piece = SessionTable::Piece;
  /// Opens a session: this vehicle's (ends the active one, becomes active) or, with `vehicle`,
  /// another vehicle's `remote_id` (beside the active one).
  Status open(int id, const std::string& name, double stamp_s, const std::string& vehicle = "", int remote_id = -1);
  /// Appends keyframe k of an open session (k.session in this manager's ids) with its loops.
  Status appendKeyframe(KeyframeInput k, const std::vector<Loop>& loops);
  /// addLoop with `loop` in this manager's ids (add_link: the operator names what list_sessions
  /// shows) or, `odometry_ids`, in the odometry's (toPiece names them after a jump).
  Status addLoopIn(const Loop& loop, bool odometry_ids, bool* waiting);
  /// The session's store row (with its provenance when it is another vehicle's).
  void addStoreRow(int id, double stamp_s);
  /// Writes a keyframe with its motion and `loops` (converted to `stored`, whose ids are set),
  /// after the `gap` keyframes lost just before it (each with `gap_motion`), in one transaction.
  void storeKeyframe(int id, const KeyframeInput* k, int keyframe, const UncertainPose2* motion, double stamp_s,
                     const std::vector<Loop>* loops, std::vector<StoredLoop>* stored, int gap = 0,
                     const UncertainPose2* gap_motion = nullptr);
  /// A keyframe too far past its session's last (or starting a session too far in): held, and
  /// refused. The next keyframe decides: continuing from the held one, it was a jump (the
  /// odometry's ids really moved on, as after a long queue overflow): the piece ends and a new
  /// session starts from the held keyframe, so nothing from it on is lost, as after a tracking
  /// loss. Anything else: the held one was a corrupt id, dropped.
  Status refuseJump(KeyframeInput k, const std::string& why);
  /// The held keyframe of a confirmed jump: ends the active session, opens one (the odometry's
  /// id if it never opened and is at most max_keyframe_gap past nextId(), else nextId()) with it
  /// as keyframe 0; counted keyframe_jumps when the keyframe ids jumped.
  Status startPiece(KeyframeInput held);
  /// A keyframe naming a session this manager did not open for our odometry: past nextId() (a
  /// session's id is the back-end's to give), or another vehicle's newer than all of ours.
  /// Refused, counted keyframes_unopened, and held. The next keyframe decides: continuing it, it
  /// was our odometry's (its sessions before it lost on the way, or its id taken by the other
  /// vehicle in the same instant): the session opens (startPiece), so nothing from it on is lost.
  /// Anything else: the held one is dropped, no id spent, nothing ended.
  Status refuseUnopened(KeyframeInput k);
  /// Adds an accepted loop to the back-end with its store row (throws std::invalid_argument as
  /// the back-end does); its event.
  void acceptLoop(const Loop& l, std::int64_t store_row);
  StoredLoop toStored(const Loop& l) const;
  /// After a back-end call: events for joins, splits and optimisations, and the maps saved when
  /// a join or split happened.
  void afterBackendChange();
  void saveMaps();
  /// The audit trail's next entry (its id, now), cause_ unless `cause` is given; not appended.
  HistoryEntry nextEntry(const std::string& kind, const std::string& sessions, const std::string& loops,
                         const std::string& message, const char* cause = nullptr) const;
  /// Appends to the audit trail (and the store, unless localising); cause_ unless `cause` is given.
  void record(const std::string& kind, const std::string& sessions, const std::string& loops,
              const std::string& message, const char* cause = nullptr);
  /// The back-end's joins and splits since the last call, into the audit trail.
  void recordMapChanges();
  /// "a,b,c" of back-end sessions, in session ids.
  std::string chainText(const std::vector<int>& backend_sessions) const;
  /// "a:ka>b:kb ..." of back-end loop ids.
  std::string loopsText(const std::vector<int>& backend_loops) const;
  void emit(SessionEvent::Kind kind, int session, int other, int map, const std::string& message) const;
  void say(const std::string& line) const;
  /// Runs a store write unless there is no store or the manager localises: true when written;
  /// a failure is counted (store_failures) and logged, never thrown (the map lives on in memory).
  template <typename F>
  bool storeWrite(const char* what, F write);
  /// A position prior the back-end accepted, written to the store now (SessionStore::addPositionPrior).
  void storePositionPrior(int session, int keyframe, const Eigen::Vector2d& position,
                          const Eigen::Matrix2d& covariance);

  EventSink events_;
  Log log_;
  SessionTable table_;  // the state: everything the manager knows
  SessionQueries view_{table_};
  const char* cause_ = "automatic";                                // of the joins and splits recordMapChanges finds
  bool hold_changes_ = false;                                      // afterBackendChange leaves them to the caller
  int seen_joins_ = 0, seen_splits_ = 0, seen_optimisations_ = 0;  // the back-end's, reported so far
  FleetSessions fleet_{this};
};

template <typename F>
bool SessionManager::storeWrite(const char* what, F write) {
  if (!table_.store() || table_.localising()) return false;  // localisation mode: nothing written (not a failure)
  try {
    write();
    return true;
  } catch (const std::exception& e) {
    const long failures = ++table_.stats().store_failures;
    say("session store " + table_.options().store_path + ": " + what + " failed (" + std::to_string(failures) +
        " failures so far; the map lives on in memory): " + e.what());
    return false;
  }
}

}  // namespace core
}  // namespace uw_multislam
