// The session manager's state in one value (cf. cartographer's PoseGraphData behind PoseGraph2D):
// the sessions and their keyframes' bookkeeping, the id maps, the loops in session ids, the audit
// trail, the mode and the counters, with the back-end and the store they describe.
// SessionManager owns one and is the only one to change it; SessionQueries reads it.
//
// The id maps' invariants are kept here, by the methods that change them, whoever calls them:
//  - a session's id is in [0, kMaxSessionId] and never names two sessions; ids only grow: a new
//    session takes an id at or past nextId(), which is past every id given in this run and every
//    id the store holds or held (deleted sessions included), so no id is ever given twice;
//  - names are unique among the sessions opened here (stored names are taken as they are);
//  - the back-end's session b is the session idOfBackend(b) and at(id).backend() is b: the
//    back-end's indexes are dense (opened in order, renumbered when a session is removed);
//  - a session's store row, once it has one, has the session's id;
//  - loops()[i] is the back-end's loop i, loopStoreRow(i) its store row (-1: not stored), and
//    each session counts the loops on it.
// The keyframes' bookkeeping of a session (stamps, odometry poses, what is stored) has no
// invariant across sessions: the manager appends to it through at().
//
// Not thread-safe, like the manager (SessionWorker's lock covers both).
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "uw_multislam/core/session/session_types.h"

namespace uw_multislam {
namespace core {

class SessionTable {
 public:
  /// One session. Its identity (name, back-end index, store row, vehicle, loop count) is the
  /// table's to set; its keyframes' bookkeeping is the manager's.
  struct Session {
    const std::string& name() const { return name_; }
    int backend() const { return backend_; }
    /// Its store row (the session's id), -1 while it has none.
    std::int64_t storeRow() const { return store_row_; }
    /// Another vehicle's session: that vehicle's name (empty: ours) and the session's id there.
    const std::string& vehicle() const { return vehicle_; }
    int remoteId() const { return remote_id_; }
    /// Loops on it (a loop inside it counts once).
    int loops() const { return loops_; }
    /// Keyframes it received (a session start_session opened has none until its first).
    int keyframes() const { return origin_received ? static_cast<int>(stamps.size()) : 0; }

    CameraIntrinsics camera;
    std::vector<double> stamps;         // per keyframe ([0]: the start's stamp until keyframe 0 comes)
    std::vector<Pose2> odometry;        // X_k^0 per keyframe
    std::vector<int> frames;            // frame index per keyframe
    std::vector<double> altitudes;      // per keyframe, m (0: not known)
    std::vector<MotionSource> sources;  // per keyframe, of the motion reaching it
    std::set<int> phantoms;             // keyframes that never arrived (bridged)
    bool origin_received = false;       // keyframe 0 arrived (not only start_session)
    bool unloaded = false;
    // The store keeps a prefix 0..stored-1 of the keyframes: after a failed keyframe write
    // (store_cut) the later ones are not written either (a gap would make the store unrestorable).
    int stored = 0;
    bool store_cut = false;
    bool memory_only = false;  // keyframes from `stored` on are not written: localisation mode

   private:
    friend class SessionTable;
    std::string name_;
    int backend_ = -1;
    std::int64_t store_row_ = -1;
    std::string vehicle_;
    int remote_id_ = -1;
    int loops_ = 0;
  };

  /// A piece of one of the odometry's sessions that this manager knows under another id (after
  /// a keyframe jump, or a session renamed because its id was taken): the odometry's (from,
  /// k >= base) is (to, k - base) here. `keyframes_only`: the id `from` is another vehicle's
  /// session here, so the loops naming it (the loop detectors') are that session's, not this one's.
  struct Piece {
    int from = -1, to = -1, base = 0;
    bool keyframes_only = false;
  };

  /// Checks the options (std::invalid_argument) and makes the hasher and the back-end; no store.
  SessionTable(const SessionManagerOptions& options, SessionLog log);
  SessionTable(const SessionTable&) = delete;
  SessionTable& operator=(const SessionTable&) = delete;

  // --- What it owns --------------------------------------------------------------------------
  const SessionManagerOptions& options() const { return options_; }
  const ImageHasher& hasher() const { return hasher_; }
  const MultiSessionBackend& backend() const { return *backend_; }
  /// For the maps' requests (join, split, optimise): sessions and loops enter and leave the
  /// back-end only through this table.
  MultiSessionBackend& backend() { return *backend_; }
  const SessionStore* store() const { return store_.get(); }
  SessionStore* store() { return store_.get(); }
  /// Opens options().store_path (SessionStore's constructor: StoreError) and restores every
  /// stored session, loop and map; returns the notes the restore made (damaged maps rebuilt...).
  /// Only on an empty table.
  std::vector<std::string> openStore();

  // --- Sessions and ids ----------------------------------------------------------------------
  bool has(int id) const { return sessions_.count(id) > 0; }
  const Session& at(int id) const;
  Session& at(int id);
  const std::map<int, Session>& sessions() const { return sessions_; }
  /// This vehicle's recording session, or -1.
  int active() const { return active_; }
  /// The id the next new session takes: past every id given in this run and every id the store
  /// holds or held.
  int nextId() const;
  int firstNewId() const { return first_new_id_; }
  int restoredSessions() const { return restored_sessions_; }
  bool restored(int id) const { return id < first_new_id_ && has(id); }
  bool deleted(int id) const { return deleted_.count(id) > 0; }
  int idOfBackend(int backend_session) const { return id_of_backend_.at(backend_session); }
  /// The session named `name`, or -1.
  int idOfName(const std::string& name) const;
  /// The session a request names: digits only, by its id (or, when no session has that id, a
  /// session an older store named so); anything else, by its name (names are unique); -1 when none.
  int findSession(const std::string& name_or_id) const;
  /// This table's id of a vehicle's session while it records here, or -1; or that ended here in
  /// this run (endedForeignSession).
  int foreignSession(const std::string& vehicle, int remote_session) const;
  int endedForeignSession(const std::string& vehicle, int remote_session) const;
  /// Other vehicles' sessions recording here: (vehicle, its session id there), in that order.
  std::vector<std::pair<std::string, int>> foreignRecording() const;
  /// Whether the keyframe is in the store (or `pending`: written in the same transaction).
  bool keyframeStored(int session, int keyframe, int pending_session = -1, int pending_keyframe = -1) const;
  /// The newest sessions in a row that have no keyframe.
  int trailingEmptySessions() const;

  // --- Changes that keep the invariants (std::logic_error when a caller would break one) -------
  /// A new session: `id` (valid, at or past nextId()) named `name` (unique; empty: the default
  /// name), started in the back-end, with its start as a placeholder origin. This vehicle's
  /// becomes the active one (the caller ended the one before); another vehicle's (`vehicle` set)
  /// records beside it.
  Session& open(int id, const std::string& name, double stamp_s, const std::string& vehicle = "", int remote_id = -1);
  /// This vehicle's active session ends (its back-end session too).
  void endActive();
  /// Another vehicle's session ends (its back-end session too); later keyframes of it are stale.
  void endForeign(const std::string& vehicle, int remote_session);
  /// Gives a session its store row (the store's id of it must be its id).
  void setStoreRow(int id, std::int64_t row);
  /// Removes a session from the table and the back-end (the back-end's indexes after it move
  /// down), with the loops on it; its id is never given again. Throws std::logic_error when the
  /// back-end refuses (a recording session, one sharing its map).
  void remove(int id);

  // --- The odometry's pieces and the held keyframe -------------------------------------------
  const std::vector<Piece>& pieces() const { return pieces_; }
  void addPiece(const Piece& p) { pieces_.push_back(p); }
  /// A keyframe id or loop end of the odometry's session as this manager names it (Piece);
  /// `detector_loop`: a loop detector's loop end (keyframes-only pieces left out).
  void toPiece(int* session, int* keyframe, bool detector_loop = false) const;
  /// The newest of this vehicle's sessions (not another vehicle's), or -1.
  int newestOwnSession() const;
  /// The held keyframe of a refused jump (one at most: bounded RAM).
  std::optional<KeyframeInput>& held() { return held_; }

  // --- Loops ---------------------------------------------------------------------------------
  const std::vector<Loop>& loops() const { return loops_; }
  std::int64_t loopStoreRow(std::size_t i) const { return store_loops_.at(i); }
  const std::vector<std::int64_t>& loopStoreRows() const { return store_loops_; }
  /// A loop in session ids into the back-end (std::invalid_argument as the back-end refuses it:
  /// nothing changed), with its store row (-1: none yet). Returns its index.
  std::size_t acceptLoop(const Loop& loop, std::int64_t store_row);
  void setLoopStoreRow(std::size_t i, std::int64_t row) { store_loops_.at(i) = row; }

  // --- The audit trail, the mode, the counters -----------------------------------------------
  const std::vector<HistoryEntry>& history() const { return history_; }
  /// Its entries from earlier runs (the first ones).
  std::ptrdiff_t historyRestored() const { return history_restored_; }
  void appendHistory(HistoryEntry e) { history_.push_back(std::move(e)); }
  bool localising() const { return localising_; }
  /// When localisation mode began (UTC), for its audit-trail entry.
  const std::string& localisingSince() const { return localising_since_; }
  void setLocalising(bool on, const std::string& since);
  const SessionManagerStats& stats() const { return stats_; }
  SessionManagerStats& stats() { return stats_; }

 private:
  SessionManagerOptions options_;
  SessionLog log_;
  ImageHasher hasher_;
  std::unique_ptr<MultiSessionBackend> backend_;
  std::unique_ptr<SessionStore> store_;
  std::map<int, Session> sessions_;
  std::vector<int> id_of_backend_;  // back-end index -> session id
  int active_ = -1;
  int restored_sessions_ = 0;
  int first_new_id_ = 0;   // nextId() once the store is restored: ids below it are stored sessions'
  int next_id_floor_ = 0;  // past every id given so far (a deleted session's id is not reused)
  std::set<int> deleted_;  // ids of sessions deleted in this run
  std::map<std::pair<std::string, int>, int> foreign_ids_;    // (vehicle, its session) recording here -> id
  std::map<std::pair<std::string, int>, int> ended_foreign_;  // ended in this run -> id: later keyframes refused
  // Every piece of this run, in order: a loop can name a keyframe of any of them. One per jump or
  // renamed session (each also opens a session, so bounded as sessions are).
  std::vector<Piece> pieces_;
  std::optional<KeyframeInput> held_;
  std::vector<Loop> loops_;                // accepted loops, session ids
  std::vector<std::int64_t> store_loops_;  // back-end loop index -> store loop id (-1: not stored)
  std::vector<HistoryEntry> history_;      // the audit trail
  std::ptrdiff_t history_restored_ = 0;
  bool localising_ = false;
  std::string localising_since_;
  SessionManagerStats stats_;
};

}  // namespace core
}  // namespace uw_multislam
