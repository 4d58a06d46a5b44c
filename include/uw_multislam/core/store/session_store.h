// The session store: one SQLite file that keeps every session of every mission.
//
// What it holds (schema version kSchemaVersion, tables in session_store_open.cpp):
//  - the hash settings (mode, seed, n, the HALOC vectors as exact text): hashes of different
//    runs are comparable only with the same vectors, so a store refuses other settings;
//  - sessions (name, stamps, state, camera intrinsics);
//  - keyframes (frame index, stamp, altitude, keypoint pixel coordinates as float32, descriptors
//    as uint8, the hash as float32, an optional grey JPEG of the keyframe,
//    core/store/keyframe_image.h) with the odometry motion that reaches each (mean and
//    covariance) and the loops it closed;
//  - maps (chains of sessions, links with the loops they summarise, the optimised motions with
//    their marginal covariances), loop states and the user's split pairs.
//
// Crash safety: WAL journal, synchronous=FULL, one transaction per keyframe (keyframe, its motion
// and its loops together), per loop and per position prior arriving on their own. A kill -9 or a
// power cut loses at most the keyframe in flight; the map state (saveMaps) is written at joins,
// splits and session ends, and a reload of a map whose sessions grew since its last save extends
// it with their odometry.
//
// Bad files: the file is checked read-only first (SQLite header, application id, schema version,
// quick_check), so a failed open never writes to it. Every error is a StoreError whose message
// names the file and the problem.
//
// Not thread-safe: one store object per thread (SQLite serialises writers across processes).
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include <cstdint>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "uw_multislam/core/common/file_identity.h"
#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/frontend/features.h"
#include "uw_multislam/core/frontend/nav_prior.h"
#include "uw_multislam/core/geometry/uncertain_pose.h"
#include "uw_multislam/core/loops/haloc.h"

struct sqlite3;
struct sqlite3_stmt;

namespace uw_multislam {
namespace core {

class StoreError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

enum class StoredSessionState { kRecording, kFinished };

struct StoredSession {
  std::int64_t id = 0;  // the store's id (store order)
  std::string name;
  StoredSessionState state = StoredSessionState::kRecording;
  double start_stamp_s = 0.0, end_stamp_s = 0.0;
  CameraIntrinsics camera;
  int keyframes = 0;
};

/// Why a camera cannot be a session's stored camera (sessions() would refuse to read the row, and
/// one such row would block the whole store): "" when it can. 0x0 is an unknown camera (a session
/// without keyframes yet).
std::string unusableCamera(const CameraIntrinsics& camera);

struct StoredKeyframe {
  std::int64_t session = 0;  // store id
  int keyframe = 0;          // 0, 1, ... within the session
  int frame_index = 0;
  double stamp_s = 0.0;
  double altitude_m = 0.0;
  cv::Size image_size;
  std::vector<cv::Point2f> points;                     // keypoint pixel coordinates, descending response
  cv::Mat descriptors;                                 // points.size() x 128, CV_8U (CV_32F accepted when writing)
  Eigen::VectorXf hash;                                // HalocProjections::kHashSize values
  std::vector<std::uint8_t> thumbnail;                 // the keyframe image (keyframe_image.h; JPEG), may be empty
  MotionSource motion_source = MotionSource::kVisual;  // of the motion written with it

  /// Its features as the loop detector takes them: keypoints at the stored pixel positions (size
  /// 1; response order kept), the stored descriptors (CV_8U) and image size.
  FrameFeatures features() const;
};

/// A loop as stored: store session ids, keyframe ids, what offline_slam reports, its state.
struct StoredLoop {
  std::int64_t id = -1;  // store id (set by the store)
  std::int64_t session_a = 0, session_b = 0;
  int keyframe_a = 0, keyframe_b = 0;
  bool global = false;
  int inliers = 0;
  UncertainPose2 z;  // pose of b in a
  bool summarised = false, applied = false, refused = false;
  /// The nav's placement of a session (SessionManager::addNavPlacement), not a visual loop: a row
  /// of the table nav_placements (created like provenance, no new schema version; a build
  /// before it reads the loop as a global loop whose link it restores the same).
  bool nav_placement = false;
};

struct StoredLink {
  UncertainPose2 measured;
  std::vector<std::int64_t> loops;  // store loop ids
};

/// An absolute position prior on a keyframe (a GPS or USBL fix: MultiSessionBackend::addPositionPrior),
/// in the frame of the map it is saved with (that map's first session's).
struct StoredPrior {
  std::int64_t session = 0;  // store id
  int keyframe = 0;
  Eigen::Vector2d position = Eigen::Vector2d::Zero();
  Eigen::Matrix2d covariance = Eigen::Matrix2d::Identity();
  bool applied = false;  // in the map's estimate for good (the IEKF's)
};

/// A map: store session ids; motions as MapState (empty: not yet optimised, use the odometry).
struct StoredMap {
  std::vector<std::int64_t> chain;
  std::vector<StoredLink> links;
  std::vector<UncertainPose2> motions;
  int pending = 0;
  /// Its keyframes' position priors, in its frame: the table position_priors (created like
  /// provenance, no new schema version; a build before it restores the map without them).
  std::vector<StoredPrior> priors;
};

/// Where a session of a merged store came from (merge_stores): one row per session
/// copied from another store. Kept in the table `provenance`, which a store gets when it is opened
/// for writing (like the keyframes_frame index: no build before it reads it, so no new schema
/// version); a store without the table, or a session never merged, has no row.
struct SessionProvenance {
  std::int64_t session = 0;         // store id in this store
  std::string source_file;          // the store it was copied from (as given to merge_stores)
  std::int64_t source_session = 0;  // its store id there
  std::string source_name;          // its name there (merge_stores renames a clash)
  std::string vehicle, dive;        // labels given to merge_stores (default: the file's stem, the name)
};

/// One entry of the audit trail: every join, split, manual link, deletion and
/// mode change, when, why and with which loops. Kept in the table `history`, which a store gets
/// when it is opened for writing (like `provenance`: no new schema version). Sessions and loops
/// are named by the session ids of the run that wrote the entry (the services' ids, which a later
/// run gives the same stored sessions as long as none before them is deleted).
struct HistoryEntry {
  std::int64_t id = 0;   // 1, 2, ... in order
  std::string time_utc;  // wall clock, ISO 8601 (2026-11-25T02:13:04Z)
  std::string kind;      // join, split, link, delete, mode
  std::string cause;     // automatic (the join rule), service (a back-end service), tool (offline_slam)
  std::string sessions;  // join: the two maps' chains "0,1+2"; split: "2+0,1" (the session, the rest); else "0,1"
  std::string loops;     // the loops involved, "a:ka>b:kb" separated by spaces (may be empty)
  std::string message;   // what happened, in words
};

/// Now, wall clock, UTC, as the audit trail writes it: ISO 8601 to the second (2026-11-25T02:13:04Z).
std::string utcTimestamp();

/// How a store is opened: kReadWrite (the default: created when missing, locked for writing),
/// kReadOnly (for tools that only read it, e.g. export_survey: a missing or empty file is an
/// error, nothing is created or locked, and every write is refused by SQLite) or kCreateNew (a
/// new store, created exclusively: anything already at the path, a link too, is refused).
enum class StoreAccess { kReadWrite, kReadOnly, kCreateNew };

class SessionStore {
 public:
  static constexpr int kSchemaVersion = 2;                    // 2: motions.source
  static constexpr std::int32_t kApplicationId = 0x55574d53;  // "UWMS"

  /// Opens the store at `path`, creating it (and nothing else: 0600, exclusively) when missing or
  /// empty. An exclusive flock() on the file itself is held as long as this object lives: a second
  /// writer (another process, or a second SessionStore of this process, through this path or any
  /// other one to the same file: a hard link, a bind mount) is refused with the holder named. The
  /// file is checked read-only before anything is written. A refused open leaves nothing behind
  /// (no file it created, no -wal/-shm). Throws StoreError.
  /// kReadOnly: the same checks, then a read-only open (no lock, no file created).
  explicit SessionStore(const std::string& path, StoreAccess mode = StoreAccess::kReadWrite);
  ~SessionStore();
  SessionStore(const SessionStore&) = delete;
  SessionStore& operator=(const SessionStore&) = delete;

  const std::string& path() const { return path_; }

  /// The store's hash settings: a store without them takes `mine`; one with other settings is
  /// refused (StoreError naming both).
  void checkHashSettings(const HashSettings& mine);
  /// The stored settings, if any.
  bool hashSettings(HashSettings* out) const;

  /// A new session (state recording). Returns its store id: `id` when given (>= 0; the session
  /// manager gives the id the session already has), else nextSessionId() (0 in a new store, as the
  /// session manager numbers). StoreError when `id` is taken or was a deleted session's.
  std::int64_t addSession(const std::string& name, const CameraIntrinsics& camera, double start_stamp_s,
                          std::int64_t id = -1);
  /// The smallest id no session has had: past every stored id and every deleted one (0 for a
  /// store that never held a session). A session's store id is its id for life (README
  /// "Session ids"), so a deleted session's id is never given again, also after a restart.
  std::int64_t nextSessionId() const;
  /// Gives a session's row its camera (a row made before the session's first keyframe arrived,
  /// e.g. by saving the maps after start_session, has none: 0x0). Refused like addSession's.
  void setSessionCamera(std::int64_t session, const CameraIntrinsics& camera);
  /// Marks a session finished.
  void endSession(std::int64_t session, double end_stamp_s);

  /// One transaction: the keyframes lost in a gap just before it (`gap`: no features, no image,
  /// a zero hash; each with `gap_motion`), the keyframe, the odometry motion reaching it (nullptr
  /// for keyframe 0) and the loops it closed (their ids are set). A keyframe with no features, no
  /// image and a zero hash (a lost one, also the placeholder origin) is a row of a few dozen bytes
  /// (an empty hash blob, read back as the zero hash): a gap costs the pages of the rows it adds
  /// to the one transaction, not a transaction and 1.5 kB per lost keyframe. Throws StoreError
  /// (the transaction is rolled back: nothing of the keyframe or its gap is kept).
  void addKeyframe(const StoredKeyframe& keyframe, const UncertainPose2* motion, std::vector<StoredLoop>* loops,
                   const std::vector<StoredKeyframe>& gap = {}, const UncertainPose2* gap_motion = nullptr);
  /// One transaction: loops that arrive on their own (the live system's loop messages); their
  /// ids are set. Both keyframes must be stored.
  void addLoops(std::vector<StoredLoop>* loops);

  /// One transaction: a position prior accepted since the maps were last saved (the live
  /// system's fixes, as addLoops for loops), in the frame of map `map` (the store id of its first
  /// session); saveMaps rewrites every prior from the back-end. The keyframe must be stored. The
  /// stored map's pending count grows by one (its stored motions are without the prior: a restart
  /// optimises it again). A session alone in its map since it started has no stored map until a
  /// join, a split or its end saves them: then (`map` is the prior's session, in no stored map)
  /// that map is stored too, the session alone without motions (restored from its odometry), so
  /// that a restart has the prior's frame.
  void addPositionPrior(std::int64_t map, const StoredPrior& prior);

  /// One transaction: replaces the map state (maps, links, split pairs) and updates the states
  /// of the given loops.
  void saveMaps(const std::vector<StoredMap>& maps, const std::vector<StoredLoop>& loop_states,
                const std::vector<std::pair<std::int64_t, std::int64_t>>& split_pairs);

  /// One transaction: deletes sessions, each with everything that names it (keyframes, motions, the
  /// loops on it, split pairs) and takes it out of the maps: a chain it ends or starts loses it
  /// and its link; a chain it sits inside splits into the sessions before and after it. A map
  /// that changed keeps no optimised motions (restored from the odometry and its links, pending
  /// optimisation); links lose the ids of deleted loops. Every other row is left as it is.
  /// StoreError naming the id when one of them is not stored (then nothing changed).
  /// `entry` (optional): the deletion's audit-trail entry, written in the same transaction.
  void deleteSessions(const std::vector<std::int64_t>& sessions, const HistoryEntry* entry = nullptr);

  std::vector<StoredSession> sessions() const;
  /// What keyframes() reads besides the frame data (index, stamp, altitude, image size): nothing,
  /// the hash only (what the hash search keeps in RAM when paging), or every blob.
  enum class KeyframeColumns { kFrame, kHash, kAll };
  /// The keyframes of a session in order; `with_features` false leaves points, descriptors,
  /// hash and thumbnail empty.
  std::vector<StoredKeyframe> keyframes(std::int64_t session, bool with_features = true) const {
    return keyframes(session, with_features ? KeyframeColumns::kAll : KeyframeColumns::kFrame);
  }
  std::vector<StoredKeyframe> keyframes(std::int64_t session, KeyframeColumns columns) const;
  /// One keyframe's frame data, points and descriptors (hash and thumbnail left empty): what
  /// verifying a loop against it needs. StoreError naming the keyframe when it is not stored or
  /// its blobs have the wrong size.
  StoredKeyframe keyframeFeatures(std::int64_t session, int keyframe) const;
  /// The session's keyframes' JPEG thumbnails in keyframe order (empty where none), without the
  /// features (a 10k-keyframe session's descriptors are 640 MB; export_survey needs only these).
  std::vector<std::vector<std::uint8_t>> thumbnails(std::int64_t session) const;
  /// The session's odometry motions, [k-1] reaching keyframe k.
  std::vector<UncertainPose2> odometry(std::int64_t session) const;
  /// Where each of those motions came from (visual, nav, fused, fallback), [k-1] for keyframe k.
  std::vector<MotionSource> motionSources(std::int64_t session) const;
  std::vector<StoredLoop> loops() const;
  std::vector<StoredMap> maps() const;
  std::vector<std::pair<std::int64_t, std::int64_t>> splitPairs() const;
  /// Records where a session came from (merge_stores). StoreError when the session is not stored.
  void addProvenance(const SessionProvenance& p);
  /// Every session's provenance, by session id; empty for a store never merged into.
  std::vector<SessionProvenance> provenance() const;
  /// Appends an entry to the audit trail with its id (past the last one; 0: the next) and
  /// returns the id. StoreError for an id already there.
  std::int64_t addHistory(HistoryEntry e);
  /// The audit trail in order; empty for a store without the table.
  std::vector<HistoryEntry> history() const;

  /// The maps' geographic datum as a set_datum at sea left it (core/export/geo_datum.h datumText):
  /// a row of the meta table; nullopt when none was ever set.
  std::optional<std::string> datum() const;
  void setDatum(const std::string& text);

  /// A cap on the file's size (SQLite's max_page_count, rounded down to whole pages; never below
  /// what the file holds already): a write that would grow it past the cap fails as on a full
  /// disk ("the disk is full"), its transaction rolled back. 0: no cap.
  void setMaxBytes(std::uint64_t bytes);

  /// Writes the WAL back into the file (e.g. before measuring or copying it).
  void checkpoint();

  /// For tests: the SQLite handle (e.g. to set max_page_count to simulate a full disk).
  sqlite3* handle() { return db_; }

 private:
  /// The store's file, open for the object's life: its identity, and for a writer the flock() on
  /// it, held through this descriptor. Released (or parked: session_store_open.cpp, HeldFiles) with the
  /// object, also when the constructor throws.
  struct HeldFile {
    FileId id;
    int fd = -1;
    bool writer = false;
    HeldFile() = default;
    HeldFile(const HeldFile&) = delete;
    HeldFile& operator=(const HeldFile&) = delete;
    ~HeldFile();
  };
  /// Opens (or creates, exclusively) the file, refuses a link, a second writer of this process
  /// (any path to the file) or of another one (the flock); fresh: nothing stored in it yet.
  void openFile(StoreAccess mode, bool* fresh);
  void checkStillTheFile() const;  // the path still names the file held (SQLite opens it by name)
  void removeCreated(const bool beside_existed[2]) noexcept;  // a failed open removes what it created
  void learnKind();                                           // descriptor_bytes_ from the meta row, if written
  HeldFile file_;
  bool created_ = false;  // the file was created by this object's open (until the open succeeds)
  class Statement;
  void exec(const std::string& sql) const;
  [[noreturn]] void fail(const std::string& what) const;
  void begin();
  void commit();
  void rollback() noexcept;
  void insertLoops(std::vector<StoredLoop>* loops);
  /// One keyframe's rows, inside the caller's transaction (placeholders in their minimal form).
  void insertKeyframe(const StoredKeyframe& keyframe, const UncertainPose2* motion);
  /// Replaces maps, map_sessions and links (inside the caller's transaction).
  void writeMaps(const std::vector<StoredMap>& maps);
  void deleteOne(std::int64_t session);  // inside the caller's transaction
  void readKeyframe(sqlite3_stmt* row, std::int64_t session, KeyframeColumns columns, bool features,
                    StoredKeyframe* out) const;
  Statement& cached(const char* sql);
  bool hasTable(const char* name) const;

  std::string path_;
  sqlite3* db_ = nullptr;
  int descriptor_bytes_ = 0;  // of the store's feature kind, from its meta row once written (0: any)
  std::vector<std::pair<const char*, std::unique_ptr<Statement>>> cache_;
};

}  // namespace core
}  // namespace uw_multislam
