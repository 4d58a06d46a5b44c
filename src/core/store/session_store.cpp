#include "uw_multislam/core/store/session_store.h"

#include <fcntl.h>
#include <sqlite3.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <sys/sysmacros.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <initializer_list>
#include <limits>
#include <map>
#include <set>
#include <sstream>

#include "uw_multislam/core/common/thread_annotations.h"

namespace uw_multislam {
namespace core {

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

// The audit trail: created like provenance, when the store is opened for writing.
const char* kHistoryTable =
    "CREATE TABLE IF NOT EXISTS history(id INTEGER PRIMARY KEY, time_utc TEXT NOT NULL, kind TEXT NOT NULL, "
    "cause TEXT NOT NULL, sessions TEXT NOT NULL, loops TEXT NOT NULL, message TEXT NOT NULL)";

std::string codeText(int rc) {
  switch (rc & 0xff) {
    case SQLITE_FULL:
      return "the disk is full";
    case SQLITE_READONLY:
      return "the file or its directory is read-only";
    case SQLITE_CANTOPEN:
      return "cannot open or create the file (missing directory or no permission?)";
    case SQLITE_CORRUPT:
      return "the database is corrupt";
    case SQLITE_NOTADB:
      return "not an SQLite database";
    case SQLITE_IOERR:
      return "input/output error";
    case SQLITE_PERM:
      return "permission denied";
    case SQLITE_BUSY:
    case SQLITE_LOCKED:
      return "the database is locked by another process";
    default:
      return sqlite3_errstr(rc);
  }
}

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

// "column 'x' of table 'motions'" (no table for an expression), for a damaged value's message.
std::string columnLabel(sqlite3_stmt* q, int col) {
  const char* table = sqlite3_column_table_name(q, col);
  return std::string("column '") + sqlite3_column_name(q, col) + "'" +
         (table ? std::string(" of table '") + table + "'" : std::string());
}

// A blob column as the whole values of T it holds (a keyframe's blobs, whose sizes readKeyframe
// checks against num_features, naming the keyframe). Text or a number where a blob belongs is
// damaged: SQLite hands out its characters as the blob's bytes (72 characters in a link's
// covariance had been read as nine tiny doubles and the link accepted).
template <typename T>
std::vector<T> blobPrefix(sqlite3_stmt* st, int col, const std::string& path) {
  const int type = sqlite3_column_type(st, col);
  if (type != SQLITE_BLOB && type != SQLITE_NULL)
    throw StoreError("session store " + path + ": " + columnLabel(st, col) + " holds " +
                     (type == SQLITE_TEXT ? "text" : "a number") + " where a blob belongs (damaged)");
  const int n = sqlite3_column_bytes(st, col);
  const void* p = sqlite3_column_blob(st, col);
  std::vector<T> out(static_cast<std::size_t>(n) / sizeof(T));
  // void*: OpenCV before 4.6 declares cv::Point_'s copy assignment itself, which GCC's
  // -Wclass-memaccess takes for a non-trivial one; the bytes are a float pair all the same.
  if (p && !out.empty()) std::memcpy(static_cast<void*>(out.data()), p, out.size() * sizeof(T));
  return out;
}

// A blob column as values of T. A blob that is not a whole number of them is damaged (named with
// its column and table): it was cut to the whole ones without a word (a link's loop list one byte
// short summarised one loop fewer).
template <typename T>
std::vector<T> blobVector(sqlite3_stmt* st, int col, const std::string& path) {
  const int n = sqlite3_column_bytes(st, col);
  if (n % static_cast<int>(sizeof(T)) != 0) {
    throw StoreError("session store " + path + ": " + columnLabel(st, col) + " holds a blob of " + std::to_string(n) +
                     " bytes, not a whole number of " + std::to_string(sizeof(T)) + "-byte values (damaged)");
  }
  return blobPrefix<T>(st, col, path);
}

// A number read from a column: SQLite keeps whatever a row holds whatever the column's type, and
// sqlite3_column_double reads a text 'NaN' (or any text, or a blob) as 0.0 without a word. A
// value that is not a number makes the store damaged, named with the column.
[[noreturn]] void notANumber(sqlite3_stmt* q, int col, const std::string& path) {
  std::string held = "a blob";
  if (sqlite3_column_type(q, col) == SQLITE_NULL) {
    held = "NULL";
  } else if (sqlite3_column_type(q, col) == SQLITE_TEXT) {
    const char* t = reinterpret_cast<const char*>(sqlite3_column_text(q, col));
    held = "the text '" + std::string(t ? t : "").substr(0, 40) + "'";
  }
  throw StoreError("session store " + path + ": " + columnLabel(q, col) + " holds " + held +
                   " where a number belongs (damaged)");
}

double realColumn(sqlite3_stmt* q, int col, const std::string& path) {
  const int type = sqlite3_column_type(q, col);
  if (type != SQLITE_FLOAT && type != SQLITE_INTEGER) notANumber(q, col, path);
  return sqlite3_column_double(q, col);
}

std::int64_t int64Column(sqlite3_stmt* q, int col, const std::string& path) {
  if (sqlite3_column_type(q, col) != SQLITE_INTEGER) notANumber(q, col, path);
  return sqlite3_column_int64(q, col);
}

// sqlite3_column_int keeps the low 32 bits of a larger value without a word.
int intColumn(sqlite3_stmt* q, int col, const std::string& path) {
  const std::int64_t v = int64Column(q, col, path);
  if (v < std::numeric_limits<int>::min() || v > std::numeric_limits<int>::max())
    throw StoreError("session store " + path + ": " + columnLabel(q, col) + " holds " + std::to_string(v) +
                     ", beyond any count or index (damaged)");
  return static_cast<int>(v);
}

// A text column the schema's CHECK limits to `allowed`: a row written with the checks off
// (PRAGMA ignore_check_constraints) had been read as one of them without a word (merge_stores
// called a session in state 'done' "still recording").
std::string checkedText(sqlite3_stmt* q, int col, const std::string& path, std::initializer_list<const char*> allowed) {
  const bool text = sqlite3_column_type(q, col) == SQLITE_TEXT;  // before column_text converts the value
  const unsigned char* t = sqlite3_column_text(q, col);
  const std::string v = t ? reinterpret_cast<const char*>(t) : "";
  std::string list;
  for (const char* a : allowed) {
    if (text && v == a) return v;
    list += std::string(list.empty() ? "'" : ", '") + a + "'";
  }
  throw StoreError("session store " + path + ": " + columnLabel(q, col) + " holds " + (text ? "" : "a non-text ") +
                   "'" + v.substr(0, 40) + "' (damaged: one of " + list + ")");
}

std::vector<double> covBlob(const Eigen::Matrix3d& c) {
  std::vector<double> v(9);
  for (int r = 0; r < 3; ++r)
    for (int k = 0; k < 3; ++k) v[3 * r + k] = c(r, k);
  return v;
}

Eigen::Matrix3d covFrom(const double* v) {
  Eigen::Matrix3d c;
  for (int r = 0; r < 3; ++r)
    for (int k = 0; k < 3; ++k) c(r, k) = v[3 * r + k];
  return c;
}

}  // namespace

// A prepared statement; reset after each use.
class SessionStore::Statement {
 public:
  Statement(const SessionStore* store, const char* sql) : store_(store) {
    if (sqlite3_prepare_v2(store->db_, sql, -1, &st_, nullptr) != SQLITE_OK) store->fail("preparing a statement");
  }
  ~Statement() { sqlite3_finalize(st_); }
  Statement& bind(int i, std::int64_t v) { return check(sqlite3_bind_int64(st_, i, v)); }
  Statement& bind(int i, int v) { return check(sqlite3_bind_int64(st_, i, v)); }
  Statement& bind(int i, double v) { return check(sqlite3_bind_double(st_, i, v)); }
  Statement& bind(int i, const std::string& v) {
    return check(sqlite3_bind_text(st_, i, v.c_str(), static_cast<int>(v.size()), SQLITE_TRANSIENT));
  }
  /// A blob of no bytes (not NULL).
  Statement& emptyBlob(int i) { return check(sqlite3_bind_zeroblob(st_, i, 0)); }
  Statement& blob(int i, const void* p, std::size_t n) {
    if (n == 0) return check(sqlite3_bind_null(st_, i));
    return check(sqlite3_bind_blob(st_, i, p, static_cast<int>(n), SQLITE_STATIC));
  }
  template <typename T>
  Statement& blob(int i, const std::vector<T>& v) {
    return blob(i, v.data(), v.size() * sizeof(T));
  }
  /// true while rows come.
  bool step() {
    const int rc = sqlite3_step(st_);
    if (rc == SQLITE_ROW) return true;
    if (rc == SQLITE_DONE) return false;
    // Reset after the error is read: a cached statement left in its failed state answered every
    // later use with SQLITE_MISUSE, so one full disk failed every later write, space or not.
    try {
      store_->fail("writing or reading");
    } catch (...) {
      reset();
      throw;
    }
  }
  void run() {
    step();
    reset();
  }
  void reset() {
    sqlite3_reset(st_);
    sqlite3_clear_bindings(st_);
  }
  sqlite3_stmt* get() { return st_; }

 private:
  Statement& check(int rc) {
    if (rc != SQLITE_OK) store_->fail("binding a value");
    return *this;
  }
  const SessionStore* store_;
  sqlite3_stmt* st_ = nullptr;
};

void SessionStore::fail(const std::string& what) const {
  const int rc = db_ ? sqlite3_extended_errcode(db_) : SQLITE_CANTOPEN;
  std::string detail = db_ ? sqlite3_errmsg(db_) : "";
  std::string msg = "session store " + path_ + ": " + what + ": " + codeText(rc);
  if (!detail.empty() && detail != codeText(rc) && detail != sqlite3_errstr(rc)) msg += " (" + detail + ")";
  throw StoreError(msg);
}

void SessionStore::exec(const std::string& sql) const {
  char* err = nullptr;
  if (sqlite3_exec(db_, sql.c_str(), nullptr, nullptr, &err) != SQLITE_OK) {
    sqlite3_free(err);
    fail("'" + sql.substr(0, 40) + "'");
  }
}

namespace {

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
  if (db_) sqlite3_close(db_);
}  // then file_ goes: the lock is released (the kernel releases it too if the process dies)

void SessionStore::begin() { exec("BEGIN IMMEDIATE"); }
void SessionStore::commit() { exec("COMMIT"); }
void SessionStore::rollback() noexcept {
  if (db_ && !sqlite3_get_autocommit(db_)) sqlite3_exec(db_, "ROLLBACK", nullptr, nullptr, nullptr);
}

SessionStore::Statement& SessionStore::cached(const char* sql) {
  for (auto& [s, st] : cache_)
    if (s == sql) return *st;
  cache_.emplace_back(sql, std::make_unique<Statement>(this, sql));
  return *cache_.back().second;
}

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

std::string unusableCamera(const CameraIntrinsics& c) { return c.unknown() ? std::string() : c.validate(); }

namespace {
// The meta row that keeps the ids of deleted sessions from being given again: `id INTEGER PRIMARY
// KEY` without AUTOINCREMENT reuses the largest id once its row is gone, and a schema change
// (AUTOINCREMENT) would make older builds' stores unreadable for nothing. A store without the row
// has deleted no session (or only below its largest id).
const char* kDeletedIdsKey = "next_session_id";
}  // namespace

std::int64_t SessionStore::nextSessionId() const {
  Statement st(this,
               "SELECT COALESCE((SELECT MAX(id) + 1 FROM sessions), 0), "
               "COALESCE((SELECT CAST(value AS INTEGER) FROM meta WHERE key = ?), 0)");
  st.bind(1, std::string(kDeletedIdsKey));
  if (!st.step()) throw StoreError("session store " + path_ + ": its session ids could not be read");
  return std::max(sqlite3_column_int64(st.get(), 0), sqlite3_column_int64(st.get(), 1));
}

std::int64_t SessionStore::addSession(const std::string& name, const CameraIntrinsics& c, double start_stamp_s,
                                      std::int64_t id) {
  if (const std::string bad = unusableCamera(c); !bad.empty())
    throw StoreError("session store " + path_ + ": session '" + name + "' not added: its camera is not usable (" + bad +
                     ")");
  Statement deleted(this, "SELECT CAST(value AS INTEGER) FROM meta WHERE key = ?");
  deleted.bind(1, std::string(kDeletedIdsKey));
  const std::int64_t floor = deleted.step() ? sqlite3_column_int64(deleted.get(), 0) : 0;
  if (id >= 0 && id < floor) {
    Statement taken(this, "SELECT count(*) FROM sessions WHERE id = ?");
    taken.bind(1, id);
    if (!taken.step() || sqlite3_column_int(taken.get(), 0) == 0)
      throw StoreError("session store " + path_ + ": session '" + name + "' not added: id " + std::to_string(id) +
                       " was a deleted session's (ids are never given twice)");
  }
  // Without an id (merge_stores, tools): the next one no session has had, from 0 like the session
  // manager's, so that a store's ids are the ids the engine gave (SQLite would start at 1).
  if (id < 0) id = nextSessionId();
  Statement st(this,
               "INSERT INTO sessions(id, name, state, start_stamp, end_stamp, cam_width, cam_height, cam_fx, cam_fy, "
               "cam_cx, cam_cy) VALUES (?, ?, 'recording', ?, ?, ?, ?, ?, ?, ?, ?)");
  st.bind(1, id);
  st.bind(2, name).bind(3, start_stamp_s).bind(4, start_stamp_s).bind(5, c.width).bind(6, c.height);
  st.bind(7, c.fx).bind(8, c.fy).bind(9, c.cx).bind(10, c.cy).run();
  return sqlite3_last_insert_rowid(db_);
}

void SessionStore::setSessionCamera(std::int64_t session, const CameraIntrinsics& c) {
  if (const std::string bad = unusableCamera(c); !bad.empty())
    throw StoreError("session store " + path_ + ": session " + std::to_string(session) +
                     ": camera not stored, it is not usable (" + bad + ")");
  Statement st(this,
               "UPDATE sessions SET cam_width = ?, cam_height = ?, cam_fx = ?, cam_fy = ?, cam_cx = ?, cam_cy = ? "
               "WHERE id = ?");
  st.bind(1, c.width).bind(2, c.height).bind(3, c.fx).bind(4, c.fy).bind(5, c.cx).bind(6, c.cy).bind(7, session).run();
}

void SessionStore::endSession(std::int64_t session, double end_stamp_s) {
  Statement st(this, "UPDATE sessions SET state = 'finished', end_stamp = ? WHERE id = ?");
  st.bind(1, end_stamp_s).bind(2, session).run();
}

// A keyframe that never arrived (no features, no image, a zero hash): its row is the minimal
// form, an empty hash blob instead of 384 zeros, so a gap of lost keyframes costs a few bytes per
// keyframe of store rather than 1.5 kB each (readKeyframe gives it back as the zero hash).
namespace {
bool isPlaceholder(const StoredKeyframe& kf) {
  return kf.points.empty() && kf.descriptors.empty() && kf.thumbnail.empty() && kf.hash.isZero(0.0f);
}
}  // namespace

void SessionStore::insertKeyframe(const StoredKeyframe& kf, const UncertainPose2* motion) {
  if (kf.hash.size() != HalocProjections::kHashSize)
    throw StoreError("session store " + path_ + ": keyframe " + std::to_string(kf.keyframe) + ": hash of " +
                     std::to_string(kf.hash.size()) + " values");
  cv::Mat desc;
  if (!kf.descriptors.empty()) kf.descriptors.convertTo(desc, CV_8U);
  if (!desc.empty() &&
      (desc.rows != static_cast<int>(kf.points.size()) ||
       (desc.cols != descriptorBytes(FeatureType::kSift) && desc.cols != descriptorBytes(FeatureType::kOrb)) ||
       !desc.isContinuous()))
    throw StoreError("session store " + path_ + ": keyframe " + std::to_string(kf.keyframe) +
                     ": descriptors do not match the points");
  if (!desc.empty() && descriptor_bytes_ > 0 && desc.cols != descriptor_bytes_)
    throw StoreError("session store " + path_ + ": keyframe " + std::to_string(kf.keyframe) + " has descriptors of " +
                     std::to_string(desc.cols) + " bytes; this store's kind has " + std::to_string(descriptor_bytes_));
  Statement& k = cached(
      "INSERT INTO keyframes(session, keyframe, frame_index, stamp, altitude, image_width, image_height, "
      "num_features, points, descriptors, hash, thumbnail) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)");
  k.bind(1, kf.session).bind(2, kf.keyframe).bind(3, kf.frame_index).bind(4, kf.stamp_s).bind(5, kf.altitude_m);
  k.bind(6, kf.image_size.width).bind(7, kf.image_size.height).bind(8, static_cast<int>(kf.points.size()));
  k.blob(9, kf.points.data(), kf.points.size() * sizeof(cv::Point2f));
  k.blob(10, desc.data, desc.total());
  if (isPlaceholder(kf)) {
    k.emptyBlob(11);  // not NULL: the column is NOT NULL, and NULL would read as damage
  } else {
    k.blob(11, kf.hash.data(), sizeof(float) * kf.hash.size());
  }
  k.blob(12, kf.thumbnail);
  k.run();
  if (motion) {
    const std::vector<double> cov = covBlob(motion->covariance);
    Statement& m =
        cached("INSERT INTO motions(session, keyframe, x, y, yaw, cov, source) VALUES (?, ?, ?, ?, ?, ?, ?)");
    m.bind(1, kf.session).bind(2, kf.keyframe).bind(3, motion->mean.x()).bind(4, motion->mean.y());
    m.bind(5, motion->mean.yaw()).blob(6, cov).bind(7, std::string(motionSourceName(kf.motion_source))).run();
  }
}

void SessionStore::addKeyframe(const StoredKeyframe& kf, const UncertainPose2* motion, std::vector<StoredLoop>* loops,
                               const std::vector<StoredKeyframe>& gap, const UncertainPose2* gap_motion) {
  if (!gap.empty() && !gap_motion)
    throw StoreError("session store " + path_ + ": keyframe " + std::to_string(kf.keyframe) +
                     ": a gap without its motion");
  begin();
  try {
    for (const StoredKeyframe& lost : gap) {
      if (!isPlaceholder(lost))
        throw StoreError("session store " + path_ + ": keyframe " + std::to_string(lost.keyframe) +
                         " of a gap has features, an image or a hash");
      insertKeyframe(lost, gap_motion);
    }
    insertKeyframe(kf, motion);
    if (loops) insertLoops(loops);
    commit();
  } catch (...) {
    rollback();
    throw;
  }
}

void SessionStore::insertLoops(std::vector<StoredLoop>* loops) {
  Statement& l = cached(
      "INSERT INTO loops(session_a, keyframe_a, session_b, keyframe_b, kind, inliers, x, y, yaw, cov, summarised, "
      "applied, refused) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)");
  for (StoredLoop& lp : *loops) {
    const std::vector<double> cov = covBlob(lp.z.covariance);
    l.bind(1, lp.session_a).bind(2, lp.keyframe_a).bind(3, lp.session_b).bind(4, lp.keyframe_b);
    l.bind(5, std::string(lp.global ? "global" : "local")).bind(6, lp.inliers);
    l.bind(7, lp.z.mean.x()).bind(8, lp.z.mean.y()).bind(9, lp.z.mean.yaw()).blob(10, cov);
    l.bind(11, lp.summarised ? 1 : 0).bind(12, lp.applied ? 1 : 0).bind(13, lp.refused ? 1 : 0).run();
    lp.id = sqlite3_last_insert_rowid(db_);
    if (lp.nav_placement) cached("INSERT INTO nav_placements(loop) VALUES (?)").bind(1, lp.id).run();
  }
}

void SessionStore::addLoops(std::vector<StoredLoop>* loops) {
  if (loops->empty()) return;
  begin();
  try {
    insertLoops(loops);
    commit();
  } catch (...) {
    rollback();
    throw;
  }
}

void SessionStore::saveMaps(const std::vector<StoredMap>& maps, const std::vector<StoredLoop>& loop_states,
                            const std::vector<std::pair<std::int64_t, std::int64_t>>& split_pairs) {
  begin();
  try {
    exec("DELETE FROM split_pairs;");
    writeMaps(maps);
    Statement ls(this, "UPDATE loops SET summarised = ?, applied = ?, refused = ? WHERE id = ?");
    for (const StoredLoop& l : loop_states)
      ls.bind(1, l.summarised ? 1 : 0).bind(2, l.applied ? 1 : 0).bind(3, l.refused ? 1 : 0).bind(4, l.id).run();
    Statement sp(this, "INSERT OR IGNORE INTO split_pairs(session_a, session_b) VALUES (?, ?)");
    for (const auto& [a, b] : split_pairs) sp.bind(1, a).bind(2, b).run();
    commit();
  } catch (...) {
    rollback();
    throw;
  }
}

void SessionStore::writeMaps(const std::vector<StoredMap>& maps) {
  exec("DELETE FROM maps; DELETE FROM map_sessions; DELETE FROM links;");
  {
    Statement m(this, "INSERT INTO maps(id, pending, motions) VALUES (?, ?, ?)");
    Statement ms(this, "INSERT INTO map_sessions(map, position, session) VALUES (?, ?, ?)");
    Statement ln(this, "INSERT INTO links(map, position, x, y, yaw, cov, loops) VALUES (?, ?, ?, ?, ?, ?, ?)");
    for (const StoredMap& map : maps) {
      if (map.chain.empty() || map.links.size() + 1 != map.chain.size())
        throw StoreError("session store " + path_ + ": a map to save has a bad chain");
      const std::int64_t id = map.chain.front();
      std::vector<double> motions;
      for (const UncertainPose2& u : map.motions) {
        motions.insert(motions.end(), {u.mean.x(), u.mean.y(), u.mean.yaw()});
        const std::vector<double> c = covBlob(u.covariance);
        motions.insert(motions.end(), c.begin(), c.end());
      }
      m.bind(1, id).bind(2, map.pending).blob(3, motions).run();
      for (std::size_t i = 0; i < map.chain.size(); ++i)
        ms.bind(1, id).bind(2, static_cast<int>(i)).bind(3, map.chain[i]).run();
      for (std::size_t i = 0; i < map.links.size(); ++i) {
        const StoredLink& l = map.links[i];
        const std::vector<double> cov = covBlob(l.measured.covariance);
        ln.bind(1, id).bind(2, static_cast<int>(i)).bind(3, l.measured.mean.x()).bind(4, l.measured.mean.y());
        ln.bind(5, l.measured.mean.yaw()).blob(6, cov).blob(7, l.loops).run();
      }
    }
  }
}

void SessionStore::deleteSessions(const std::vector<std::int64_t>& sessions, const HistoryEntry* entry) {
  begin();
  try {
    for (const std::int64_t s : sessions) deleteOne(s);
    if (entry) addHistory(*entry);
    commit();
  } catch (...) {
    rollback();
    throw;
  }
}

void SessionStore::deleteOne(std::int64_t session) {
  Statement has(this, "SELECT count(*) FROM sessions WHERE id = ?");
  has.bind(1, session);
  if (!has.step() || sqlite3_column_int(has.get(), 0) == 0)
    throw StoreError("session store " + path_ + ": no session with store id " + std::to_string(session) + " to delete");
  has.reset();
  // Ids are for life: the deleted id (and every one below the largest so far) is never given
  // again, also after a restart (nextSessionId).
  Statement mark(this, "INSERT OR REPLACE INTO meta(key, value) VALUES (?, ?)");
  mark.bind(1, std::string(kDeletedIdsKey)).bind(2, std::to_string(nextSessionId())).run();
  std::set<std::int64_t> gone_loops;
  Statement gl(this, "SELECT id FROM loops WHERE session_a = ? OR session_b = ?");
  gl.bind(1, session).bind(2, session);
  while (gl.step()) gone_loops.insert(sqlite3_column_int64(gl.get(), 0));
  // The maps without the session: a chain loses it and the link(s) that reached it; a chain it
  // sat in the middle of falls apart into the sessions before and those after (their link to
  // it measured nothing between them). A map that changed keeps no optimised motions (their
  // layout was the whole chain's): it is restored from the odometry and its links, and
  // optimised again at the next flush (pending >= 1).
  std::vector<StoredMap> kept;
  for (const StoredMap& m : maps()) {
    const auto at = std::find(m.chain.begin(), m.chain.end(), session);
    if (at == m.chain.end()) {
      StoredMap c = m;
      for (StoredLink& l : c.links)
        l.loops.erase(
            std::remove_if(l.loops.begin(), l.loops.end(), [&](std::int64_t id) { return gone_loops.count(id) > 0; }),
            l.loops.end());
      kept.push_back(std::move(c));
      continue;
    }
    const std::size_t i = static_cast<std::size_t>(at - m.chain.begin());
    for (const auto& [first, last] : {std::make_pair(std::size_t{0}, i), std::make_pair(i + 1, m.chain.size())}) {
      if (first >= last) continue;
      StoredMap part;
      part.chain.assign(m.chain.begin() + static_cast<std::ptrdiff_t>(first),
                        m.chain.begin() + static_cast<std::ptrdiff_t>(last));
      part.links.assign(m.links.begin() + static_cast<std::ptrdiff_t>(first),
                        m.links.begin() + static_cast<std::ptrdiff_t>(last - 1));
      part.pending = std::max(m.pending, 1);
      kept.push_back(std::move(part));
    }
  }
  for (const char* sql :
       {"DELETE FROM keyframes WHERE session = ?1", "DELETE FROM motions WHERE session = ?1",
        "DELETE FROM nav_placements WHERE loop IN (SELECT id FROM loops WHERE session_a = ?1 OR session_b = ?1)",
        "DELETE FROM loops WHERE session_a = ?1 OR session_b = ?1",
        "DELETE FROM split_pairs WHERE session_a = ?1 OR session_b = ?1", "DELETE FROM sessions WHERE id = ?1"}) {
    Statement d(this, sql);
    d.bind(1, session).run();
  }
  writeMaps(kept);
}

std::vector<StoredSession> SessionStore::sessions() const {
  Statement st(this,
               "SELECT s.id, s.name, s.state, s.start_stamp, s.end_stamp, s.cam_width, s.cam_height, s.cam_fx, "
               "s.cam_fy, s.cam_cx, s.cam_cy, (SELECT COUNT(*) FROM keyframes k WHERE k.session = s.id) "
               "FROM sessions s ORDER BY s.id");
  std::vector<StoredSession> out;
  while (st.step()) {
    sqlite3_stmt* q = st.get();
    StoredSession s;
    s.id = sqlite3_column_int64(q, 0);
    s.name = reinterpret_cast<const char*>(sqlite3_column_text(q, 1));
    s.state = checkedText(q, 2, path_, {"recording", "finished"}) == "finished" ? StoredSessionState::kFinished
                                                                                : StoredSessionState::kRecording;
    s.start_stamp_s = realColumn(q, 3, path_);
    s.end_stamp_s = realColumn(q, 4, path_);
    s.camera.width = intColumn(q, 5, path_);
    s.camera.height = intColumn(q, 6, path_);
    s.camera.fx = realColumn(q, 7, path_);
    s.camera.fy = realColumn(q, 8, path_);
    s.camera.cx = realColumn(q, 9, path_);
    s.camera.cy = realColumn(q, 10, path_);
    s.keyframes = intColumn(q, 11, path_);
    // 0x0: unknown (a session without keyframes; older stores kept it for some with keyframes);
    // anything else must be a camera the odometry could have run with.
    if (const std::string bad = unusableCamera(s.camera); !bad.empty())
      throw StoreError("session store " + path_ + ": session " + std::to_string(s.id) + " '" + s.name +
                       "' has a damaged camera row (" + bad + ")");
    out.push_back(s);
  }
  return out;
}

// The columns of a keyframe row as keyframes() and keyframeFeatures() read them: frame data from
// column 0 (keyframe, frame_index, stamp, altitude, image size, num_features), then points,
// descriptors, hash and thumbnail (NULL where not read).
void SessionStore::readKeyframe(sqlite3_stmt* q, std::int64_t session, KeyframeColumns columns, bool features,
                                StoredKeyframe* k) const {
  k->session = session;
  k->keyframe = intColumn(q, 0, path_);
  k->frame_index = intColumn(q, 1, path_);
  k->stamp_s = realColumn(q, 2, path_);
  k->altitude_m = realColumn(q, 3, path_);
  // Every stored keyframe had a finite stamp (a text 'nan' is refused above as not a number; an
  // infinite one passed). An altitude that is not usable is the exports' to count as missing
  // (test_export_survey: a keyframe without valid altitude is left out of the mosaic).
  if (!std::isfinite(k->stamp_s))
    throw StoreError("session store " + path_ + ": keyframe " + std::to_string(k->keyframe) + " of session " +
                     std::to_string(session) + " has stamp " + std::to_string(k->stamp_s) + " (damaged)");
  k->image_size = cv::Size(intColumn(q, 4, path_), intColumn(q, 5, path_));
  const int n = intColumn(q, 6, path_);
  const auto corrupt = [&] {
    return StoreError("session store " + path_ + ": keyframe " + std::to_string(k->keyframe) + " of session " +
                      std::to_string(session) + " has blobs of the wrong size (corrupt)");
  };
  if (features) {
    k->points = blobPrefix<cv::Point2f>(q, 7, path_);
    const std::vector<std::uint8_t> d = blobPrefix<std::uint8_t>(q, 8, path_);
    // n x 128 bytes (SIFT) or n x 32 (ORB): the blob's size tells which (the store's meta row
    // `features` says which kind all its sessions hold).
    const std::size_t sift = descriptorBytes(FeatureType::kSift), orb = descriptorBytes(FeatureType::kOrb);
    const std::size_t un = n < 0 ? 0 : static_cast<std::size_t>(n);
    if (n < 0 || static_cast<int>(k->points.size()) != n || (d.size() != un * sift && d.size() != un * orb))
      throw corrupt();
    // With no feature the blob says nothing: the store's kind, once known (0 x 32 stays ORB).
    const std::size_t width = n > 0 ? (d.size() == un * orb ? orb : sift)
                                    : (descriptor_bytes_ > 0 ? static_cast<std::size_t>(descriptor_bytes_) : sift);
    k->descriptors = cv::Mat(n, static_cast<int>(width), CV_8U);
    if (n > 0) std::memcpy(k->descriptors.data, d.data(), d.size());
  }
  if (columns != KeyframeColumns::kFrame) {
    const std::vector<float> h = blobPrefix<float>(q, 9, path_);
    if (h.empty() && sqlite3_column_type(q, 9) == SQLITE_BLOB && n == 0) {
      k->hash = Eigen::VectorXf::Zero(HalocProjections::kHashSize);  // a keyframe that never arrived
    } else {
      if (h.size() != static_cast<std::size_t>(HalocProjections::kHashSize)) throw corrupt();
      k->hash = Eigen::Map<const Eigen::VectorXf>(h.data(), static_cast<Eigen::Index>(h.size()));
    }
  }
  if (columns == KeyframeColumns::kAll) k->thumbnail = blobVector<std::uint8_t>(q, 10, path_);
}

std::vector<StoredKeyframe> SessionStore::keyframes(std::int64_t session, KeyframeColumns columns) const {
  const char* sql =
      columns == KeyframeColumns::kAll
          ? "SELECT keyframe, frame_index, stamp, altitude, image_width, image_height, num_features, points, "
            "descriptors, hash, thumbnail FROM keyframes WHERE session = ? ORDER BY keyframe"
      : columns == KeyframeColumns::kHash
          ? "SELECT keyframe, frame_index, stamp, altitude, image_width, image_height, num_features, NULL, NULL, "
            "hash, NULL FROM keyframes WHERE session = ? ORDER BY keyframe"
          : "SELECT keyframe, frame_index, stamp, altitude, image_width, image_height, num_features "
            "FROM keyframes WHERE session = ? ORDER BY keyframe";
  Statement st(this, sql);
  st.bind(1, session);
  std::vector<StoredKeyframe> out;
  while (st.step()) {
    StoredKeyframe k;
    readKeyframe(st.get(), session, columns, columns == KeyframeColumns::kAll, &k);
    out.push_back(std::move(k));
  }
  return out;
}

std::vector<std::vector<std::uint8_t>> SessionStore::thumbnails(std::int64_t session) const {
  Statement st(this, "SELECT thumbnail FROM keyframes WHERE session = ? ORDER BY keyframe");
  st.bind(1, session);
  std::vector<std::vector<std::uint8_t>> out;
  while (st.step()) out.push_back(blobVector<std::uint8_t>(st.get(), 0, path_));
  return out;
}

StoredKeyframe SessionStore::keyframeFeatures(std::int64_t session, int keyframe) const {
  Statement st(this,
               "SELECT keyframe, frame_index, stamp, altitude, image_width, image_height, num_features, points, "
               "descriptors FROM keyframes WHERE session = ? AND keyframe = ?");
  st.bind(1, session).bind(2, keyframe);
  if (!st.step())
    throw StoreError("session store " + path_ + ": keyframe " + std::to_string(keyframe) + " of session " +
                     std::to_string(session) + " is not in the store");
  StoredKeyframe k;
  readKeyframe(st.get(), session, KeyframeColumns::kFrame, true, &k);
  return k;
}

std::vector<UncertainPose2> SessionStore::odometry(std::int64_t session) const {
  Statement st(this, "SELECT keyframe, x, y, yaw, cov FROM motions WHERE session = ? ORDER BY keyframe");
  st.bind(1, session);
  std::vector<UncertainPose2> out;
  while (st.step()) {
    sqlite3_stmt* q = st.get();
    if (intColumn(q, 0, path_) != static_cast<int>(out.size()) + 1)
      throw StoreError("session store " + path_ + ": session " + std::to_string(session) +
                       " misses the motion to keyframe " + std::to_string(out.size() + 1));
    const std::vector<double> c = blobVector<double>(q, 4, path_);
    if (c.size() != 9) throw StoreError("session store " + path_ + ": a motion covariance has the wrong size");
    out.emplace_back(Pose2(realColumn(q, 1, path_), realColumn(q, 2, path_), realColumn(q, 3, path_)),
                     covFrom(c.data()));
  }
  return out;
}

std::vector<MotionSource> SessionStore::motionSources(std::int64_t session) const {
  Statement st(this, "SELECT source FROM motions WHERE session = ? ORDER BY keyframe");
  st.bind(1, session);
  std::vector<MotionSource> out;
  while (st.step()) {
    const unsigned char* t = sqlite3_column_text(st.get(), 0);
    MotionSource s = MotionSource::kVisual;
    if (!t || !parseMotionSource(reinterpret_cast<const char*>(t), &s))
      throw StoreError("session store " + path_ + ": a motion has an unknown source");
    out.push_back(s);
  }
  return out;
}

std::vector<StoredLoop> SessionStore::loops() const {
  Statement st(this,
               "SELECT id, session_a, keyframe_a, session_b, keyframe_b, kind, inliers, x, y, yaw, cov, summarised, "
               "applied, refused FROM loops ORDER BY id");
  std::vector<StoredLoop> out;
  while (st.step()) {
    sqlite3_stmt* q = st.get();
    StoredLoop l;
    l.id = sqlite3_column_int64(q, 0);
    l.session_a = int64Column(q, 1, path_);
    l.keyframe_a = intColumn(q, 2, path_);
    l.session_b = int64Column(q, 3, path_);
    l.keyframe_b = intColumn(q, 4, path_);
    l.global = checkedText(q, 5, path_, {"local", "global"}) == "global";
    l.inliers = intColumn(q, 6, path_);
    const std::vector<double> c = blobVector<double>(q, 10, path_);
    if (c.size() != 9) throw StoreError("session store " + path_ + ": a loop covariance has the wrong size");
    l.z = UncertainPose2(Pose2(realColumn(q, 7, path_), realColumn(q, 8, path_), realColumn(q, 9, path_)),
                         covFrom(c.data()));
    l.summarised = intColumn(q, 11, path_) != 0;
    l.applied = intColumn(q, 12, path_) != 0;
    l.refused = intColumn(q, 13, path_) != 0;
    out.push_back(l);
  }
  if (hasTable("nav_placements")) {
    std::set<std::int64_t> placements;
    Statement np(this, "SELECT loop FROM nav_placements");
    while (np.step()) placements.insert(sqlite3_column_int64(np.get(), 0));
    for (StoredLoop& l : out) l.nav_placement = placements.count(l.id) > 0;
  }
  return out;
}

std::vector<StoredMap> SessionStore::maps() const {
  std::vector<StoredMap> out;
  std::map<std::int64_t, std::size_t> at;
  Statement st(this, "SELECT id, pending, motions FROM maps ORDER BY id");
  while (st.step()) {
    sqlite3_stmt* q = st.get();
    StoredMap m;
    m.pending = intColumn(q, 1, path_);
    const std::vector<double> v = blobVector<double>(q, 2, path_);
    if (v.size() % 12 != 0) throw StoreError("session store " + path_ + ": map motions have the wrong size");
    for (std::size_t i = 0; i < v.size(); i += 12)
      m.motions.emplace_back(Pose2(v[i], v[i + 1], v[i + 2]), covFrom(&v[i + 3]));
    at[sqlite3_column_int64(q, 0)] = out.size();
    out.push_back(std::move(m));
  }
  Statement ms(this, "SELECT map, session FROM map_sessions ORDER BY map, position");
  while (ms.step()) {
    const auto it = at.find(int64Column(ms.get(), 0, path_));
    if (it == at.end()) throw StoreError("session store " + path_ + ": a map session of no map");
    out[it->second].chain.push_back(int64Column(ms.get(), 1, path_));
  }
  Statement ln(this, "SELECT map, x, y, yaw, cov, loops FROM links ORDER BY map, position");
  while (ln.step()) {
    sqlite3_stmt* q = ln.get();
    const auto it = at.find(int64Column(q, 0, path_));
    if (it == at.end()) throw StoreError("session store " + path_ + ": a link of no map");
    const std::vector<double> c = blobVector<double>(q, 4, path_);
    if (c.size() != 9) throw StoreError("session store " + path_ + ": a link covariance has the wrong size");
    StoredLink l;
    l.measured = UncertainPose2(Pose2(realColumn(q, 1, path_), realColumn(q, 2, path_), realColumn(q, 3, path_)),
                                covFrom(c.data()));
    l.loops = blobVector<std::int64_t>(q, 5, path_);
    out[it->second].links.push_back(std::move(l));
  }
  for (const StoredMap& m : out) {
    if (m.chain.empty() || m.links.size() + 1 != m.chain.size())
      throw StoreError("session store " + path_ + ": a stored map has " + std::to_string(m.chain.size()) +
                       " sessions and " + std::to_string(m.links.size()) + " links (corrupt)");
    // A session is in one place of one chain (it silently became two maps).
    std::set<std::int64_t> seen;
    for (std::int64_t s : m.chain)
      if (!seen.insert(s).second)
        throw StoreError("session store " + path_ + ": the stored map of session " + std::to_string(m.chain.front()) +
                         " names session " + std::to_string(s) + " twice (corrupt)");
  }
  return out;
}

std::vector<std::pair<std::int64_t, std::int64_t>> SessionStore::splitPairs() const {
  Statement st(this, "SELECT session_a, session_b FROM split_pairs ORDER BY session_a, session_b");
  std::vector<std::pair<std::int64_t, std::int64_t>> out;
  while (st.step()) out.emplace_back(int64Column(st.get(), 0, path_), int64Column(st.get(), 1, path_));
  return out;
}

namespace {

std::string columnText(sqlite3_stmt* st, int col) {
  const unsigned char* t = sqlite3_column_text(st, col);
  return std::string(t ? reinterpret_cast<const char*>(t) : "");
}

}  // namespace

// A store opened read-only that was never opened for writing by a build that creates the table
// (provenance, history) has none.
bool SessionStore::hasTable(const char* name) const {
  Statement t(this, "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = ?");
  t.bind(1, std::string(name));
  return t.step();
}

void SessionStore::addProvenance(const SessionProvenance& p) {
  bool stored = false;
  {
    Statement st(this, "SELECT 1 FROM sessions WHERE id = ?");
    st.bind(1, p.session);
    stored = st.step();
  }
  if (!stored)
    throw StoreError("session store " + path_ + ": provenance of session " + std::to_string(p.session) +
                     ", which is not stored");
  Statement st(this,
               "INSERT OR REPLACE INTO provenance(session, source_file, source_session, source_name, vehicle, dive) "
               "VALUES (?, ?, ?, ?, ?, ?)");
  st.bind(1, p.session).bind(2, p.source_file).bind(3, p.source_session).bind(4, p.source_name);
  st.bind(5, p.vehicle).bind(6, p.dive).run();
}

std::vector<SessionProvenance> SessionStore::provenance() const {
  std::vector<SessionProvenance> out;
  if (!hasTable("provenance")) return out;
  Statement st(
      this, "SELECT session, source_file, source_session, source_name, vehicle, dive FROM provenance ORDER BY session");
  auto text = [&](int col) { return columnText(st.get(), col); };
  while (st.step()) {
    SessionProvenance p;
    p.session = int64Column(st.get(), 0, path_);
    p.source_file = text(1);
    p.source_session = int64Column(st.get(), 2, path_);
    p.source_name = text(3);
    p.vehicle = text(4);
    p.dive = text(5);
    out.push_back(std::move(p));
  }
  return out;
}

std::string utcTimestamp() {
  const std::time_t t = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char out[32];
  std::strftime(out, sizeof out, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return out;
}

std::int64_t SessionStore::addHistory(HistoryEntry e) {
  if (e.id == 0) {
    Statement last(this, "SELECT COALESCE(MAX(id), 0) FROM history");
    last.step();
    e.id = sqlite3_column_int64(last.get(), 0) + 1;
  }
  Statement st(this,
               "INSERT INTO history(id, time_utc, kind, cause, sessions, loops, message) VALUES (?, ?, ?, ?, ?, ?, ?)");
  st.bind(1, e.id).bind(2, e.time_utc).bind(3, e.kind).bind(4, e.cause).bind(5, e.sessions).bind(6, e.loops);
  st.bind(7, e.message).run();
  return e.id;
}

std::vector<HistoryEntry> SessionStore::history() const {
  std::vector<HistoryEntry> out;
  if (!hasTable("history")) return out;
  Statement st(this, "SELECT id, time_utc, kind, cause, sessions, loops, message FROM history ORDER BY id");
  auto text = [&](int col) { return columnText(st.get(), col); };
  while (st.step())
    out.push_back({sqlite3_column_int64(st.get(), 0), text(1), text(2), text(3), text(4), text(5), text(6)});
  return out;
}

void SessionStore::setMaxBytes(std::uint64_t bytes) {
  Statement size(this, "PRAGMA page_size");
  const std::int64_t page = size.step() ? sqlite3_column_int64(size.get(), 0) : 4096;
  size.reset();
  // SQLite's largest page count (4294967294) stands for "no cap".
  const std::uint64_t pages =
      bytes == 0 ? 4294967294ULL : std::max<std::uint64_t>(1, bytes / static_cast<std::uint64_t>(page));
  exec("PRAGMA max_page_count=" + std::to_string(pages));
}

void SessionStore::checkpoint() { exec("PRAGMA wal_checkpoint(TRUNCATE)"); }

FrameFeatures StoredKeyframe::features() const {
  FrameFeatures f;
  f.image_size = image_size;
  f.keypoints.reserve(points.size());
  for (const cv::Point2f& p : points) f.keypoints.emplace_back(p, 1.0f);
  f.descriptors = descriptors;
  return f;
}

}  // namespace core
}  // namespace uw_multislam
