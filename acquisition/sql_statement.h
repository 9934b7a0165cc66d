// A prepared SQLite statement that finalises itself: what Storage and the tables that layers
// above keep in the same file (the daemon's jobs) use to bind, step and read, with errors that
// name what was being done and SQLite's own message.
#pragma once

#include <sqlite3.h>

#include <cstdint>
#include <optional>
#include <string>

#include "common/result.h"

namespace gonio::acquisition {

// A prepared statement that finalises itself.
class SqlStatement {
 public:
  SqlStatement(sqlite3* db, const char* sql) : db_(db) {
    if (sqlite3_prepare_v2(db, sql, -1, &s_, nullptr) != SQLITE_OK) s_ = nullptr;
  }
  ~SqlStatement() { sqlite3_finalize(s_); }
  SqlStatement(const SqlStatement&) = delete;
  SqlStatement& operator=(const SqlStatement&) = delete;
  bool ok() const { return s_ != nullptr; }
  SqlStatement& Bind(int i, double v) { return sqlite3_bind_double(s_, i, v), *this; }
  SqlStatement& Bind(int i, std::int64_t v) { return sqlite3_bind_int64(s_, i, v), *this; }
  SqlStatement& Bind(int i, int v) { return sqlite3_bind_int(s_, i, v), *this; }
  SqlStatement& Bind(int i, const std::string& v) {
    return sqlite3_bind_text(s_, i, v.c_str(), static_cast<int>(v.size()), SQLITE_TRANSIENT), *this;
  }
  SqlStatement& Bind(int i, std::optional<double> v) {
    return v ? Bind(i, *v) : (sqlite3_bind_null(s_, i), *this);
  }
  SqlStatement& Bind(int i, std::optional<std::int64_t> v) {
    return v ? Bind(i, *v) : (sqlite3_bind_null(s_, i), *this);
  }
  int Step() { return sqlite3_step(s_); }
  double D(int c) { return sqlite3_column_double(s_, c); }
  std::int64_t I(int c) { return sqlite3_column_int64(s_, c); }
  bool Null(int c) { return sqlite3_column_type(s_, c) == SQLITE_NULL; }
  std::string T(int c) {
    const auto* t = sqlite3_column_text(s_, c);
    return t ? reinterpret_cast<const char*>(t) : "";
  }
  Error Fail(const std::string& what) const {
    return Error{ErrorCode::kIo, what + ": " + sqlite3_errmsg(db_)};
  }

 private:
  sqlite3* db_;
  sqlite3_stmt* s_ = nullptr;
};

// Runs SQL without results (BEGIN, COMMIT, PRAGMA ...); errors name the file.
inline Status ExecSql(sqlite3* db, const std::string& path, const char* sql) {
  char* err = nullptr;
  if (sqlite3_exec(db, sql, nullptr, nullptr, &err) != SQLITE_OK) {
    Error e{ErrorCode::kIo, path + ": " + (err ? err : "sqlite error")};
    sqlite3_free(err);
    return e;
  }
  return OkStatus();
}

}  // namespace gonio::acquisition
