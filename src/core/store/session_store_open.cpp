// The session store's file: the open and its checks, the lock that makes one writer, the schema
// and what a writer adds to an older store (indexes, tables), and the hash settings.
#include "uw_multislam/core/store/session_store.h"

#include <fcntl.h>
#include <sqlite3.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <sys/sysmacros.h>
#include <unistd.h>

#include <cctype>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>

#include "session_store_detail.h"
#include "uw_multislam/core/common/thread_annotations.h"

namespace uw_multislam {
namespace core {

using namespace store_detail;  // NOLINT: the store's own helpers

namespace {

// Blobs are raw arrays in the host's byte order (little-endian on x86-64 and the Jetson's ARM).
const char* kSchema = R"sql(
CREATE TABLE meta(key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE sessions(
  id INTEGER PRIMARY KEY,
  name TEXT NOT NULL,
  state TEXT NOT NULL CHECK(state IN ('recording', 'finished')),
  start_stamp REAL NOT NULL, end_stamp REAL NOT NULL,
  cam_width INTEGER NOT NULL, cam_height INTEGER NOT NULL,
  cam_fx REAL NOT NULL, cam_fy REAL NOT NULL, cam_cx REAL NOT NULL, cam_cy REAL NOT NULL);
CREATE TABLE keyframes(
  session INTEGER NOT NULL REFERENCES sessions(id),
  keyframe INTEGER NOT NULL,
  frame_index INTEGER NOT NULL, stamp REAL NOT NULL, altitude REAL NOT NULL,
  image_width INTEGER NOT NULL, image_height INTEGER NOT NULL,
  num_features INTEGER NOT NULL,
  points BLOB,       -- num_features x 2 float32, pixel coordinates
  descriptors BLOB,  -- num_features x 128 uint8
  hash BLOB NOT NULL,-- 384 float32
  thumbnail BLOB,    -- JPEG or NULL
  PRIMARY KEY(session, keyframe));
CREATE TABLE motions(  -- odometry X_k^{k-1}, written with keyframe k
  session INTEGER NOT NULL, keyframe INTEGER NOT NULL,
  x REAL NOT NULL, y REAL NOT NULL, yaw REAL NOT NULL,
  cov BLOB NOT NULL,  -- 9 float64, row-major
  source TEXT NOT NULL DEFAULT 'visual' CHECK(source IN ('visual', 'nav', 'fused', 'fallback')),
  PRIMARY KEY(session, keyframe));
CREATE TABLE loops(
  id INTEGER PRIMARY KEY,
  session_a INTEGER NOT NULL, keyframe_a INTEGER NOT NULL,
  session_b INTEGER NOT NULL, keyframe_b INTEGER NOT NULL,
  kind TEXT NOT NULL CHECK(kind IN ('local', 'global')), inliers INTEGER NOT NULL,
  x REAL NOT NULL, y REAL NOT NULL, yaw REAL NOT NULL, cov BLOB NOT NULL,
  summarised INTEGER NOT NULL DEFAULT 0, applied INTEGER NOT NULL DEFAULT 0, refused INTEGER NOT NULL DEFAULT 0);
CREATE TABLE maps(
  id INTEGER PRIMARY KEY,   -- store id of its first session
  pending INTEGER NOT NULL,
  motions BLOB);            -- n x 12 float64 (x, y, yaw, covariance row-major) or NULL
CREATE TABLE map_sessions(map INTEGER NOT NULL, position INTEGER NOT NULL, session INTEGER NOT NULL,
  PRIMARY KEY(map, position));
CREATE TABLE links(map INTEGER NOT NULL, position INTEGER NOT NULL,  -- joins chain[position] -> chain[position + 1]
  x REAL NOT NULL, y REAL NOT NULL, yaw REAL NOT NULL, cov BLOB NOT NULL,
  loops BLOB,               -- int64 store loop ids it summarises
  PRIMARY KEY(map, position));
CREATE TABLE split_pairs(session_a INTEGER NOT NULL, session_b INTEGER NOT NULL, PRIMARY KEY(session_a, session_b));
)sql";

// A covering index of the keyframes' frame data (for the start-up). A keyframe row is 74 kB: its
// frame data share a page with the start of its points, so reading them for every keyframe at a
// restart (the session manager and restoreStore do) reads one 4 kB page per keyframe; from this
// index, about 60 bytes. An index changes nothing any build reads or writes (SQLite keeps it up to
// date whichever build writes), so it needs no new schema version: a store without it (written
// before) gets it when it is opened for writing, once.
const char* kFrameIndex =
    "CREATE INDEX IF NOT EXISTS keyframes_frame ON keyframes(session, keyframe, frame_index, stamp, altitude, "
    "image_width, image_height, num_features)";

// The hashes the start-up reads for every stored keyframe, with the frame data: from
// the row they sat behind its points and descriptors, so SQLite walked the row's whole overflow
// chain (about 18 pages) to reach them; an index entry of about 1.6 kB is one page and one
// overflow page. Like kFrameIndex no new schema version: created when the store is opened for
// writing (once: 22.6 s measured for a store of 100 k keyframes), about 1.6 kB a keyframe on
// disk (2 %). kFrameIndex stays: the planner takes the narrower one for frame data.
const char* kHashIndex =
    "CREATE INDEX IF NOT EXISTS keyframes_hash ON keyframes(session, keyframe, frame_index, stamp, altitude, "
    "image_width, image_height, num_features, hash)";

// Where merged sessions came from (merge_stores). Like kFrameIndex, created when the
// store is opened for writing: no build before it reads it, so no new schema version.
const char* kProvenanceTable =
    "CREATE TABLE IF NOT EXISTS provenance(session INTEGER PRIMARY KEY REFERENCES sessions(id), "
    "source_file TEXT NOT NULL, source_session INTEGER NOT NULL, source_name TEXT NOT NULL, "
    "vehicle TEXT NOT NULL, dive TEXT NOT NULL)";

// Which loops are the nav's placements of a session (SessionManager::addNavPlacement), not visual
// loops. Created like provenance, when the store is opened for writing: a build before it reads
// such a loop as a global loop (and restores the map's link from it all the same).
const char* kNavPlacementTable = "CREATE TABLE IF NOT EXISTS nav_placements(loop INTEGER PRIMARY KEY)";
// Position priors (GPS or USBL fixes) with the map they were saved in, written with the maps;
// created like provenance.
const char* kPositionPriorTable =
    "CREATE TABLE IF NOT EXISTS position_priors(map INTEGER NOT NULL, session INTEGER NOT NULL, keyframe INTEGER "
    "NOT NULL, x REAL NOT NULL, y REAL NOT NULL, cxx REAL NOT NULL, cxy REAL NOT NULL, cyy REAL NOT NULL, "
    "applied INTEGER NOT NULL)";

// The audit trail: created like provenance, when the store is opened for writing.
const char* kHistoryTable =
    "CREATE TABLE IF NOT EXISTS history(id INTEGER PRIMARY KEY, time_utc TEXT NOT NULL, kind TEXT NOT NULL, "
    "cause TEXT NOT NULL, sessions TEXT NOT NULL, loops TEXT NOT NULL, message TEXT NOT NULL)";

// A path as the path part of an SQLite URI filename.
std::string uriEscape(const std::string& path) {
  std::string out;
  for (unsigned char c : path) {
    if (std::isalnum(c) || c == '/' || c == '.' || c == '_' || c == '-' || c == '~') {
      out += static_cast<char>(c);
    } else {
      char buf[4];
      std::snprintf(buf, sizeof buf, "%%%02X", c);
      out += buf;
    }
  }
  return out;
}

// What a refused second writer is told about the holder: "pid N (its command) on HOST".
std::string describeProcess(long pid) {
  std::string comm;
  std::ifstream in("/proc/" + std::to_string(pid) + "/comm");
  std::getline(in, comm);
  char host[128] = {};
  gethostname(host, sizeof host - 1);
  return "pid " + std::to_string(pid) + (comm.empty() ? "" : " (" + comm + ")") + " on " + host;
}

// The process holding an flock() on the file: the kernel lists every lock in /proc/locks as
// "N: FLOCK ADVISORY WRITE <pid> <major>:<minor>:<inode> 0 EOF" (major and minor in hex). -1 when
// it is not listed (no /proc, a lock taken on another host over NFS).
long flockHolder(const FileId& id) {
  std::ifstream in("/proc/locks");
  std::string line;
  while (std::getline(in, line)) {
    std::istringstream words(line);
    std::string number, kind, advisory, access, where;
    long pid = -1;
    words >> number >> kind;
    if (kind == "->") words >> kind;  // a waiter (none with LOCK_NB, but the format allows it)
    if (kind != "FLOCK" || !(words >> advisory >> access >> pid >> where)) continue;
    unsigned int major = 0, minor = 0;
    unsigned long long inode = 0;
    if (std::sscanf(where.c_str(), "%x:%x:%llu", &major, &minor, &inode) != 3) continue;
    if (major == ::major(id.device) && minor == ::minor(id.device) && inode == id.inode) return pid;
  }
  return -1;
}

// The store files this process holds open, by identity (device, inode). SQLite locks a database
// with POSIX advisory (fcntl) locks, which belong to a process and an inode: closing ANY
// descriptor of the inode in the process drops all of them ("How To Corrupt An SQLite Database
// File", 2.2). So a descriptor of a file another store of this process holds is never closed while
// that store lives: it is parked here and closed with the last one. The registry also refuses a
// second writer in this process through another path (a hard link, a bind mount) before any
// descriptor of the file is opened.
class HeldFiles {
 public:
  static HeldFiles& instance() {
    static HeldFiles held;
    return held;
  }
  /// The description of this process's writer of the file; "" when none.
  std::string writerOf(const FileId& id) {
    MutexLock lock(&mutex_);
    const auto it = held_.find(id);
    return it == held_.end() || it->second.writers == 0 ? "" : it->second.holder;
  }
  /// Registers a store's descriptor of the file; false (with the holder) when a writer is asked
  /// for and this process has one: then the descriptor is parked, not closed.
  bool enter(const FileId& id, int fd, bool writer, std::string* holder) {
    MutexLock lock(&mutex_);
    Entry& e = held_[id];
    if (writer && e.writers > 0) {
      *holder = e.holder;
      e.parked.push_back(fd);
      return false;
    }
    ++e.users;
    if (writer) {
      ++e.writers;
      e.holder = describeProcess(::getpid());
    }
    return true;
  }
  /// A store's descriptor goes (entered: it was registered): closed, with the parked ones, when no
  /// other store of this process holds the file; else parked.
  void leave(const FileId& id, int fd, bool entered, bool writer) {
    MutexLock lock(&mutex_);
    const auto it = held_.find(id);
    if (it == held_.end()) {
      ::close(fd);
      return;
    }
    Entry& e = it->second;
    if (entered) {
      --e.users;
      if (writer) --e.writers;
    }
    if (e.users > 0) {
      e.parked.push_back(fd);
      return;
    }
    for (int p : e.parked) ::close(p);
    ::close(fd);
    held_.erase(it);
  }

 private:
  struct Entry {
    int users = 0, writers = 0;
    std::string holder;       // the writer's description
    std::vector<int> parked;  // descriptors closed with the last user
  };
  Mutex mutex_;
  std::map<FileId, Entry> held_ GUARDED_BY(mutex_);
};

std::string inUse(const std::string& path, const std::string& who) {
  return "session store " + path + ": in use by " + who +
         "; one process writes a store at a time (stop it, or give this run another store)";
}
}  // namespace

SessionStore::HeldFile::~HeldFile() {
  if (fd < 0) return;
  // Released now, also when the descriptor is parked for a reader of this process (its close would
  // come later); flock(LOCK_UN) leaves SQLite's fcntl locks alone.
  if (writer) ::flock(fd, LOCK_UN);
  HeldFiles::instance().leave(id, fd, true, writer);
}

void SessionStore::openFile(StoreAccess mode, bool* fresh) {
  namespace fs = std::filesystem;
  const bool writer = mode != StoreAccess::kReadOnly;
  std::error_code ec;
  int fd = -1;
  struct stat st {};
  // A few tries: the name may be created or removed by another process between the look and the open.
  for (int attempt = 0; fd < 0; ++attempt) {
    const bool exists = ::lstat(path_.c_str(), &st) == 0;
    if (exists && mode == StoreAccess::kCreateNew)
      throw StoreError("session store " + path_ + ": exists; a new store was asked for (the file was left as it is)");
    if (exists) {
      // A store holds a mission's images' features and the vehicle's track: never through a
      // symbolic link (it could point anywhere).
      if (S_ISLNK(st.st_mode))
        throw StoreError("session store " + path_ + ": a symbolic link; give the file's own path");
      if (!S_ISREG(st.st_mode)) throw StoreError("session store " + path_ + ": not a regular file");
      // Refused before a descriptor of the file is opened (closing it would drop the locks this
      // process's writer holds through SQLite).
      if (writer) {
        const std::string who = HeldFiles::instance().writerOf({st.st_dev, st.st_ino});
        if (!who.empty()) throw StoreError(inUse(path_, who + ", this process"));
      }
      fd = ::open(path_.c_str(), O_RDONLY | O_NOFOLLOW | O_NONBLOCK | O_NOCTTY | O_CLOEXEC);
      if (fd < 0) {
        const int err = errno;
        if (err == ENOENT && attempt < 3) continue;  // removed meanwhile: look again
        if (err == ELOOP) throw StoreError("session store " + path_ + ": a symbolic link; give the file's own path");
        throw StoreError("session store " + path_ + ": cannot read the file (" + std::strerror(err) + ")");
      }
    } else {
      if (!writer) throw StoreError("session store " + path_ + ": no such file");
      const fs::path parent = fs::path(path_).parent_path();
      if (!parent.empty() && !fs::is_directory(parent, ec))
        throw StoreError("session store " + path_ + ": the directory " + parent.string() + " does not exist");
      // Created here, exclusively and 0600 (SQLite gives its -wal and -shm files the database's
      // mode), refusing a link or a file that appeared meanwhile.
      fd = ::open(path_.c_str(), O_RDWR | O_CREAT | O_EXCL | O_NOFOLLOW | O_NOCTTY | O_CLOEXEC, 0600);
      if (fd < 0) {
        const int err = errno;
        if (err == EEXIST && attempt < 3) continue;  // made meanwhile: look again
        std::string why = std::strerror(err);
        if (err == EACCES || err == EROFS || err == EPERM) why = "read-only path (" + why + ")";
        throw StoreError("session store " + path_ + ": cannot create: " + why);
      }
      created_ = true;
    }
  }
  FileId id;
  if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
    HeldFiles::instance().leave({st.st_dev, st.st_ino}, fd, false, false);
    throw StoreError("session store " + path_ + ": not a regular file");
  }
  id = {st.st_dev, st.st_ino};
  std::string holder;
  if (!HeldFiles::instance().enter(id, fd, writer, &holder)) throw StoreError(inUse(path_, holder + ", this process"));
  file_.id = id;
  file_.fd = fd;
  file_.writer = writer;
  if (writer) {
    // One writer per store for the whole run. SQLite's own locks are per transaction: two
    // processes writing one store both succeed, and the last one to save the maps silently wins;
    // two paths to one file (hard links) even get a WAL each and corrupt it ("How To Corrupt An
    // SQLite Database File", 2.5). So the lock is on the file itself: an flock() through this
    // descriptor, held while this object lives, released by the kernel when the process dies
    // (kill -9 included), so a stale lock never blocks a restart. flock() locks belong to the open
    // file and are independent of SQLite's fcntl() locks on Linux.
    if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
      const int err = errno;
      created_ = false;  // another process holds what we just made: it is theirs now
      if (err != EWOULDBLOCK) throw StoreError("session store " + path_ + ": cannot lock it: " + std::strerror(err));
      const long pid = flockHolder(id);
      throw StoreError(inUse(path_, pid > 0 ? describeProcess(pid) : "another process"));
    }
  }
  *fresh = created_ || st.st_size == 0;  // 0 bytes: created but never written (a crash before the first commit)
}

void SessionStore::checkStillTheFile() const {
  struct stat st {};
  if (::lstat(path_.c_str(), &st) != 0 || FileId{st.st_dev, st.st_ino} != file_.id)
    throw StoreError("session store " + path_ + ": the file was replaced while it was being opened");
}

void SessionStore::removeCreated(const bool beside_existed[2]) noexcept {
  // Only the file made here, and what SQLite made beside it (never a file or link that was there
  // before): a refused open leaves nothing.
  struct stat st {};
  if (!created_ || ::lstat(path_.c_str(), &st) != 0 || FileId{st.st_dev, st.st_ino} != file_.id) return;
  ::unlink(path_.c_str());
  const char* suffixes[2] = {"-wal", "-shm"};
  for (int i = 0; i < 2; ++i)
    if (!beside_existed[i] && ::lstat((path_ + suffixes[i]).c_str(), &st) == 0 && S_ISREG(st.st_mode))
      ::unlink((path_ + suffixes[i]).c_str());
}

SessionStore::SessionStore(const std::string& path, StoreAccess mode) : path_(path) {
  namespace fs = std::filesystem;
  std::error_code ec;
  const bool read_only = mode == StoreAccess::kReadOnly;
  bool fresh = false;
  openFile(mode, &fresh);                   // file_ releases it if anything below throws
  bool beside_existed[2] = {false, false};  // -wal, -shm
  try {
    // SQLite opens "<store>-wal" and "<store>-shm" by name and would follow a link there.
    const char* suffixes[2] = {"-wal", "-shm"};
    for (int i = 0; i < 2; ++i) {
      struct stat beside {};
      beside_existed[i] = ::lstat((path + suffixes[i]).c_str(), &beside) == 0;
      if (beside_existed[i] && !S_ISREG(beside.st_mode))
        throw StoreError("session store " + path + ": its " + suffixes[i] + " file is " +
                         (S_ISLNK(beside.st_mode) ? "a symbolic link" : "not a regular file") +
                         "; the file was left as it is");
    }
    if (read_only && fresh) throw StoreError("session store " + path + ": an empty file (no session was ever stored)");
    if (!fresh) {
      // Check before SQLite touches it: the header, then a read-only open.
      char header[16] = {};
      if (::pread(file_.fd, header, sizeof header, 0) != static_cast<ssize_t>(sizeof header) ||
          std::memcmp(header, "SQLite format 3", 16) != 0)
        throw StoreError("session store " + path +
                         ": not an SQLite database (wrong header); the file was left as it is");
      // Read-only; without a WAL beside it (no crash, no other writer) also "immutable", so that
      // SQLite creates no -wal/-shm files next to a file it then refuses.
      sqlite3* ro = nullptr;
      const bool has_wal = fs::exists(path + "-wal", ec);
      const std::string uri = "file:" + uriEscape(fs::absolute(path, ec).string()) + (has_wal ? "" : "?immutable=1");
      const int rc =
          sqlite3_open_v2(uri.c_str(), &ro, SQLITE_OPEN_READONLY | SQLITE_OPEN_URI | SQLITE_OPEN_NOFOLLOW, nullptr);
      auto refuse = [&](const std::string& why) {
        sqlite3_close(ro);
        throw StoreError("session store " + path + ": " + why + "; the file was left as it is");
      };
      if (rc != SQLITE_OK) refuse(codeText(rc));
      try {
        checkStillTheFile();
      } catch (...) {
        sqlite3_close(ro);
        throw;
      }
      auto scalar = [&](const char* sql, std::string* out) {
        sqlite3_stmt* st = nullptr;
        int r = sqlite3_prepare_v2(ro, sql, -1, &st, nullptr);
        if (r == SQLITE_OK) r = sqlite3_step(st);
        if (r == SQLITE_ROW) {
          const unsigned char* t = sqlite3_column_text(st, 0);
          *out = t ? reinterpret_cast<const char*>(t) : "";
          r = SQLITE_OK;
        } else if (r == SQLITE_DONE) {
          out->clear();
          r = SQLITE_OK;
        } else {
          r = sqlite3_extended_errcode(ro);
        }
        sqlite3_finalize(st);
        return r;
      };
      std::string v;
      int r = scalar("PRAGMA application_id", &v);
      if (r != SQLITE_OK) refuse(codeText(r));
      if (v != std::to_string(kApplicationId)) refuse("an SQLite database, but not a uw_multislam session store");
      r = scalar("PRAGMA user_version", &v);
      if (r != SQLITE_OK) refuse(codeText(r));
      if (v != std::to_string(kSchemaVersion))
        refuse("schema version " + v + ", this build reads version " + std::to_string(kSchemaVersion) +
               " (use the matching uw_multislam, or a new file)");
      // quick_check of every table but the keyframes: checking those read the whole file (3.5 s
      // at 100 k keyframes, the start-up's largest part). A keyframe's pages are checked as they
      // are read instead: a corrupt one fails that read (DATA_LOSS, or a counted skip when
      // paged), the rest of the store goes on.
      std::vector<std::string> tables;
      {
        sqlite3_stmt* st = nullptr;
        r = sqlite3_prepare_v2(ro, "SELECT name FROM sqlite_master WHERE type = 'table' AND name <> 'keyframes'", -1,
                               &st, nullptr);
        if (r == SQLITE_OK) {
          while ((r = sqlite3_step(st)) == SQLITE_ROW)
            tables.emplace_back(reinterpret_cast<const char*>(sqlite3_column_text(st, 0)));
        }
        r = r == SQLITE_DONE ? SQLITE_OK : sqlite3_extended_errcode(ro);
        sqlite3_finalize(st);
      }
      if (r != SQLITE_OK) refuse(codeText(r));
      for (const std::string& t : tables) {
        r = scalar(("PRAGMA quick_check('" + t + "')").c_str(), &v);
        if (r != SQLITE_OK) refuse(codeText(r));
        if (v != "ok") refuse("the database is corrupt (" + v + ")");
      }
      // The kind its sessions hold, read on this read-only connection: a damaged meta row is
      // refused before the writable open below touches the file (WAL mode, indexes).
      db_ = ro;
      learnKind();
      if (read_only) {  // the checked read-only connection is the store's
        sqlite3_extended_result_codes(db_, 1);
        sqlite3_busy_timeout(db_, 2000);
        return;
      }
      db_ = nullptr;
      sqlite3_close(ro);
      // A file nobody may write (chmod a-w) is refused even as root, for whom access(W_OK) and
      // the open succeed: its owner marked it read-only on purpose.
      const fs::perms p = fs::status(path, ec).permissions();
      if (!ec && (p & (fs::perms::owner_write | fs::perms::group_write | fs::perms::others_write)) == fs::perms::none)
        throw StoreError("session store " + path +
                         ": cannot open for writing: the file is read-only (no write "
                         "permission for anyone; chmod u+w it to extend it, or use another file)");
    }
    const int flags = SQLITE_OPEN_READWRITE | SQLITE_OPEN_NOFOLLOW;  // the file exists: made above if it did not
    const int rc = sqlite3_open_v2(path.c_str(), &db_, flags, nullptr);
    if (rc != SQLITE_OK) {
      const int ext = db_ ? sqlite3_extended_errcode(db_) : rc;
      const int sys = db_ ? sqlite3_system_errno(db_) : 0;
      sqlite3_close(db_);
      db_ = nullptr;
      std::string why = codeText(ext);
      if (sys != 0) why += ": " + std::string(std::strerror(sys));
      if (sys == EACCES || sys == EROFS || sys == EPERM)
        why = "read-only path (" + why + ")";
      else if (access(fs::path(path).parent_path().empty() ? "." : fs::path(path).parent_path().c_str(), W_OK) != 0 ||
               access(path.c_str(), W_OK) != 0)
        why = "read-only path (" + why + ")";
      throw StoreError("session store " + path + ": " + (fresh ? "cannot create: " : "cannot open for writing: ") +
                       why);
    }
    checkStillTheFile();
    sqlite3_extended_result_codes(db_, 1);
    sqlite3_busy_timeout(db_, 2000);
    exec("PRAGMA journal_mode=WAL");
    exec("PRAGMA synchronous=FULL");
    exec("PRAGMA foreign_keys=ON");
    if (fresh) {
      begin();
      exec(kSchema);
      exec("PRAGMA application_id=" + std::to_string(kApplicationId));
      exec("PRAGMA user_version=" + std::to_string(kSchemaVersion));
      commit();
    }
    exec(kFrameIndex);
    exec(kHashIndex);
    exec(kProvenanceTable);
    exec(kHistoryTable);
    exec(kNavPlacementTable);
    exec(kPositionPriorTable);
  } catch (...) {
    cache_.clear();
    if (db_) sqlite3_close(db_);
    db_ = nullptr;
    removeCreated(beside_existed);
    throw;
  }
  created_ = false;  // the store's from now on
}

SessionStore::~SessionStore() {
  cache_.clear();
  // A writer's WAL written back into the file and cut to nothing: SQLite does it by itself only
  // when the last connection to the file closes, so with a reader still open (an export, a tool)
  // the WAL stayed at its full size after a clean exit. A failure leaves it as it was (restorable).
  if (db_ && file_.writer) sqlite3_exec(db_, "PRAGMA wal_checkpoint(TRUNCATE)", nullptr, nullptr, nullptr);
  if (db_) sqlite3_close(db_);
}  // then file_ goes: the lock is released (the kernel releases it too if the process dies)
bool SessionStore::hashSettings(HashSettings* out) const {
  Statement st(this, "SELECT key, value FROM meta");
  std::map<std::string, std::string> kv;
  while (st.step())
    kv[reinterpret_cast<const char*>(sqlite3_column_text(st.get(), 0))] =
        reinterpret_cast<const char*>(sqlite3_column_text(st.get(), 1));
  if (!kv.count("hash_mode")) return false;
  if (!parseHashMode(kv["hash_mode"], &out->mode))
    throw StoreError("session store " + path_ + ": unknown hash mode '" + kv["hash_mode"] + "'");
  out->seed = std::stoull(kv["projection_seed"]);
  out->num_features = std::stoi(kv["num_features"]);
  out->projections = kv["projections"];
  out->features = FeatureType::kSift;
  if (kv.count("features") && !parseFeatureType(kv["features"], &out->features))
    throw StoreError("session store " + path_ + ": unknown feature kind '" + kv["features"] + "'");
  return true;
}

void SessionStore::learnKind() {
  // The kind its sessions hold, known from the open on (not only once a writer checks its
  // configuration): a read-only reader (export, merge inputs) then reads a featureless keyframe
  // of an ORB store as 0 x 32, and a writer refuses a keyframe of the other width at once.
  HashSettings stored;
  try {
    if (hashSettings(&stored)) descriptor_bytes_ = descriptorBytes(stored.features);
  } catch (const std::logic_error&) {  // std::stoi/stoull of a damaged meta row
    throw StoreError("session store " + path_ + ": its meta table is damaged (hash settings unreadable)");
  }
}

void SessionStore::checkHashSettings(const HashSettings& mine) {
  HashSettings stored;
  if (hashSettings(&stored)) {
    // HashSettings::compatible decides; the message names what differs in the configuration's terms.
    if (!HashSettings::compatible(stored, mine)) {
      if (stored.mode != mine.mode || stored.seed != mine.seed || stored.num_features != mine.num_features)
        throw StoreError("session store " + path_ + ": its hashes were made with hash_mode " +
                         hashModeName(stored.mode) + ", projection_seed " + std::to_string(stored.seed) +
                         ", n = " + std::to_string(stored.num_features) + "; this configuration has " +
                         hashModeName(mine.mode) + ", " + std::to_string(mine.seed) +
                         ", n = " + std::to_string(mine.num_features) + ": hashes would not be comparable");
      throw StoreError("session store " + path_ + ": its keyframes hold " + featureTypeName(stored.features) +
                       " features; this configuration extracts " + featureTypeName(mine.features) +
                       " (odometry.features.type): their hashes and matches would not be comparable");
    }
    descriptor_bytes_ = descriptorBytes(stored.features);
    return;
  }
  begin();
  try {
    Statement st(this, "INSERT INTO meta(key, value) VALUES (?, ?)");
    for (const auto& [k, v] :
         std::vector<std::pair<std::string, std::string>>{{"hash_mode", hashModeName(mine.mode)},
                                                          {"projection_seed", std::to_string(mine.seed)},
                                                          {"num_features", std::to_string(mine.num_features)},
                                                          {"projections", mine.projections},
                                                          {"features", featureTypeName(mine.features)}}) {
      st.bind(1, k).bind(2, v).run();
    }
    commit();
  } catch (...) {
    rollback();
    throw;
  }
  descriptor_bytes_ = descriptorBytes(mine.features);
}

}  // namespace core
}  // namespace uw_multislam
