// The sweep engine: measures a run's pending points in order, each one committed when complete,
// through the driver interfaces only. Per point: all axes move together, the readback is stored;
// the exposure is auto-ranged on a ladder of 8 steps per decade (no rectangle pixel past
// `saturation` of the linear range; the brightest pixel brought above a quarter of `target`,
// and flagged if it stays below `floor` at max_s); N frames are accumulated; a dark at the same
// exposure and temperature comes from the dark library (reused while fresh, retaken when stale
// or when the temperature moved); the source monitor, when present, is read around every frame
// and normalises by the lamp's output.
//
// Stored value: (rectangle mean - dark mean) / exposure, in counts per second, divided by the
// monitor's mean reading in mW when there is a monitor (so runs on different days compare),
// proportional to BTDF * cos(theta_l) (REFERENCE.md section 1). Its sigma comes from the pooled
// per-pixel variance of the frames and of the dark, and the spread of the monitor's readings.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <map>
#include <optional>

#include "acquisition/plan.h"
#include "acquisition/storage.h"
#include "drivers/camera/camera.h"
#include "drivers/monitor/source_monitor.h"
#include "drivers/stage/stage.h"

namespace gonio::acquisition {

inline constexpr double kMonitorUnitW = 1e-3;  // values are per mW at the monitor

struct EngineOptions {
  double linear_limit_adu = 65535;  // the sensor's linear range (full well), raw ADU
  int max_ranging_tries = 12;
};

// What the engine spent its time on (for the efficiency benchmark and logs).
struct EngineStats {
  int points = 0;
  int frames = 0, ranging_frames = 0, dark_frames = 0;  // frames = the averaged ones
  double exposure_s = 0;       // summed over every frame taken (averaged, ranging, dark)
  double dark_exposure_s = 0;  // of which darks
};

struct Progress {
  int done = 0, total = 0;  // measured points of the run (skipped ones not counted)
  PlannedPoint point;
  Measurement last;
  double elapsed_s = 0, eta_s = 0;
};

class Engine {
 public:
  // The devices and the database must outlive the engine; `monitor` may be null.
  Engine(drivers::StageController& stages, drivers::Camera& camera, drivers::SourceMonitor* monitor,
         Storage& db, EngineOptions options = {});

  // Runs (or resumes) `run`. Returns OK when every point is done (the run is marked done), or
  // when `stop` was set (after the current point is stored; the run is left paused). A device
  // error stops the stages and leaves the run paused for a resume, with the error returned.
  Status Run(std::int64_t run, const Plan& plan, const std::atomic<bool>& stop,
             const std::function<void(const Progress&)>& progress = {});

  const EngineStats& stats() const { return stats_; }

 private:
  Result<Measurement> MeasurePoint(const PlannedPoint& p, const Plan& plan);
  Result<const DarkRecord*> DarkFor(double exposure_s, const Plan& plan);
  Result<double> MonitorW();

  drivers::StageController& stages_;
  drivers::Camera& camera_;
  drivers::SourceMonitor* monitor_;
  Storage& db_;
  EngineOptions o_;
  std::int64_t run_ = 0;
  std::optional<double> monitor_reference_;
  double last_exposure_s_ = 0;
  std::map<std::int64_t, DarkRecord> darks_;  // by exposure in microseconds
  EngineStats stats_;
};

}  // namespace gonio::acquisition
