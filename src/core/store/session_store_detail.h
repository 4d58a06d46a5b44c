// What the session store's files share (private to src/core/store): its prepared statement and
// the readers of column values that refuse damage by name (session_store.h; the open and schema:
// session_store_open.cpp, writes: session_store_write.cpp, reads: session_store_read.cpp).
#pragma once

#include <sqlite3.h>

#include <Eigen/Core>

#include <cstdint>
#include <cstring>
#include <initializer_list>
#include <string>
#include <vector>

#include "uw_multislam/core/store/session_store.h"

namespace uw_multislam {
namespace core {
namespace store_detail {

/// An SQLite result code in words.
std::string codeText(int rc);

/// "column 'x' of table 'motions'" (no table for an expression), for a damaged value's message.
std::string columnLabel(sqlite3_stmt* q, int col);

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

/// A number read from a column: SQLite keeps whatever a row holds whatever the column's type, and
/// sqlite3_column_double reads a text 'NaN' (or any text, or a blob) as 0.0 without a word. A
/// value that is not a number makes the store damaged, named with the column.
double realColumn(sqlite3_stmt* q, int col, const std::string& path);
std::int64_t int64Column(sqlite3_stmt* q, int col, const std::string& path);
/// sqlite3_column_int keeps the low 32 bits of a larger value without a word: refused here.
int intColumn(sqlite3_stmt* q, int col, const std::string& path);
/// A text column the schema's CHECK limits to `allowed`: a row written with the checks off
/// (PRAGMA ignore_check_constraints) had been read as one of them without a word (merge_stores
/// called a session in state 'done' "still recording").
std::string checkedText(sqlite3_stmt* q, int col, const std::string& path, std::initializer_list<const char*> allowed);
/// A text column, "" for NULL.
std::string columnText(sqlite3_stmt* st, int col);
/// The meta row that keeps the maps' geographic datum (SessionStore::datum).
constexpr char kDatumKey[] = "datum";

/// A covariance as the 9 float64 of a `cov` blob (row-major), and back.
std::vector<double> covBlob(const Eigen::Matrix3d& c);
Eigen::Matrix3d covFrom(const double* v);

}  // namespace store_detail

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

}  // namespace core
}  // namespace uw_multislam
