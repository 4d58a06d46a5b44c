// Runs SQL on a database file the way a damaged or older store is made in the tests: opened,
// executed, closed (nothing held open beside the code under test).
#pragma once

#include <gtest/gtest.h>
#include <sqlite3.h>

#include <string>

namespace uw_multislam {
namespace testing_util {

/// `ASSERT_TRUE(execSql(path, "UPDATE ..."))`: fails with SQLite's message.
inline ::testing::AssertionResult execSql(const std::string& path, const std::string& sql) {
  sqlite3* db = nullptr;
  if (sqlite3_open(path.c_str(), &db) != SQLITE_OK) {
    const std::string why = db ? sqlite3_errmsg(db) : "out of memory";
    sqlite3_close(db);
    return ::testing::AssertionFailure() << path << ": " << why;
  }
  char* err = nullptr;
  const int rc = sqlite3_exec(db, sql.c_str(), nullptr, nullptr, &err);
  const std::string why = err ? err : "";
  sqlite3_free(err);
  sqlite3_close(db);
  if (rc != SQLITE_OK) return ::testing::AssertionFailure() << path << ": " << sql << ": " << why;
  return ::testing::AssertionSuccess();
}

}  // namespace testing_util
}  // namespace uw_multislam
