#include "daemon/service/job_store.h"

#include "acquisition/sql_statement.h"

namespace gonio::daemon {

using acquisition::ExecSql;
using acquisition::SqlStatement;

const char* ToString(JobState s) {
  switch (s) {
    case JobState::kQueued:
      return "queued";
    case JobState::kRunning:
      return "running";
    case JobState::kPaused:
      return "paused";
    case JobState::kDone:
      return "done";
    case JobState::kAborted:
      return "aborted";
    case JobState::kFailed:
      return "failed";
    case JobState::kCancelled:
      return "cancelled";
  }
  return "?";
}

std::optional<JobState> ParseJobState(std::string_view text) {
  for (JobState s : {JobState::kQueued, JobState::kRunning, JobState::kPaused, JobState::kDone,
                     JobState::kAborted, JobState::kFailed, JobState::kCancelled})
    if (text == ToString(s)) return s;
  return std::nullopt;
}

Result<std::int64_t> JobStore::Insert(const JobRecord& j) {
  return db_.WithConnection([&](sqlite3* db, const std::string&) -> Result<std::int64_t> {
    SqlStatement i(db,
                   "INSERT INTO jobs(name, plan, state, position, run_id, message, options) "
                   "VALUES(?,?,?,(SELECT COALESCE(MAX(position),0)+1 FROM jobs),?,?,?)");
    i.Bind(1, j.name).Bind(2, j.plan_text).Bind(3, std::string(ToString(j.state)));
    i.Bind(4, j.run).Bind(5, j.message).Bind(6, j.options_json);
    if (i.Step() != SQLITE_DONE) return i.Fail("storing job " + j.name);
    return static_cast<std::int64_t>(sqlite3_last_insert_rowid(db));
  });
}

Status JobStore::Update(const JobRecord& j) {
  return db_.WithConnection([&](sqlite3* db, const std::string& path) -> Status {
    SqlStatement u(db,
                   "UPDATE jobs SET state=?, run_id=?, message=?, options=?, "
                   "updated_at=strftime('%Y-%m-%dT%H:%M:%fZ','now') WHERE id=?");
    u.Bind(1, std::string(ToString(j.state))).Bind(2, j.run).Bind(3, j.message);
    u.Bind(4, j.options_json).Bind(5, j.id);
    if (u.Step() != SQLITE_DONE) return u.Fail("updating job " + std::to_string(j.id));
    if (sqlite3_changes(db) != 1)
      return Error{ErrorCode::kNotFound, "no job " + std::to_string(j.id) + " in " + path};
    return OkStatus();
  });
}

Status JobStore::SetQueueOrder(const std::vector<std::int64_t>& ids) {
  return db_.WithConnection([&](sqlite3* db, const std::string& path) -> Status {
    if (Status s = ExecSql(db, path, "BEGIN IMMEDIATE"); !s.ok()) return s;
    std::int64_t pos = 0;
    for (std::int64_t id : ids) {
      SqlStatement u(db, "UPDATE jobs SET position=? WHERE id=?");
      u.Bind(1, ++pos).Bind(2, id);
      if (u.Step() != SQLITE_DONE) {
        Error e = u.Fail("reordering the job queue");
        (void)ExecSql(db, path, "ROLLBACK");
        return e;
      }
    }
    return ExecSql(db, path, "COMMIT");
  });
}

Result<std::vector<JobRecord>> JobStore::Jobs(int finished_limit) {
  return db_.WithConnection([&](sqlite3* db,
                                const std::string& path) -> Result<std::vector<JobRecord>> {
    std::vector<JobRecord> out;
    auto read = [&](SqlStatement& q) -> Status {
      int rc = 0;
      while ((rc = q.Step()) == SQLITE_ROW) {
        JobRecord j;
        j.id = q.I(0);
        j.name = q.T(1);
        j.plan_text = q.T(2);
        const std::string state = q.T(3);
        const auto parsed = ParseJobState(state);
        if (!parsed)  // the schema's CHECK admits only the seven: a file edited by hand
          return Error{ErrorCode::kIo, path + ": job " + std::to_string(j.id) + " has state '" +
                                           state + "', which is not a job state"};
        j.state = *parsed;
        j.position = q.I(4);
        if (!q.Null(5)) j.run = q.I(5);
        j.message = q.T(6);
        j.options_json = q.T(7);
        out.push_back(std::move(j));
      }
      if (rc != SQLITE_DONE) return q.Fail("reading the jobs");
      return OkStatus();
    };
    constexpr const char* kCols =
        "SELECT id, name, plan, state, position, run_id, message, options ";
    SqlStatement open(
        db, (std::string(kCols) +
             "FROM jobs WHERE state IN ('queued','running','paused') ORDER BY position, id")
                .c_str());
    if (Status s = read(open); !s.ok()) return s.error();
    SqlStatement done(db, (std::string(kCols) +
                           "FROM (SELECT * FROM jobs WHERE state NOT IN "
                           "('queued','running','paused') ORDER BY id DESC LIMIT ?) ORDER BY id")
                              .c_str());
    done.Bind(1, finished_limit);
    if (Status s = read(done); !s.ok()) return s.error();
    return out;
  });
}

}  // namespace gonio::daemon
