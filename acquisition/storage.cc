#include "acquisition/storage.h"

#include "acquisition/sql_statement.h"
#include "acquisition/strategy.h"

#include <sqlite3.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <mutex>

namespace gonio::acquisition {

namespace {

// Migration k takes the schema from version k to k + 1. Never edit a released migration: add one.
const char* const kMigrations[] = {
    R"sql(
CREATE TABLE instrument_configs(
  id INTEGER PRIMARY KEY, hash TEXT NOT NULL UNIQUE, content TEXT NOT NULL,
  created_at TEXT NOT NULL DEFAULT (strftime('%Y-%m-%dT%H:%M:%fZ','now')));
CREATE TABLE specimens(
  id INTEGER PRIMARY KEY, name TEXT NOT NULL UNIQUE, material TEXT NOT NULL DEFAULT '',
  thickness_mm REAL NOT NULL, eta REAL NOT NULL);
CREATE TABLE runs(
  id INTEGER PRIMARY KEY, specimen_id INTEGER NOT NULL REFERENCES specimens(id),
  config_id INTEGER NOT NULL REFERENCES instrument_configs(id), plan TEXT NOT NULL,
  status TEXT NOT NULL CHECK(status IN ('planned','running','paused','done','aborted','failed')),
  monitor_reference_w REAL,
  created_at TEXT NOT NULL DEFAULT (strftime('%Y-%m-%dT%H:%M:%fZ','now')),
  finished_at TEXT);
CREATE TABLE plan_points(
  run_id INTEGER NOT NULL REFERENCES runs(id), idx INTEGER NOT NULL,
  theta_l_deg REAL NOT NULL, theta_v_deg REAL NOT NULL, phi_deg REAL NOT NULL,
  sample_deg REAL NOT NULL, arm_deg REAL NOT NULL, azimuth_deg REAL NOT NULL,
  status TEXT NOT NULL CHECK(status IN ('pending','done','skipped')), reason TEXT NOT NULL DEFAULT '',
  PRIMARY KEY(run_id, idx));
CREATE TABLE darks(
  id INTEGER PRIMARY KEY, exposure_s REAL NOT NULL, temperature_c REAL NOT NULL,
  frames INTEGER NOT NULL, rect_mean REAL NOT NULL, pixel_var REAL NOT NULL,
  taken_unix_s REAL NOT NULL);
CREATE TABLE measurements(
  run_id INTEGER NOT NULL, idx INTEGER NOT NULL,
  sample_read_deg REAL NOT NULL, arm_read_deg REAL NOT NULL, azimuth_read_deg REAL NOT NULL,
  exposure_s REAL NOT NULL, frames INTEGER NOT NULL, temperature_c REAL NOT NULL,
  monitor_w REAL, rect_mean REAL NOT NULL, rect_sd REAL NOT NULL, pixel_var REAL NOT NULL,
  rect_pixels INTEGER NOT NULL, rect_saturated INTEGER NOT NULL,
  dark_id INTEGER REFERENCES darks(id), value REAL NOT NULL, sigma REAL NOT NULL,
  flags INTEGER NOT NULL, ranging_tries INTEGER NOT NULL,
  measured_at TEXT NOT NULL DEFAULT (strftime('%Y-%m-%dT%H:%M:%fZ','now')),
  PRIMARY KEY(run_id, idx), FOREIGN KEY(run_id, idx) REFERENCES plan_points(run_id, idx));
CREATE TABLE run_events(
  run_id INTEGER NOT NULL REFERENCES runs(id), kind TEXT NOT NULL, detail TEXT NOT NULL,
  at TEXT NOT NULL DEFAULT (strftime('%Y-%m-%dT%H:%M:%fZ','now')));
CREATE TABLE calibrations(
  id INTEGER PRIMARY KEY, kind TEXT NOT NULL, content TEXT NOT NULL,
  created_at TEXT NOT NULL DEFAULT (strftime('%Y-%m-%dT%H:%M:%fZ','now')));
CREATE TABLE fit_results(
  id INTEGER PRIMARY KEY, run_id INTEGER NOT NULL REFERENCES runs(id), model TEXT NOT NULL,
  parameters TEXT NOT NULL, summary TEXT NOT NULL,
  created_at TEXT NOT NULL DEFAULT (strftime('%Y-%m-%dT%H:%M:%fZ','now')));
)sql",
    // 2: the daemon's jobs, so that its queue and a job's schedule options survive a restart.
    R"sql(
CREATE TABLE jobs(
  id INTEGER PRIMARY KEY, name TEXT NOT NULL, plan TEXT NOT NULL,
  state TEXT NOT NULL
    CHECK(state IN ('queued','running','paused','done','aborted','failed','cancelled')),
  position INTEGER NOT NULL, run_id INTEGER REFERENCES runs(id),
  message TEXT NOT NULL DEFAULT '', options TEXT NOT NULL DEFAULT '{}',
  created_at TEXT NOT NULL DEFAULT (strftime('%Y-%m-%dT%H:%M:%fZ','now')),
  updated_at TEXT NOT NULL DEFAULT (strftime('%Y-%m-%dT%H:%M:%fZ','now')));
CREATE INDEX jobs_by_state ON jobs(state, position);
)sql",
    // 3: reflection plans (the camera on the light side): which side each point views from.
    R"sql(
ALTER TABLE plan_points ADD COLUMN side TEXT NOT NULL DEFAULT 'transmission'
  CHECK(side IN ('transmission','reflection'));
)sql",
    // 4: the measurement equation (#16): what rebuilds each point's instrument response (JSON,
    // fitting/response.h; NULL for runs of a bench without [bench]), and each point's
    // uncertainty budget by component (NULL for points stored before).
    R"sql(
ALTER TABLE runs ADD COLUMN response TEXT;
ALTER TABLE measurements ADD COLUMN sigma_stat REAL;
ALTER TABLE measurements ADD COLUMN sigma_lamp REAL;
ALTER TABLE measurements ADD COLUMN sigma_monitor REAL;
)sql",
    // 5: the estimate made when the run was created (#17), and the exposure each point took
    // (ranging tries, averaged frames, retakes and the darks it needed; bench seconds), so that
    // a run shows what it was expected to cost beside what it cost. NULL for earlier rows.
    R"sql(
ALTER TABLE runs ADD COLUMN estimate_s REAL;
ALTER TABLE runs ADD COLUMN estimate_exposure_s REAL;
ALTER TABLE runs ADD COLUMN estimate_basis TEXT;
ALTER TABLE measurements ADD COLUMN exposed_s REAL;
)sql",
    // 6: adaptive runs (#17): the points a run chose as it went carry the exposure planned for
    // them (the engine's first try) and the bench seconds predicted for them, against which the
    // run checks its budget. NULL for the points a plan set out.
    R"sql(
ALTER TABLE plan_points ADD COLUMN planned_exposure_s REAL;
ALTER TABLE plan_points ADD COLUMN predicted_s REAL;
)sql",
    // 7: measured backgrounds (#16 item 3): the stray light seen with the beam blocked, already
    // subtracted from value, and its uncertainty, a component of sigma. NULL where none was
    // measured.
    R"sql(
ALTER TABLE measurements ADD COLUMN background REAL;
ALTER TABLE measurements ADD COLUMN sigma_background REAL;
)sql",
    // 8: the part of sigma_stat that the point's dark set makes, which every point subtracted
    // with that set shares (#16). NULL for earlier rows.
    R"sql(
ALTER TABLE measurements ADD COLUMN sigma_dark REAL;
)sql",
};
constexpr int kMigrationCount = sizeof kMigrations / sizeof kMigrations[0];
static_assert(kMigrationCount == kSchemaVersion);

using Stmt = SqlStatement;

std::string Hash(const std::string& text) {  // FNV-1a, 64 bit: identity, not security
  std::uint64_t h = 1469598103934665603ull;
  for (unsigned char c : text) h = (h ^ c) * 1099511628211ull;
  char b[17];
  std::snprintf(b, sizeof b, "%016llx", static_cast<unsigned long long>(h));
  return b;
}

}  // namespace

Result<std::unique_ptr<Storage>> Storage::Open(const std::string& path) {
  std::unique_ptr<Storage> s(new Storage());
  s->path_ = path;
  if (sqlite3_open_v2(path.c_str(), &s->db_, SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE, nullptr) !=
      SQLITE_OK)
    return Error{ErrorCode::kIo, "cannot open database " + path + ": " +
                                     (s->db_ ? sqlite3_errmsg(s->db_) : "out of memory")};
  sqlite3_busy_timeout(s->db_, 5000);
  // WAL: readers (the daemon's API, gonioctl) never block the run; FULL: a committed point
  // survives a power cut, not only a killed process.
  if (Status st = s->Exec("PRAGMA journal_mode=WAL; PRAGMA synchronous=FULL; "
                          "PRAGMA foreign_keys=ON;");
      !st.ok())
    return st.error();
  if (Status st = s->Migrate(); !st.ok()) return st.error();
  return s;
}

Storage::~Storage() { sqlite3_close(db_); }

Status Storage::Exec(const std::string& sql) { return ExecSql(db_, path_, sql.c_str()); }

Status Storage::Migrate() {
  Stmt v(db_, "PRAGMA user_version");
  if (!v.ok() || v.Step() != SQLITE_ROW) return v.Fail("reading the schema version");
  version_ = static_cast<int>(v.I(0));
  if (version_ > kSchemaVersion)
    return Error{ErrorCode::kInvalidArgument,
                 path_ + " has schema version " + std::to_string(version_) +
                     ", newer than this program's " + std::to_string(kSchemaVersion) +
                     "; use a newer gonio"};
  while (version_ < kSchemaVersion) {
    // Each migration and its version bump commit together.
    const std::string sql = std::string("BEGIN IMMEDIATE;") + kMigrations[version_] +
                            "PRAGMA user_version=" + std::to_string(version_ + 1) + ";COMMIT;";
    if (Status s = Exec(sql); !s.ok()) {
      (void)Exec("ROLLBACK");
      return s;
    }
    ++version_;
  }
  return OkStatus();
}

Result<std::int64_t> Storage::EnsureSpecimen(const Specimen& sp) {
  std::lock_guard guard(mu_);
  Stmt ins(db_,
           "INSERT INTO specimens(name, material, thickness_mm, eta) VALUES(?,?,?,?) "
           "ON CONFLICT(name) DO UPDATE SET material=excluded.material, "
           "thickness_mm=excluded.thickness_mm, eta=excluded.eta");
  ins.Bind(1, sp.name).Bind(2, sp.material).Bind(3, sp.thickness_mm).Bind(4, sp.eta);
  if (ins.Step() != SQLITE_DONE) return ins.Fail("storing specimen " + sp.name);
  Stmt q(db_, "SELECT id FROM specimens WHERE name=?");
  q.Bind(1, sp.name);
  if (q.Step() != SQLITE_ROW) return q.Fail("reading specimen " + sp.name);
  return q.I(0);
}

Result<std::int64_t> Storage::StoreConfig(const std::string& text) {
  std::lock_guard guard(mu_);
  const std::string h = Hash(text);
  Stmt ins(db_, "INSERT OR IGNORE INTO instrument_configs(hash, content) VALUES(?,?)");
  ins.Bind(1, h).Bind(2, text);
  if (ins.Step() != SQLITE_DONE) return ins.Fail("storing the instrument config");
  Stmt q(db_, "SELECT id FROM instrument_configs WHERE hash=?");
  q.Bind(1, h);
  if (q.Step() != SQLITE_ROW) return q.Fail("reading the instrument config");
  return q.I(0);
}

Result<std::int64_t> Storage::CreateRun(std::int64_t specimen_id, std::int64_t config_id,
                                        const std::string& plan_text,
                                        const std::vector<PlannedPoint>& points,
                                        const std::string& response) {
  std::lock_guard guard(mu_);
  if (Status s = Exec("BEGIN IMMEDIATE"); !s.ok()) return s.error();
  auto fail = [&](const Error& e) {
    (void)Exec("ROLLBACK");
    return e;
  };
  Stmt run(db_,
           "INSERT INTO runs(specimen_id, config_id, plan, status, response) "
           "VALUES(?,?,?,'planned',?)");
  run.Bind(1, specimen_id).Bind(2, config_id).Bind(3, plan_text);
  if (response.empty())
    run.Bind(4, std::optional<double>());  // NULL: no response
  else
    run.Bind(4, response);
  if (run.Step() != SQLITE_DONE) return fail(run.Fail("creating the run"));
  const std::int64_t id = sqlite3_last_insert_rowid(db_);
  for (const PlannedPoint& p : points)
    if (Status s = InsertPoint(id, p); !s.ok()) return fail(s.error());
  if (Status s = Exec("COMMIT"); !s.ok()) return fail(s.error());
  return id;
}

Status Storage::InsertPoint(std::int64_t run, const PlannedPoint& p) {
  Stmt pt(db_,
          "INSERT INTO plan_points(run_id, idx, theta_l_deg, theta_v_deg, phi_deg, sample_deg, "
          "arm_deg, azimuth_deg, status, reason, side, planned_exposure_s, predicted_s) "
          "VALUES(?,?,?,?,?,?,?,?,?,?,?,?,?)");
  pt.Bind(1, run).Bind(2, p.index).Bind(3, p.theta_l_deg).Bind(4, p.theta_v_deg);
  pt.Bind(5, p.phi_deg).Bind(6, p.stage.sample_deg).Bind(7, p.stage.arm_deg);
  pt.Bind(8, p.stage.azimuth_deg).Bind(9, std::string(p.skipped ? "skipped" : "pending"));
  pt.Bind(10, p.reason)
      .Bind(11, std::string(ToString(p.reflection ? Side::kReflection : Side::kTransmission)));
  pt.Bind(12, p.planned_exposure_s);
  pt.Bind(13, p.predicted_s > 0 ? std::optional<double>(p.predicted_s) : std::nullopt);
  if (pt.Step() != SQLITE_DONE) return pt.Fail("storing plan point " + std::to_string(p.index));
  return OkStatus();
}

Result<std::vector<int>> Storage::AddChosenPoints(std::int64_t run,
                                                  std::vector<PlannedPoint> points,
                                                  const std::vector<std::string>& reasons) {
  std::lock_guard guard(mu_);
  if (Status s = Exec("BEGIN IMMEDIATE"); !s.ok()) return s.error();
  auto fail = [&](const Error& e) -> Error {
    (void)Exec("ROLLBACK");
    return e;
  };
  Stmt q(db_, "SELECT coalesce(max(idx), -1) FROM plan_points WHERE run_id=?");
  q.Bind(1, run);
  if (q.Step() != SQLITE_ROW) return fail(q.Fail("numbering the chosen points"));
  int next = static_cast<int>(q.I(0)) + 1;
  std::vector<int> indices;
  for (std::size_t k = 0; k < points.size(); ++k) {
    PlannedPoint& p = points[k];
    p.index = next++;
    p.skipped = false;
    p.reason.clear();
    if (Status s = InsertPoint(run, p); !s.ok()) return fail(s.error());
    Stmt e(db_, "INSERT INTO run_events(run_id, kind, detail) VALUES(?,'chosen',?)");
    e.Bind(1, run).Bind(2, "point " + std::to_string(p.index) + ": " +
                               (k < reasons.size() ? reasons[k] : std::string()));
    if (e.Step() != SQLITE_DONE) return fail(e.Fail("storing a choice"));
    indices.push_back(p.index);
  }
  if (Status s = Exec("COMMIT"); !s.ok()) return fail(s.error());
  return indices;
}

Result<std::int64_t> Storage::NewRun(const Plan& plan, const std::string& config_text,
                                     const std::vector<PlannedPoint>& points,
                                     const std::string& response) {
  auto specimen = EnsureSpecimen(plan.specimen);
  if (!specimen.ok()) return specimen.error();
  auto config = StoreConfig(config_text);
  if (!config.ok()) return config.error();
  return CreateRun(*specimen, *config, plan.text, points, response);
}

const char* ToString(RunStatus s) {
  switch (s) {
    case RunStatus::kPlanned:
      return "planned";
    case RunStatus::kRunning:
      return "running";
    case RunStatus::kPaused:
      return "paused";
    case RunStatus::kDone:
      return "done";
    case RunStatus::kAborted:
      return "aborted";
    case RunStatus::kFailed:
      return "failed";
  }
  return "?";
}

std::optional<RunStatus> ParseRunStatus(std::string_view text) {
  for (RunStatus s : {RunStatus::kPlanned, RunStatus::kRunning, RunStatus::kPaused,
                      RunStatus::kDone, RunStatus::kAborted, RunStatus::kFailed})
    if (text == ToString(s)) return s;
  return std::nullopt;
}

Status Storage::SetRunStatus(std::int64_t run, RunStatus status) {
  std::lock_guard guard(mu_);
  Stmt u(db_, Finished(status) ? "UPDATE runs SET status=?, "
                                 "finished_at=strftime('%Y-%m-%dT%H:%M:%fZ','now') WHERE id=?"
                               : "UPDATE runs SET status=? WHERE id=?");
  const std::string text = ToString(status);
  u.Bind(1, text).Bind(2, run);
  if (u.Step() != SQLITE_DONE) return u.Fail("setting run " + std::to_string(run) + " " + text);
  return OkStatus();
}

Status Storage::SetMonitorReference(std::int64_t run, double watts) {
  std::lock_guard guard(mu_);
  Stmt u(db_, "UPDATE runs SET monitor_reference_w=? WHERE id=?");
  u.Bind(1, watts).Bind(2, run);
  if (u.Step() != SQLITE_DONE) return u.Fail("storing the monitor reference");
  return OkStatus();
}

Status Storage::AddEvent(std::int64_t run, const std::string& kind, const std::string& detail) {
  std::lock_guard guard(mu_);
  Stmt i(db_, "INSERT INTO run_events(run_id, kind, detail) VALUES(?,?,?)");
  i.Bind(1, run).Bind(2, kind).Bind(3, detail);
  if (i.Step() != SQLITE_DONE) return i.Fail("storing a run event");
  return OkStatus();
}

Result<std::vector<RunEvent>> Storage::Events(std::int64_t run) {
  std::lock_guard guard(mu_);
  Stmt q(db_, "SELECT kind, detail, at FROM run_events WHERE run_id=? ORDER BY rowid");
  q.Bind(1, run);
  std::vector<RunEvent> out;
  int rc = 0;
  while ((rc = q.Step()) == SQLITE_ROW) out.push_back({q.T(0), q.T(1), q.T(2)});
  if (rc != SQLITE_DONE) return q.Fail("reading run events");
  return out;
}

Result<RunInfo> Storage::GetRun(std::int64_t run) {
  std::lock_guard guard(mu_);
  Stmt q(db_,
         "SELECT r.id, s.name, r.status, r.monitor_reference_w, r.plan, "
         "(SELECT count(*) FROM plan_points WHERE run_id=r.id), "
         "(SELECT count(*) FROM plan_points WHERE run_id=r.id AND status='done'), "
         "(SELECT count(*) FROM plan_points WHERE run_id=r.id AND status='skipped'), s.eta, "
         "r.response, r.estimate_s, r.estimate_exposure_s, r.estimate_basis, "
         "(SELECT sum(exposed_s) FROM measurements WHERE run_id=r.id) "
         "FROM runs r JOIN specimens s ON s.id=r.specimen_id WHERE r.id=?");
  q.Bind(1, run);
  if (q.Step() != SQLITE_ROW)
    return Error{ErrorCode::kInvalidArgument, "no run " + std::to_string(run) + " in " + path_};
  RunInfo i;
  i.id = q.I(0);
  i.specimen = q.T(1);
  const std::string status = q.T(2);
  const auto parsed = ParseRunStatus(status);
  if (!parsed)  // the schema's CHECK admits only the six: a file edited by hand
    return Error{ErrorCode::kIo, path_ + ": run " + std::to_string(run) + " has status '" + status +
                                     "', which is not a run status"};
  i.status = *parsed;
  if (!q.Null(3)) i.monitor_reference_w = q.D(3);
  i.plan_text = q.T(4);
  i.points_total = static_cast<int>(q.I(5));
  i.points_done = static_cast<int>(q.I(6));
  i.points_skipped = static_cast<int>(q.I(7));
  i.specimen_eta = q.D(8);
  if (!q.Null(9)) i.response = q.T(9);
  if (!q.Null(10) && !q.Null(11) && !q.Null(12))
    i.estimate = RunEstimate{q.D(10), q.D(11), q.T(12)};
  if (!q.Null(13)) i.exposed_s = q.D(13);
  return i;
}

Status Storage::SetRunEstimate(std::int64_t run, const RunEstimate& e) {
  std::lock_guard guard(mu_);
  Stmt u(db_, "UPDATE runs SET estimate_s=?, estimate_exposure_s=?, estimate_basis=? WHERE id=?");
  u.Bind(1, e.total_s).Bind(2, e.exposure_s).Bind(3, e.basis).Bind(4, run);
  if (u.Step() != SQLITE_DONE) return u.Fail("storing run " + std::to_string(run) + "'s estimate");
  return OkStatus();
}

Result<std::vector<RunInfo>> Storage::ListRuns() {
  std::lock_guard guard(mu_);
  std::vector<std::int64_t> ids;
  {
    Stmt q(db_, "SELECT id FROM runs ORDER BY id");
    int rc = 0;
    while ((rc = q.Step()) == SQLITE_ROW) ids.push_back(q.I(0));
    if (rc != SQLITE_DONE) return q.Fail("listing runs");
  }
  std::vector<RunInfo> out;
  for (std::int64_t id : ids) {
    auto r = GetRun(id);
    if (!r.ok()) return r.error();
    out.push_back(std::move(*r));
  }
  return out;
}

Result<std::optional<std::int64_t>> Storage::UnfinishedRun() {
  std::lock_guard guard(mu_);
  Stmt q(db_, "SELECT id FROM runs WHERE status IN ('running','paused') ORDER BY id DESC LIMIT 1");
  const int rc = q.Step();
  if (rc == SQLITE_ROW) return std::optional<std::int64_t>(q.I(0));
  if (rc != SQLITE_DONE) return q.Fail("looking for an unfinished run");
  return std::optional<std::int64_t>();
}

Result<std::vector<PlannedPoint>> Storage::Points(std::int64_t run, bool pending_only) {
  std::lock_guard guard(mu_);
  Stmt q(db_, pending_only
                  ? "SELECT idx, theta_l_deg, theta_v_deg, phi_deg, sample_deg, arm_deg, "
                    "azimuth_deg, status, reason, side, planned_exposure_s, predicted_s FROM "
                    "plan_points WHERE run_id=? AND status='pending' ORDER BY idx"
                  : "SELECT idx, theta_l_deg, theta_v_deg, phi_deg, sample_deg, arm_deg, "
                    "azimuth_deg, status, reason, side, planned_exposure_s, predicted_s FROM "
                    "plan_points WHERE run_id=? ORDER BY idx");
  q.Bind(1, run);
  std::vector<PlannedPoint> out;
  int rc;
  while ((rc = q.Step()) == SQLITE_ROW) {
    PlannedPoint p;
    p.index = static_cast<int>(q.I(0));
    p.theta_l_deg = q.D(1);
    p.theta_v_deg = q.D(2);
    p.phi_deg = q.D(3);
    p.stage = {q.D(4), q.D(5), q.D(6)};
    p.skipped = q.T(7) == "skipped";
    p.reason = q.T(8);
    p.reflection = q.T(9) == ToString(Side::kReflection);
    if (!q.Null(10)) p.planned_exposure_s = q.D(10);
    p.predicted_s = q.Null(11) ? 0 : q.D(11);
    out.push_back(p);
  }
  if (rc != SQLITE_DONE) return q.Fail("reading plan points");
  return out;
}

Status Storage::StoreMeasurement(std::int64_t run, const Measurement& m) {
  std::lock_guard guard(mu_);
  if (Status s = Exec("BEGIN IMMEDIATE"); !s.ok()) return s;
  auto fail = [&](const Error& e) -> Status {
    (void)Exec("ROLLBACK");
    return e;
  };
  Stmt i(db_,
         "INSERT INTO measurements(run_id, idx, sample_read_deg, arm_read_deg, azimuth_read_deg, "
         "exposure_s, frames, temperature_c, monitor_w, rect_mean, rect_sd, pixel_var, "
         "rect_pixels, rect_saturated, dark_id, value, sigma, flags, ranging_tries, sigma_stat, "
         "sigma_lamp, sigma_monitor, exposed_s, background, sigma_background, sigma_dark) "
         "VALUES(?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?)");
  i.Bind(1, run).Bind(2, m.index).Bind(3, m.sample_read_deg).Bind(4, m.arm_read_deg);
  i.Bind(5, m.azimuth_read_deg).Bind(6, m.exposure_s).Bind(7, m.frames).Bind(8, m.temperature_c);
  i.Bind(9, m.monitor_w).Bind(10, m.rect_mean).Bind(11, m.rect_sd).Bind(12, m.pixel_var);
  i.Bind(13, m.rect_pixels).Bind(14, m.rect_saturated);
  if (m.dark_id > 0) {
    i.Bind(15, m.dark_id);
  } else {
    i.Bind(15, std::optional<double>());  // no dark: NULL
  }
  i.Bind(16, m.value);
  i.Bind(17, m.sigma).Bind(18, m.flags).Bind(19, m.ranging_tries);
  i.Bind(20, m.sigma_stat).Bind(21, m.sigma_lamp).Bind(22, m.sigma_monitor);
  i.Bind(23, m.exposed_s);
  i.Bind(24, m.background);
  i.Bind(25, m.background ? std::optional<double>(m.sigma_background) : std::nullopt);
  i.Bind(26, m.sigma_dark);
  if (i.Step() != SQLITE_DONE)
    return fail(
        i.Fail("storing point " + std::to_string(m.index) + " of run " + std::to_string(run)));
  Stmt u(db_, "UPDATE plan_points SET status='done' WHERE run_id=? AND idx=? AND status='pending'");
  u.Bind(1, run).Bind(2, m.index);
  if (u.Step() != SQLITE_DONE || sqlite3_changes(db_) != 1)
    return fail(Error{ErrorCode::kInvalidArgument, "point " + std::to_string(m.index) + " of run " +
                                                       std::to_string(run) + " is not pending"});
  if (Status s = Exec("COMMIT"); !s.ok()) return fail(s.error());
  return OkStatus();
}

Status Storage::UpdateBudgets(std::int64_t run, const std::vector<BudgetUpdate>& updates) {
  std::lock_guard guard(mu_);
  if (Status s = Exec("BEGIN IMMEDIATE"); !s.ok()) return s;
  for (const BudgetUpdate& b : updates) {
    Stmt u(db_,
           "UPDATE measurements SET sigma=?, sigma_lamp=?, sigma_monitor=?, sigma_background=? "
           "WHERE run_id=? AND idx=?");
    u.Bind(1, b.sigma).Bind(2, b.sigma_lamp).Bind(3, b.sigma_monitor).Bind(4, b.sigma_background);
    u.Bind(5, run).Bind(6, b.index);
    const std::string what = "point " + std::to_string(b.index) + " of run " + std::to_string(run);
    Error e{ErrorCode::kInvalidArgument, "no measurement of " + what};
    const bool stepped = u.Step() == SQLITE_DONE;
    if (!stepped) e = u.Fail("updating the budget of " + what);
    if (!stepped || sqlite3_changes(db_) != 1) {
      (void)Exec("ROLLBACK");
      return e;
    }
  }
  return Exec("COMMIT");
}

Result<std::vector<MeasurementRow>> Storage::Measurements(std::int64_t run) {
  std::lock_guard guard(mu_);
  Stmt q(db_,
         "SELECT p.idx, p.theta_l_deg, p.theta_v_deg, p.phi_deg, p.sample_deg, p.arm_deg, "
         "p.azimuth_deg, m.sample_read_deg, m.arm_read_deg, m.azimuth_read_deg, m.exposure_s, "
         "m.frames, m.temperature_c, m.monitor_w, m.rect_mean, m.rect_sd, m.pixel_var, "
         "m.rect_pixels, m.rect_saturated, m.dark_id, m.value, m.sigma, m.flags, m.ranging_tries, "
         "p.side, m.sigma_stat, m.sigma_lamp, m.sigma_monitor, m.exposed_s, p.planned_exposure_s, "
         "p.predicted_s, d.rect_mean, m.background, m.sigma_background, m.sigma_dark "
         "FROM measurements m "
         "JOIN plan_points p ON p.run_id=m.run_id AND p.idx=m.idx "
         "LEFT JOIN darks d ON d.id=m.dark_id "
         "WHERE m.run_id=? ORDER BY p.idx");
  q.Bind(1, run);
  std::vector<MeasurementRow> out;
  int rc;
  while ((rc = q.Step()) == SQLITE_ROW) {
    MeasurementRow r;
    r.point.index = r.m.index = static_cast<int>(q.I(0));
    r.point.theta_l_deg = q.D(1);
    r.point.theta_v_deg = q.D(2);
    r.point.phi_deg = q.D(3);
    r.point.stage = {q.D(4), q.D(5), q.D(6)};
    r.m.sample_read_deg = q.D(7);
    r.m.arm_read_deg = q.D(8);
    r.m.azimuth_read_deg = q.D(9);
    r.m.exposure_s = q.D(10);
    r.m.frames = static_cast<int>(q.I(11));
    r.m.temperature_c = q.D(12);
    if (!q.Null(13)) r.m.monitor_w = q.D(13);
    r.m.rect_mean = q.D(14);
    r.m.rect_sd = q.D(15);
    r.m.pixel_var = q.D(16);
    r.m.rect_pixels = static_cast<int>(q.I(17));
    r.m.rect_saturated = static_cast<int>(q.I(18));
    r.m.dark_id = q.I(19);
    r.m.value = q.D(20);
    r.m.sigma = q.D(21);
    r.m.flags = static_cast<int>(q.I(22));
    r.m.ranging_tries = static_cast<int>(q.I(23));
    r.point.reflection = q.T(24) == ToString(Side::kReflection);
    // Points stored before the budget (schema 4) have their sigma as the statistical part.
    r.m.sigma_stat = q.Null(25) ? r.m.sigma : q.D(25);
    r.m.sigma_lamp = q.Null(26) ? 0 : q.D(26);
    r.m.sigma_monitor = q.Null(27) ? 0 : q.D(27);
    r.m.exposed_s = q.Null(28) ? 0 : q.D(28);
    if (!q.Null(29)) r.point.planned_exposure_s = q.D(29);
    r.point.predicted_s = q.Null(30) ? 0 : q.D(30);
    if (!q.Null(31)) r.dark_rect_mean = q.D(31);
    if (!q.Null(32)) r.m.background = q.D(32);
    r.m.sigma_background = q.Null(33) ? 0 : q.D(33);
    r.m.sigma_dark = q.Null(34) ? 0 : q.D(34);
    out.push_back(r);
  }
  if (rc != SQLITE_DONE) return q.Fail("reading measurements");
  return out;
}

Result<std::optional<ExposureHistory>> Storage::LatestExposures(const std::string& specimen) {
  std::lock_guard guard(mu_);
  Stmt q(db_,
         "SELECT r.id FROM runs r JOIN specimens s ON s.id=r.specimen_id "
         "WHERE s.name=? AND r.status='done' ORDER BY r.id DESC LIMIT 1");
  q.Bind(1, specimen);
  const int rc = q.Step();
  if (rc == SQLITE_DONE) return std::optional<ExposureHistory>();
  if (rc != SQLITE_ROW) return q.Fail("looking for an earlier run of " + specimen);
  ExposureHistory h;
  h.run = q.I(0);
  auto rows = Measurements(h.run);
  if (!rows.ok()) return rows.error();
  for (const MeasurementRow& r : *rows)
    h.entries.push_back({r.point.theta_l_deg, r.point.theta_v_deg, r.point.phi_deg, r.m.exposure_s,
                         r.m.ranging_tries, r.point.reflection});
  return std::optional<ExposureHistory>(std::move(h));
}

Result<std::optional<Throughput>> Storage::LatestThroughput() {
  std::lock_guard guard(mu_);
  Stmt q(db_,
         "SELECT r.id, json_extract(f.parameters, '$.scale'), "
         "coalesce(json_extract(f.parameters, '$.floor'), 0) FROM runs r "
         "JOIN fit_results f ON f.run_id = r.id "
         "WHERE r.status = 'done' AND json_valid(f.parameters) "
         "AND json_extract(f.parameters, '$.chosen') = 1 "
         "AND json_extract(f.parameters, '$.scale') > 0 ORDER BY r.id DESC, f.id DESC LIMIT 1");
  int rc = q.Step();
  if (rc == SQLITE_DONE) return std::optional<Throughput>();
  if (rc != SQLITE_ROW) return q.Fail("looking for a run with a fit");
  Throughput t;
  t.run = q.I(0);
  t.scale = q.D(1);
  t.floor = std::max(0.0, q.D(2));
  // Counts per stored value: the rectangle's rate above its dark over the value (the monitor
  // normalisation), and the dark's level; medians, so that a stray point does not decide.
  // The points' sigmas calibrate the bench's noise per frame (for an adaptive plan's forecast).
  Stmt m(db_,
         "SELECT (m.rect_mean - d.rect_mean) / m.exposure_s / m.value, d.rect_mean, "
         "m.value, m.sigma, m.exposure_s, m.frames "
         "FROM measurements m JOIN darks d ON d.id = m.dark_id "
         "WHERE m.run_id = ? AND m.value > 0 AND m.exposure_s > 0");
  m.Bind(1, t.run);
  std::vector<double> per_value, dark;
  std::vector<Observation> points;
  while ((rc = m.Step()) == SQLITE_ROW) {
    if (m.D(0) > 0) per_value.push_back(m.D(0));
    dark.push_back(m.D(1));
    Observation o;
    o.value = m.D(2), o.sigma = m.D(3), o.exposure_s = m.D(4);
    o.frames = static_cast<int>(m.I(5));
    points.push_back(o);
  }
  if (rc != SQLITE_DONE) return m.Fail("reading run " + std::to_string(t.run) + "'s exposures");
  if (per_value.empty()) return std::optional<Throughput>();
  auto median = [](std::vector<double>& v) {
    std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
    return v[v.size() / 2];
  };
  t.adu_per_value = median(per_value);
  t.dark_adu = median(dark);
  if (auto noise = CalibrateFrameNoise(points); noise.ok()) t.noise = *noise;
  return std::optional<Throughput>(t);
}

Result<std::int64_t> Storage::StoreDark(const DarkRecord& d) {
  std::lock_guard guard(mu_);
  Stmt i(db_,
         "INSERT INTO darks(exposure_s, temperature_c, frames, rect_mean, pixel_var, "
         "taken_unix_s) VALUES(?,?,?,?,?,?)");
  i.Bind(1, d.exposure_s).Bind(2, d.temperature_c).Bind(3, d.frames).Bind(4, d.mean);
  i.Bind(5, d.pixel_var).Bind(6, d.taken_unix_s);
  if (i.Step() != SQLITE_DONE) return i.Fail("storing a dark frame");
  return sqlite3_last_insert_rowid(db_);
}

Result<std::int64_t> Storage::StoreFitResult(std::int64_t run, const std::string& model,
                                             const std::string& parameters,
                                             const std::string& summary) {
  std::lock_guard guard(mu_);
  Stmt i(db_, "INSERT INTO fit_results(run_id, model, parameters, summary) VALUES(?,?,?,?)");
  i.Bind(1, run).Bind(2, model).Bind(3, parameters).Bind(4, summary);
  if (i.Step() != SQLITE_DONE) return i.Fail("storing a fit result of run " + std::to_string(run));
  return static_cast<std::int64_t>(sqlite3_last_insert_rowid(db_));
}

Result<std::vector<FitRecord>> Storage::FitResults(std::int64_t run) {
  std::lock_guard guard(mu_);
  Stmt q(db_,
         "SELECT id, model, parameters, summary, created_at FROM fit_results WHERE run_id=? "
         "ORDER BY id");
  q.Bind(1, run);
  std::vector<FitRecord> out;
  int rc = 0;
  while ((rc = q.Step()) == SQLITE_ROW) out.push_back({q.I(0), q.T(1), q.T(2), q.T(3), q.T(4)});
  if (rc != SQLITE_DONE) return q.Fail("reading the fit results of run " + std::to_string(run));
  return out;
}

Status Storage::ExportCsv(std::int64_t run, const std::string& path) {
  std::lock_guard guard(mu_);
  // Written beside the file and renamed over it once whole: an export that fails (an unknown
  // run, a full disk) or is interrupted leaves an earlier export of that name as it was.
  const std::string partial = path + ".partial";
  Status s = [&]() -> Status {
    std::ofstream out(partial);
    if (!out) return Error{ErrorCode::kIo, "cannot write " + partial};
    if (Status e = ExportCsv(run, out); !e.ok()) return e;
    out.close();
    if (!out) return Error{ErrorCode::kIo, "writing " + partial + " failed"};
    return OkStatus();
  }();
  std::error_code ec;
  if (s.ok()) {
    std::filesystem::rename(partial, path, ec);
    if (ec) s = Error{ErrorCode::kIo, "renaming " + partial + " to " + path + ": " + ec.message()};
  }
  if (!s.ok()) std::filesystem::remove(partial, ec);
  return s;
}

Status Storage::ExportCsv(std::int64_t run, std::ostream& out) {
  std::lock_guard guard(mu_);
  auto rows = Measurements(run);
  if (!rows.ok()) return rows.error();
  auto info = GetRun(run);
  if (!info.ok()) return info.error();
  out << "# run " << run
      << ": dark-subtracted, monitor-normalised counts per second (background-subtracted where "
         "the background column is set)\n";
  // The instrument response's setup (fitting/samples_csv.h reads it back with the stage columns).
  if (info->response) out << "# response: " << *info->response << "\n";
  out << "theta_l_deg,theta_v_deg,phi_l_deg,phi_v_deg,value,sigma,exposure_s,frames,"
         "rect_mean_adu,temperature_c,monitor_w,flags,side,sample_read_deg,arm_read_deg,"
         "azimuth_read_deg,sigma_stat,sigma_lamp,sigma_monitor,background,sigma_background,"
         "dark_set,sigma_dark\n";
  out.precision(9);
  for (const MeasurementRow& r : *rows) {
    out << r.point.theta_l_deg << "," << r.point.theta_v_deg << "," << r.point.phi_deg << ","
        << r.point.phi_deg << "," << r.m.value << "," << r.m.sigma << "," << r.m.exposure_s << ","
        << r.m.frames << "," << r.m.rect_mean << "," << r.m.temperature_c << ",";
    // At the stream's 9 digits (std::to_string's 6 decimals kept 4 of a 1.7 mW reading's).
    if (r.m.monitor_w) out << *r.m.monitor_w;
    out << "," << r.m.flags << ","
        << ToString(r.point.reflection ? acquisition::Side::kReflection
                                       : acquisition::Side::kTransmission)
        << "," << r.m.sample_read_deg << "," << r.m.arm_read_deg << "," << r.m.azimuth_read_deg
        << "," << r.m.sigma_stat << "," << r.m.sigma_lamp << "," << r.m.sigma_monitor << ",";
    // Empty where no background was measured (the fitter may then fit a floor).
    if (r.m.background)
      out << *r.m.background << "," << r.m.sigma_background;
    else
      out << ",";
    // The dark set the point was subtracted with (points of one set share its error, sigma_dark,
    // a part of sigma_stat); empty where there is none (a point stored without one).
    out << ",";
    if (r.m.dark_id > 0) out << r.m.dark_id;
    out << "," << r.m.sigma_dark;
    out << "\n";
  }
  return OkStatus();
}

Result<RunEstimate> EstimateRun(Storage& db, const Plan& plan,
                                const std::vector<PlannedPoint>& points,
                                const std::vector<devices::AxisSettings>& axes,
                                double linear_limit_adu, int max_ranging_tries,
                                const std::optional<Throughput>& configured) {
  auto history = db.LatestExposures(plan.specimen.name);
  if (!history.ok()) return history.error();
  const ExposureHistory* seen = *history ? &**history : nullptr;
  std::optional<Throughput> bench;
  // Read when there is no history, or for an adaptive plan (whose forecast simulates its runs).
  if (seen == nullptr || plan.strategy.kind == StrategyKind::kAdaptive) {
    auto throughput = db.LatestThroughput();
    if (!throughput.ok()) return throughput.error();
    bench = *throughput ? *throughput : configured;
  }
  return EstimateOn(plan, points, axes, seen, bench, linear_limit_adu, max_ranging_tries);
}

std::string DescribeExposureAgainstEstimate(const RunInfo& run) {
  char buf[160];
  std::string out;
  if (run.exposed_s) {
    std::snprintf(buf, sizeof buf, "exposure %.0f s", *run.exposed_s);
    out = buf;
  }
  if (run.estimate) {
    std::snprintf(buf, sizeof buf, "%sestimated %.0f s", out.empty() ? "exposure " : ", ",
                  run.estimate->exposure_s);
    out += buf;
    if (run.exposed_s && run.estimate->exposure_s > 0) {
      std::snprintf(buf, sizeof buf, " (%+.0f %%)",
                    100 * (*run.exposed_s / run.estimate->exposure_s - 1));
      out += buf;
    }
    out += " from " + run.estimate->basis;
  }
  return out;
}

}  // namespace gonio::acquisition
