// The session store: what its parts share (statements, transactions, column readers) and its
// small settings. Opening and the schema: session_store_open.cpp; writes: session_store_write.cpp;
// reads: session_store_read.cpp.
#include "uw_multislam/core/store/session_store.h"

#include <sqlite3.h>

#include <algorithm>
#include <ctime>
#include <filesystem>
#include <limits>

#include "session_store_detail.h"

namespace uw_multislam {
namespace core {

namespace store_detail {

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

std::string columnLabel(sqlite3_stmt* q, int col) {
  const char* table = sqlite3_column_table_name(q, col);
  return std::string("column '") + sqlite3_column_name(q, col) + "'" +
         (table ? std::string(" of table '") + table + "'" : std::string());
}

namespace {
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

}  // namespace

double realColumn(sqlite3_stmt* q, int col, const std::string& path) {
  const int type = sqlite3_column_type(q, col);
  if (type != SQLITE_FLOAT && type != SQLITE_INTEGER) notANumber(q, col, path);
  return sqlite3_column_double(q, col);
}

std::int64_t int64Column(sqlite3_stmt* q, int col, const std::string& path) {
  if (sqlite3_column_type(q, col) != SQLITE_INTEGER) notANumber(q, col, path);
  return sqlite3_column_int64(q, col);
}

int intColumn(sqlite3_stmt* q, int col, const std::string& path) {
  const std::int64_t v = int64Column(q, col, path);
  if (v < std::numeric_limits<int>::min() || v > std::numeric_limits<int>::max())
    throw StoreError("session store " + path + ": " + columnLabel(q, col) + " holds " + std::to_string(v) +
                     ", beyond any count or index (damaged)");
  return static_cast<int>(v);
}

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

std::string columnText(sqlite3_stmt* st, int col) {
  const unsigned char* t = sqlite3_column_text(st, col);
  return std::string(t ? reinterpret_cast<const char*>(t) : "");
}

}  // namespace store_detail

using namespace store_detail;  // NOLINT: the store's own helpers

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
// A store opened read-only that was never opened for writing by a build that creates the table
// (provenance, history) has none.
bool SessionStore::hasTable(const char* name) const {
  Statement t(this, "SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = ?");
  t.bind(1, std::string(name));
  return t.step();
}
std::string unusableCamera(const CameraIntrinsics& c) { return c.unknown() ? std::string() : c.validate(); }
std::string utcTimestamp() {
  const std::time_t t = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char out[32];
  std::strftime(out, sizeof out, "%Y-%m-%dT%H:%M:%SZ", &tm);
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
