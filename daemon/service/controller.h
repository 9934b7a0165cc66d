// The daemon's core: a job queue of measurement plans, one worker thread that runs them through
// the sweep engine on the instrument, run control (pause, resume, abort), suspenders, and an
// event log. It owns no device: the caller opens them (goniod from the instrument config, tests
// from the simulator) and keeps them alive; everything here works through the driver interfaces.
//
// States (Report().state):
//   idle       no run in hand; the next queued job starts at once (or at its start time)
//   cooling    a scheduled job waits for the sensor to reach its setpoint and hold it
//   running    the engine is measuring the current job's run
//   paused     stopped by the operator after a stored point; resume continues, abort ends it
//   suspended  stopped by a condition (sensor temperature out of band, monitor below its floor,
//              a device fault that the drivers' retries did not clear); the condition is polled
//              and the run continues by itself once it clears. Each suspension is a run event.
//   aborting   abort asked while running: the current point finishes, then the stages stop
//   fault      a suspension that did not clear within its limit; resume retries, abort ends it
//
// Every point is committed by the engine before a pause, suspension, abort or shutdown takes
// effect, so nothing measured is lost and nothing is measured twice. Every job is stored in the
// database (Storage's jobs) as it changes, so a restart finds the queue in its order, and the
// interrupted job with its schedule options (a cooler wait is done again; the fits still follow).
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "acquisition/engine.h"
#include "acquisition/plan.h"
#include "acquisition/run_start.h"
#include "acquisition/storage.h"
#include "daemon/schedule/schedule.h"
#include "daemon/service/events.h"
#include "daemon/service/frame_view.h"
#include "daemon/service/job_store.h"

namespace gonio::daemon {

enum class State { kIdle, kCooling, kRunning, kPaused, kSuspended, kAborting, kFault };
const char* ToString(State s);

struct Job {
  std::int64_t id = 0;
  std::string name;       // the submitter's label (a plan file name)
  std::string plan_text;  // TOML, validated at submit
  JobState state = JobState::kQueued;
  std::optional<std::int64_t> run;  // once started
  std::string message;              // why it failed, was aborted or cancelled
  // From a schedule (all optional): not before this time; cool and hold first; fit after.
  std::optional<std::int64_t> start_at_unix;
  std::optional<CoolerWait> cooler;
  std::vector<std::string> fit;
  std::string schedule;  // the schedule's name, if it came from one
  bool cooled = false;   // this process has done the cooler wait (a restart waits again)
};

// The job, and a run's progress, as the API and the event stream show them.
nlohmann::json ToJson(const Job& j);
nlohmann::json ToJson(const acquisition::Progress& p);

// Conditions that suspend a run (Bluesky's suspenders). Unset ones are not checked.
struct Suspenders {
  // Sensor temperature must stay within setpoint_c +- band_c.
  std::optional<double> temperature_setpoint_c;
  double temperature_band_c = 2.0;
  // The source monitor's reading must stay above this (W); needs a monitor.
  std::optional<double> monitor_floor_w;
  double poll_s = 2.0;  // how often a suspended condition is checked (real seconds)
  // How often the devices' links are checked while a run measures (CheckLink of the stages, the
  // camera and the monitor, on a thread beside the engine): a device gone suspends the run
  // within this and the check's own time, not at the engine's next use of it. 0: not checked.
  double link_check_s = 0.5;
  double fault_give_up_s = 600.0;  // a device fault not cleared this long becomes State::kFault
};

struct ControllerOptions {
  // How each run starts (acquisition/run_start.h): the engine's options, the config text and the
  // responses stored with it, the configured [throughput] its estimate may be priced on.
  acquisition::RunStart run_start;
  Suspenders suspenders;
};

struct StatusReport {
  State state = State::kIdle;
  std::string reason;  // why paused, suspended or in fault
  std::optional<Job> job;
  std::optional<acquisition::Progress> progress;  // of the current run, after its first point
  int queued = 0;
};

class Controller {
 public:
  // The devices and the database outlive the controller; monitor may be null. `context` checks
  // submitted plans (specimen catalogue, travel limits, image size).
  Controller(devices::StageController& stages, devices::Camera& camera,
             devices::SourceMonitor* monitor, acquisition::Storage& db,
             acquisition::PlanContext context, ControllerOptions options);
  ~Controller();  // Shutdown()
  Controller(const Controller&) = delete;
  Controller& operator=(const Controller&) = delete;

  // Loads the stored jobs (the queue in its order, recent finished ones) and starts the worker.
  // With `resume_interrupted`, the job whose run was left unfinished in the database (the daemon
  // was killed or stopped), or a run left by another program, is taken up again: resumed at once
  // (true) or held paused for the operator (false). Without, it is listed as paused and left.
  Status Start(std::optional<bool> resume_interrupted = std::nullopt);
  // Stops after the current point is stored, leaves the run paused in the database (a restart
  // resumes it), stops the stages, and joins the worker. Idempotent.
  void Shutdown();

  // Validates the plan (errors "name:line: what", kInvalidArgument) and queues it.
  Result<Job> Submit(const std::string& name, const std::string& plan_text);
  // Validates the job's plan and queues it with its schedule options (job.id and state ignored).
  Result<Job> Submit(Job job);
  // Queues every run of a parsed schedule (the cooler wait before each entry's first run).
  Result<std::vector<Job>> Submit(const Schedule& schedule);
  const acquisition::PlanContext& context() const { return context_; }
  const acquisition::EngineOptions& engine_options() const { return o_.run_start.engine; }
  const std::optional<acquisition::Throughput>& configured_throughput() const {
    return o_.run_start.throughput;
  }
  std::vector<Job> Jobs() const;  // current first, then the queue in order, then finished ones
  Result<Job> GetJob(std::int64_t id) const;  // kNotFound
  // Queued jobs only (kFailedPrecondition otherwise: a running one is aborted instead).
  Result<Job> Cancel(std::int64_t id);
  // Moves a queued job to `position` (0 = next) in the queue.
  Status Move(std::int64_t id, int position);

  // Run control; kFailedPrecondition when the state does not allow it (the message says why).
  Status Pause();
  Status Resume();
  Status Abort();

  StatusReport Report() const;
  EventLog& events() { return events_; }

  // The latest frame: the first averaged frame of the last point measured, or the last Snap.
  const LatestFrame& frames() const { return frames_; }
  // One frame at `exposure_s` (0 < exposure_s <= kMaxSnapS) between runs, for aligning the
  // bench: only when idle with no job in hand (kFailedPrecondition otherwise; a run's frames
  // show by themselves). No job starts until it is done. The shutter is opened first.
  static constexpr double kMaxSnapS = 10;
  Result<std::shared_ptr<const FrameView>> Snap(double exposure_s);

  // Waits until the controller is idle with an empty queue (tests, scripts), up to timeout_s.
  bool WaitIdle(double timeout_s);

 private:
  enum class StopReason { kNone, kPause, kAbort, kSuspend, kShutdown };
  void Worker();
  void RunCurrent(std::unique_lock<std::mutex>& lock);
  bool StartRun(Job& job, const acquisition::Plan& plan, std::unique_lock<std::mutex>& lock);
  bool CoolFirst(Job& job, std::int64_t run, std::unique_lock<std::mutex>& lock);
  void OnMeasureFailed(std::int64_t run, const gonio::Status& s);  // mu_ held
  void OnMeasureReturned(std::int64_t run, std::unique_lock<std::mutex>& lock);
  void OnPoint(const acquisition::Progress& p);       // worker thread, from the engine
  std::optional<std::string> SuspendCondition();      // worker thread; the reason, when tripped
  void SetState(State s, const std::string& reason);  // mu_ held
  void SaveJob(const Job& j);                         // stores and publishes it; mu_ held
  Status LoadJobs(std::optional<bool> resume_interrupted);       // mu_ held, before the worker
  void FinishCurrent(JobState end, const std::string& message);  // mu_ held
  void SafeState();                                              // stages stopped; worker thread
  Status CoolDown(
      const CoolerWait& w);  // worker thread, without mu_; the driver's wait, cancelled by stop_
  void FitAfterRun(const Job& job);  // worker thread, without mu_
  // The engine on `run`, its frames shown and the links watched (WatchLinks); without mu_.
  gonio::Status MeasureWatched(std::int64_t run, const acquisition::Plan& plan);
  // The first device whose link does not answer, as the suspension's reason; without mu_.
  std::optional<std::string> LinkLost();
  // Checks the links every link_check_s until *done; a loss suspends the run (OnLinkLost).
  void WatchLinks(const std::atomic<bool>& done);
  void OnLinkLost(const std::string& why);  // takes mu_

  devices::StageController& stages_;
  devices::Camera& camera_;
  devices::SourceMonitor* monitor_;
  acquisition::Storage& db_;
  JobStore jobs_{db_};
  acquisition::PlanContext context_;
  ControllerOptions o_;
  EventLog events_;
  LatestFrame frames_;

  mutable std::mutex mu_;
  std::condition_variable cv_;
  State state_ = State::kIdle;
  std::string reason_;
  std::deque<Job> queue_;
  std::optional<Job> current_;
  std::vector<Job> finished_;
  std::optional<acquisition::Progress> progress_;
  bool resume_requested_ = false;
  bool camera_lent_ = false;  // a Snap has the camera: no job starts
  bool shutdown_ = false;
  double suspended_since_ = 0;
  // The device fault logged for the outage in hand ("" when none): a retry that fails the same
  // way logs nothing more, and the first point measured after it logs the outage's end.
  std::string fault_logged_;
  StopReason stop_reason_ = StopReason::kNone;
  std::atomic<bool> stop_{false};
  std::atomic<bool> interrupt_{false};  // Shutdown: the point in hand is abandoned (pending)
  bool link_lost_ = false;  // the link watch stopped this attempt (OnLinkLost); mu_ held
  std::thread worker_;
  bool started_ = false;
};

}  // namespace gonio::daemon
