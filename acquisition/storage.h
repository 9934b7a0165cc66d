// The instrument's SQLite database (WAL): configurations, specimens, runs, their planned points,
// measurements, dark frames' statistics, calibrations and fit results, with a schema version and
// migrations (PRAGMA user_version). Each point is stored in one transaction with its plan point
// marked done, so a run killed at any moment resumes from what is committed: done points are not
// measured twice and none is lost. Schema: acquisition/README.md.
#pragma once

#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <ostream>
#include <string>
#include <string_view>
#include <vector>

#include "acquisition/exposure.h"
#include "acquisition/plan.h"
#include "common/result.h"

struct sqlite3;

namespace gonio::acquisition {

inline constexpr int kSchemaVersion = 8;

// A run's status, stored as text ("planned", "running", ...) and turned into a string only where
// it is stored or sent.
enum class RunStatus { kPlanned, kRunning, kPaused, kDone, kAborted, kFailed };
const char* ToString(RunStatus s);
std::optional<RunStatus> ParseRunStatus(std::string_view text);
// Done, aborted or failed: nothing more will be measured.
inline bool Finished(RunStatus s) {
  return s == RunStatus::kDone || s == RunStatus::kAborted || s == RunStatus::kFailed;
}

struct RunInfo {
  std::int64_t id = 0;
  std::string specimen;
  double specimen_eta = 1.5;
  RunStatus status = RunStatus::kPlanned;
  int points_total = 0, points_done = 0, points_skipped = 0;
  std::optional<double> monitor_reference_w;
  std::string plan_text;
  // What rebuilds each point's instrument response (fitting::ResponseSetup as JSON), when the
  // bench's geometry was configured.
  std::optional<std::string> response;
  std::optional<RunEstimate> estimate;  // made when it was created; none for older runs
  // The exposure its measured points took (bench seconds: ranging, frames, retakes, darks);
  // nullopt for points stored before schema 5.
  std::optional<double> exposed_s;
};

// What happened to a run besides its points: pauses, suspensions, faults, aborts.
struct RunEvent {
  std::string kind, detail, at;  // at: UTC ISO 8601
};

// A fit of a run's samples (the fitter's JSON, as the fitting layer wrote it).
struct FitRecord {
  std::int64_t id = 0;
  std::string model, parameters, summary, created_at;
};

struct DarkRecord {
  std::int64_t id = 0;
  double exposure_s = 0, temperature_c = 0;
  int frames = 0;
  double mean = 0;       // the rectangle's mean, ADU
  double pixel_var = 0;  // pooled per-pixel variance between frames, ADU^2
  double taken_unix_s = 0;
};

struct Measurement {
  int index = 0;
  double sample_read_deg = 0, arm_read_deg = 0, azimuth_read_deg = 0;
  double exposure_s = 0;
  int frames = 0;
  double temperature_c = 0;
  std::optional<double> monitor_w;
  double rect_mean = 0, rect_sd = 0;  // ADU, mean over frames; sd of the frames' means
  double pixel_var = 0;  // pooled per-pixel variance between frames, ADU^2 (common mode out)
  int rect_pixels = 0, rect_saturated = 0;
  std::int64_t dark_id = 0;
  // Dark-subtracted (background-subtracted when `background` is set), normalised counts per
  // second.
  double value = 0, sigma = 0;
  // sigma's components, added in quadrature (docs/measurement.md): shot, read and dark noise;
  // the lamp's fluctuation between the point's frames; the monitor normalisation; the measured
  // background's own uncertainty (0 when none was measured).
  double sigma_stat = 0, sigma_lamp = 0, sigma_monitor = 0, sigma_background = 0;
  // The part of sigma_stat that the dark set's own error makes: every point subtracted with the
  // same dark set (dark_id) shares it, so it is not independent from point to point as the rest
  // of sigma is (docs/measurement.md). 0 with a measured background (the dark cancels) and for
  // points stored before schema 8.
  double sigma_dark = 0;
  // The stray-light background measured with the beam blocked ([background] plans), in value's
  // units, already subtracted from value; nullopt when the plan measured none.
  std::optional<double> background;
  int flags = 0;  // kFlag*
  int ranging_tries = 0;
  // Bench seconds of exposure the point took: its ranging tries, averaged frames, retakes and
  // the darks taken for it.
  double exposed_s = 0;
};
inline constexpr int kFlagAtMaxExposure = 1;  // underexposed even at the longest exposure

struct MeasurementRow {
  PlannedPoint point;
  Measurement m;
  std::optional<double> dark_rect_mean;  // ADU, of the dark it was subtracted with
};

class Storage {
 public:
  // Opens or creates the database and migrates it to kSchemaVersion. A database newer than this
  // program is refused (kInvalidArgument) rather than touched.
  static Result<std::unique_ptr<Storage>> Open(const std::string& path);
  ~Storage();
  Storage(const Storage&) = delete;
  Storage& operator=(const Storage&) = delete;

  int schema_version() const { return version_; }

  Result<std::int64_t> EnsureSpecimen(const Specimen& s);
  // The instrument configuration's text, stored once per distinct content (by its hash).
  Result<std::int64_t> StoreConfig(const std::string& text);
  Result<std::int64_t> CreateRun(std::int64_t specimen_id, std::int64_t config_id,
                                 const std::string& plan_text,
                                 const std::vector<PlannedPoint>& points,
                                 const std::string& response = "");
  // A new run of a plan, as every program starts one: its specimen (stored once), the
  // instrument config's text (once per distinct content), and its points; the run's id.
  // `response` (may be empty): what rebuilds each point's instrument response, as JSON
  // (fitting::ResponseSetup).
  Result<std::int64_t> NewRun(const Plan& plan, const std::string& config_text,
                              const std::vector<PlannedPoint>& points,
                              const std::string& response = "");
  Status SetRunStatus(std::int64_t run, RunStatus status);
  Status SetMonitorReference(std::int64_t run, double watts);
  Status AddEvent(std::int64_t run, const std::string& kind, const std::string& detail);
  Result<std::vector<RunEvent>> Events(std::int64_t run);  // oldest first
  Result<RunInfo> GetRun(std::int64_t run);
  Status SetRunEstimate(std::int64_t run, const RunEstimate& e);
  // Every run, oldest first.
  Result<std::vector<RunInfo>> ListRuns();
  // The most recent run left running or paused (an interrupted one), if any.
  Result<std::optional<std::int64_t>> UnfinishedRun();

  Result<std::vector<PlannedPoint>> Points(std::int64_t run, bool pending_only);
  // Points an adaptive run chose (strategy.h), appended after the run's last index as pending,
  // each with a 'chosen' event carrying its reason, in one transaction: a run killed at any
  // moment has either the whole decision or none of it. Returns their indices.
  Result<std::vector<int>> AddChosenPoints(std::int64_t run, std::vector<PlannedPoint> points,
                                           const std::vector<std::string>& reasons);
  // Stores the measurement and marks its point done, atomically.
  Status StoreMeasurement(std::int64_t run, const Measurement& m);
  Result<std::vector<MeasurementRow>> Measurements(std::int64_t run);
  // A stored point's budget as re-estimated once more of the run is known (the engine's pooled
  // terms at the run's end, engine.h): sigma and the lamp, monitor and background components,
  // for the listed points of the run, in one transaction. The values and everything else stay.
  struct BudgetUpdate {
    int index = 0;
    double sigma = 0, sigma_lamp = 0, sigma_monitor = 0;
    std::optional<double> sigma_background;
  };
  Status UpdateBudgets(std::int64_t run, const std::vector<BudgetUpdate>& updates);
  // The exposures of the newest finished ("done") run of this specimen, to estimate a new plan's
  // time (EstimateSeconds); nullopt if the specimen has none.
  Result<std::optional<ExposureHistory>> LatestExposures(const std::string& specimen);
  // The bench's throughput (exposure.h) from the newest finished run of any specimen that has a
  // chosen fit with a scale, for estimates of specimens never measured; nullopt if there is none.
  Result<std::optional<Throughput>> LatestThroughput();

  Result<std::int64_t> StoreDark(const DarkRecord& d);

  // Fit results stored with their run: parameters and summary as JSON text.
  Result<std::int64_t> StoreFitResult(std::int64_t run, const std::string& model,
                                      const std::string& parameters, const std::string& summary);
  Result<std::vector<FitRecord>> FitResults(std::int64_t run);

  // The run's measurements as the fitter's CSV (fitting/samples_csv.h): theta_l_deg, theta_v_deg,
  // phi_l_deg, phi_v_deg, value, sigma, then the raw statistics and each point's side
  // (transmission or reflection). To a path: written whole or not at all (an error leaves an
  // earlier file of that name unchanged).
  Status ExportCsv(std::int64_t run, const std::string& path);
  Status ExportCsv(std::int64_t run, std::ostream& out);  // the same CSV to a stream

  // For a layer above that keeps a table of its own in this file (the daemon's job queue,
  // daemon/service/job_store.h; its table is migration 2 of the schema): runs
  // fn(connection, path) under the lock that keeps each call, and its transaction, alone, and
  // returns what fn returns. fn must not call back into this Storage.
  template <typename F>
  auto WithConnection(F&& fn) {
    std::lock_guard guard(mu_);
    return fn(db_, path_);
  }

 private:
  Storage() = default;
  Status Exec(const std::string& sql);
  Status Migrate();
  Status InsertPoint(std::int64_t run, const PlannedPoint& p);  // inside a transaction
  // One connection shared by threads (the daemon's worker and its API): each call, and each
  // call's transaction, runs alone, so one thread's statements never land in another's BEGIN.
  mutable std::recursive_mutex mu_;
  sqlite3* db_ = nullptr;
  std::string path_;
  int version_ = 0;
};

// The estimate of a new run of `plan` (EstimateOn) on what `db` holds: the newest finished run of
// its specimen, else its expected lobe at the bench's throughput (the newest run with a fit's,
// else `configured`, the instrument config's), else not priced.
Result<RunEstimate> EstimateRun(Storage& db, const Plan& plan,
                                const std::vector<PlannedPoint>& points,
                                const std::vector<devices::AxisSettings>& axes,
                                double linear_limit_adu, int max_ranging_tries,
                                const std::optional<Throughput>& configured = std::nullopt);

// "exposure 2136 s, estimated 2139 s (+0 %) from <basis>", or what of it is known ("" when
// neither is): for run summaries and events.
std::string DescribeExposureAgainstEstimate(const RunInfo& run);

}  // namespace gonio::acquisition
