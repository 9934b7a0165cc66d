// Schedules: a TOML file listing jobs to run unattended. Each [[job]] names a plan file
// (relative to the schedule), how many times to run it, and optionally a start time, a cooler
// wait before its first run, and the models to fit after each run:
//
//   [[job]]
//   plan = "plan_demo.toml"
//   repeat = 2
//   start_at = "2026-11-24T02:00"   # local time; the job does not start before it
//   fit = ["beckmann", "ggx"]       # after each run, stored with the run
//   [job.cooler]                    # before the first run: cool and hold
//   setpoint_c = -10
//   tolerance_c = 0.5
//   hold_s = 60
//   timeout_s = 900
//
// The daemon parses it with the plans' texts (gonioctl reads the files and sends them along), so
// every plan is validated against the instrument; errors carry "schedule.toml:line:" or the
// plan's "name:line:". A dry run lists what would happen and how long it would take.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "acquisition/exposure.h"
#include "acquisition/plan.h"
#include "common/result.h"

namespace gonio::daemon {

struct CoolerWait {
  double setpoint_c = -10;
  double tolerance_c = 0.5;
  double hold_s = 60;      // within tolerance continuously this long (real seconds)
  double timeout_s = 900;  // real seconds
};

struct ScheduleEntry {
  std::string plan_name;  // as the schedule writes it
  std::string plan_text;
  int repeat = 1;
  std::optional<std::int64_t> start_at_unix;
  std::optional<CoolerWait> cooler;
  std::vector<std::string> fit;
  int line = 0;  // of its [[job]]
  // From the plan: what a dry run reports.
  int points = 0, skipped = 0;
  double estimate_s = 0;        // motion and exposure of one run (bench seconds)
  std::string estimate_basis;   // acquisition::DescribeEstimateBasis, or why not priced
  bool estimate_priced = true;  // false: estimate_s is the motion only (RunEstimate::priced)
};

struct Schedule {
  std::string name;
  std::vector<ScheduleEntry> jobs;
  double EstimateSeconds() const;  // all runs, without start-time waits and cooling
};

// The exposures an earlier run of a specimen needed (Storage::LatestExposures), if any.
using ExposureLookup =
    std::function<std::optional<acquisition::ExposureHistory>(const std::string& specimen)>;

// What prices a plan before it runs (acquisition::EstimateSeconds): an earlier run of its
// specimen, else the specimen's expected lobe at the bench's throughput (the database's, else
// the instrument config's), else not priced.
struct EstimateBasis {
  ExposureLookup history;
  std::optional<acquisition::Throughput> throughput;  // Storage::LatestThroughput
  double linear_limit_adu = 65535;                    // the engine's (EngineOptions)
  int max_ranging_tries = 12;
};

// plans: plan name (as written in the schedule) -> its text. Each entry's estimate is priced on
// `basis`.
Result<Schedule> ParseSchedule(std::string_view text, const std::string& name,
                               const std::map<std::string, std::string>& plans,
                               const acquisition::PlanContext& context,
                               const EstimateBasis& basis = {});

// The plan files a schedule names, each once, with the line that names it: what a client reads
// and sends along with the schedule. Only the TOML syntax is checked here (errors
// "name:line: ..."); ParseSchedule checks the rest on the daemon's side.
struct PlanReference {
  std::string name;
  int line = 0;
};
Result<std::vector<PlanReference>> PlanReferences(std::string_view text, const std::string& name);

// "2026-11-24T02:00" or "2026-11-24T02:00:30", local time; nullopt if malformed.
std::optional<std::int64_t> ParseLocalTime(const std::string& iso);

}  // namespace gonio::daemon
