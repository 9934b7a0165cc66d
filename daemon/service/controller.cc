#include "daemon/service/controller.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <thread>

#include "daemon/service/fit_run.h"

namespace gonio::daemon {
namespace {

using acquisition::Progress;

double NowS() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

double UnixNow() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

Error NotNow(const std::string& what) { return Error{ErrorCode::kFailedPrecondition, what}; }

constexpr int kFinishedJobsKept = 100;  // listed after a restart

// A finished run's status as its job's end, and back: the two share done, aborted and failed.
JobState JobEndOf(acquisition::RunStatus finished) {
  switch (finished) {
    case acquisition::RunStatus::kDone:
      return JobState::kDone;
    case acquisition::RunStatus::kAborted:
      return JobState::kAborted;
    default:
      return JobState::kFailed;
  }
}

acquisition::RunStatus RunStatusOf(JobState end) {
  switch (end) {
    case JobState::kDone:
      return acquisition::RunStatus::kDone;
    case JobState::kAborted:
      return acquisition::RunStatus::kAborted;
    default:
      return acquisition::RunStatus::kFailed;
  }
}

// A job as the database keeps it: the schedule's options as JSON beside the plan.
JobRecord ToRecord(const Job& j) {
  JobRecord r;
  r.id = j.id;
  r.name = j.name;
  r.plan_text = j.plan_text;
  r.state = j.state;
  r.run = j.run;
  r.message = j.message;
  nlohmann::json o = nlohmann::json::object();
  if (j.start_at_unix) o["start_at_unix"] = *j.start_at_unix;
  if (j.cooler)
    o["cooler"] = {{"setpoint_c", j.cooler->setpoint_c},
                   {"tolerance_c", j.cooler->tolerance_c},
                   {"hold_s", j.cooler->hold_s},
                   {"timeout_s", j.cooler->timeout_s}};
  if (!j.fit.empty()) o["fit"] = j.fit;
  if (!j.schedule.empty()) o["schedule"] = j.schedule;
  r.options_json = o.dump();
  return r;
}

// The job's fields; its schedule options are read by ReadOptions.
Job FromRecord(const JobRecord& r) {
  Job j;
  j.id = r.id;
  j.name = r.name;
  j.plan_text = r.plan_text;
  j.state = r.state;
  j.run = r.run;
  j.message = r.message;
  return j;
}

Status ReadOptions(const JobRecord& r, Job& j) {
  try {
    const nlohmann::json o = nlohmann::json::parse(r.options_json);
    if (o.contains("start_at_unix")) j.start_at_unix = o.at("start_at_unix").get<std::int64_t>();
    if (o.contains("cooler")) {
      const auto& c = o.at("cooler");
      j.cooler = CoolerWait{c.at("setpoint_c").get<double>(), c.at("tolerance_c").get<double>(),
                            c.at("hold_s").get<double>(), c.at("timeout_s").get<double>()};
    }
    if (o.contains("fit")) j.fit = o.at("fit").get<std::vector<std::string>>();
    if (o.contains("schedule")) j.schedule = o.at("schedule").get<std::string>();
  } catch (const nlohmann::json::exception& e) {
    return Error{ErrorCode::kInvalidArgument,
                 "job " + std::to_string(r.id) + ": stored options unreadable: " + e.what()};
  }
  return OkStatus();
}

}  // namespace

nlohmann::json ToJson(const Job& j) {
  nlohmann::json o{
      {"id", j.id}, {"name", j.name}, {"state", ToString(j.state)}, {"message", j.message}};
  o["run"] = j.run ? nlohmann::json(*j.run) : nlohmann::json(nullptr);
  if (j.start_at_unix) o["start_at_unix"] = *j.start_at_unix;
  if (j.cooler) o["cooler_setpoint_c"] = j.cooler->setpoint_c;
  if (!j.fit.empty()) o["fit"] = j.fit;
  if (!j.schedule.empty()) o["schedule"] = j.schedule;
  return o;
}

nlohmann::json ToJson(const acquisition::Progress& p) {
  return {{"done", p.done},
          {"total", p.total},
          {"theta_l_deg", p.point.theta_l_deg},
          {"theta_v_deg", p.point.theta_v_deg},
          {"phi_deg", p.point.phi_deg},
          {"value", p.last.value},
          {"sigma", p.last.sigma},
          {"exposure_s", p.last.exposure_s},
          {"elapsed_s", p.elapsed_s},
          {"eta_s", p.eta_s}};
}

const char* ToString(State s) {
  switch (s) {
    case State::kIdle:
      return "idle";
    case State::kCooling:
      return "cooling";
    case State::kRunning:
      return "running";
    case State::kPaused:
      return "paused";
    case State::kSuspended:
      return "suspended";
    case State::kAborting:
      return "aborting";
    case State::kFault:
      return "fault";
  }
  return "unknown";
}

Controller::Controller(devices::StageController& stages, devices::Camera& camera,
                       devices::SourceMonitor* monitor, acquisition::Storage& db,
                       acquisition::PlanContext context, ControllerOptions options)
    : stages_(stages),
      camera_(camera),
      monitor_(monitor),
      db_(db),
      context_(std::move(context)),
      o_(std::move(options)) {}

Controller::~Controller() { Shutdown(); }

Status Controller::Start(std::optional<bool> resume_interrupted) {
  std::unique_lock lock(mu_);
  if (started_) return NotNow("the controller is already started");
  if (Status st = LoadJobs(resume_interrupted); !st.ok()) return st;
  // What the camera lacks is said once, here, as a capability; the suspender that needs the
  // sensor's temperature is off without one.
  const devices::CameraCapabilities caps = camera_.Capabilities();
  if (!caps.Missing().empty()) events_.Publish("log", {{"message", "camera: " + caps.Missing()}});
  if (!caps.temperature) o_.suspenders.temperature_setpoint_c.reset();
  started_ = true;
  worker_ = std::thread([this] { Worker(); });
  return OkStatus();
}

Status Controller::LoadJobs(std::optional<bool> resume_interrupted) {
  auto records = jobs_.Jobs(kFinishedJobsKept);
  if (!records.ok()) return records.error();
  std::vector<Job> interrupted;  // jobs that had started (a run) and did not finish
  for (const JobRecord& r : *records) {
    Job j = FromRecord(r);
    if (Status st = ReadOptions(r, j); !st.ok()) {  // a damaged row ends that job, not the start
      j.message = st.error().message;
      if (Unfinished(j.state)) {
        j.state = JobState::kFailed;
        JobRecord failed = r;  // its options stay as found, for whoever looks
        failed.state = j.state;
        failed.message = j.message;
        (void)jobs_.Update(failed);
      }
      finished_.push_back(j);
      continue;
    }
    if (!Unfinished(j.state)) {
      finished_.push_back(j);
    } else if (!j.run) {
      j.state = JobState::kQueued;  // it never started
      queue_.push_back(j);
    } else {
      interrupted.push_back(j);
    }
  }
  // The run decides: a job whose run finished (the daemon died before the job was stored)
  // takes the run's end.
  std::vector<Job> open;
  for (Job& j : interrupted) {
    auto info = db_.GetRun(*j.run);
    if (!info.ok()) return info.error();
    if (acquisition::Finished(info->status)) {
      j.state = JobEndOf(info->status);
      j.message = "its run ended before the daemon stopped";
      SaveJob(j);
      finished_.push_back(j);
    } else {
      open.push_back(j);
    }
  }
  // A run left unfinished by another program (gonio-acquire) or an older daemon has no job.
  auto unfinished = db_.UnfinishedRun();
  if (!unfinished.ok()) return unfinished.error();
  if (*unfinished && std::none_of(open.begin(), open.end(),
                                  [&](const Job& j) { return *j.run == **unfinished; })) {
    auto info = db_.GetRun(**unfinished);
    if (!info.ok()) return info.error();
    Job j;
    j.name = "interrupted run " + std::to_string(info->id);
    j.plan_text = info->plan_text;
    j.run = info->id;
    j.state = JobState::kPaused;
    auto id = jobs_.Insert(ToRecord(j));
    if (!id.ok()) return id.error();
    j.id = *id;
    open.push_back(j);
  }
  for (std::size_t k = 0; k < open.size(); ++k) {
    Job& j = open[k];
    j.state = JobState::kPaused;
    // Only one job runs at a time, so at most one should be open; any other is left paused.
    if (!resume_interrupted || k + 1 < open.size()) {
      j.message = resume_interrupted ? "interrupted; another interrupted job was taken up"
                                     : "interrupted; not taken up (--on-start ignore)";
      SaveJob(j);
      finished_.push_back(j);
      continue;
    }
    current_ = j;
    (void)db_.SetRunStatus(*j.run, acquisition::RunStatus::kPaused);
    (void)db_.AddEvent(*j.run, "daemon", "found interrupted at daemon start");
    SetState(State::kPaused, "interrupted by a daemon stop; found at start");
    SaveJob(*current_);
    if (*resume_interrupted) resume_requested_ = true;
  }
  return OkStatus();
}

void Controller::Shutdown() {
  {
    std::lock_guard lock(mu_);
    if (!started_ || shutdown_) return;
    shutdown_ = true;
    stop_reason_ = StopReason::kShutdown;
    stop_ = true;
    interrupt_ = true;  // a stop within seconds: the exposure in hand is not waited for
    cv_.notify_all();
  }
  if (worker_.joinable()) worker_.join();
  events_.Close();
}

Result<Job> Controller::Submit(const std::string& name, const std::string& plan_text) {
  Job j;
  j.name = name;
  j.plan_text = plan_text;
  return Submit(std::move(j));
}

Result<Job> Controller::Submit(Job j) {
  auto plan = acquisition::LoadPlanText(j.plan_text, j.name.empty() ? "plan" : j.name, context_);
  if (!plan.ok()) return plan.error();
  std::lock_guard lock(mu_);
  if (shutdown_) return NotNow("the daemon is shutting down");
  j.state = JobState::kQueued;
  j.run.reset();
  j.message.clear();
  auto id = jobs_.Insert(ToRecord(j));  // stored before it is accepted: a restart keeps it
  if (!id.ok()) return id.error();
  j.id = *id;
  queue_.push_back(j);
  events_.Publish("job", ToJson(j));
  cv_.notify_all();
  return j;
}

Result<std::vector<Job>> Controller::Submit(const Schedule& schedule) {
  std::vector<Job> out;
  for (const ScheduleEntry& e : schedule.jobs) {
    for (int k = 0; k < e.repeat; ++k) {
      Job j;
      j.name = e.plan_name;
      j.plan_text = e.plan_text;
      j.start_at_unix = e.start_at_unix;
      if (k == 0) j.cooler = e.cooler;
      j.fit = e.fit;
      j.schedule = schedule.name;
      auto queued = Submit(std::move(j));
      if (!queued.ok()) return queued.error();
      out.push_back(*queued);
    }
  }
  return out;
}

std::vector<Job> Controller::Jobs() const {
  std::lock_guard lock(mu_);
  std::vector<Job> out;
  if (current_) out.push_back(*current_);
  out.insert(out.end(), queue_.begin(), queue_.end());
  out.insert(out.end(), finished_.rbegin(), finished_.rend());
  return out;
}

Result<Job> Controller::GetJob(std::int64_t id) const {
  for (const Job& j : Jobs())
    if (j.id == id) return j;
  return Error{ErrorCode::kNotFound, "no job " + std::to_string(id)};
}

Result<Job> Controller::Cancel(std::int64_t id) {
  std::lock_guard lock(mu_);
  for (auto it = queue_.begin(); it != queue_.end(); ++it) {
    if (it->id != id) continue;
    Job j = *it;
    queue_.erase(it);
    j.state = JobState::kCancelled;
    j.message = "cancelled before it started";
    finished_.push_back(j);
    SaveJob(j);
    return j;
  }
  if (current_ && current_->id == id)
    return NotNow("job " + std::to_string(id) + " is " + ToString(current_->state) +
                  ": abort it instead of cancelling");
  for (const Job& j : finished_)
    if (j.id == id) return NotNow("job " + std::to_string(id) + " is already " + ToString(j.state));
  return Error{ErrorCode::kNotFound, "no job " + std::to_string(id)};
}

Status Controller::Move(std::int64_t id, int position) {
  std::lock_guard lock(mu_);
  auto it = std::find_if(queue_.begin(), queue_.end(), [&](const Job& j) { return j.id == id; });
  if (it == queue_.end()) {
    if (current_ && current_->id == id)
      return NotNow("job " + std::to_string(id) + " is not queued");
    return Error{ErrorCode::kNotFound, "no queued job " + std::to_string(id)};
  }
  if (position < 0) return InvalidArgument("position must be >= 0");
  Job j = *it;
  queue_.erase(it);
  const auto at = std::min<std::size_t>(static_cast<std::size_t>(position), queue_.size());
  queue_.insert(queue_.begin() + static_cast<std::ptrdiff_t>(at), j);
  std::vector<std::int64_t> order;
  for (const Job& q : queue_) order.push_back(q.id);
  if (Status st = jobs_.SetQueueOrder(order); !st.ok()) return st;
  events_.Publish("queue", {{"moved", id}, {"position", at}});
  return OkStatus();
}

Result<std::shared_ptr<const FrameView>> Controller::Snap(double exposure_s) {
  if (!(exposure_s > 0 && exposure_s <= kMaxSnapS))
    return Error{ErrorCode::kInvalidArgument, "exposure_s must be above 0 and at most " +
                                                  std::to_string(static_cast<int>(kMaxSnapS)) +
                                                  " s"};
  {
    std::lock_guard lock(mu_);
    if (state_ != State::kIdle || current_)
      return NotNow("the camera is in use (" + std::string(ToString(state_)) +
                    (current_ && current_->run ? ", run " + std::to_string(*current_->run) : "") +
                    "): a run's frames show in the view as they are taken");
    if (camera_lent_) return NotNow("another snap is in progress");
    camera_lent_ = true;
  }
  auto snap = [&]() -> Result<devices::Frame> {
    if (camera_.Capabilities().shutter)
      if (Status s = camera_.SetShutter(true); !s.ok()) return s.error();
    if (Status s = camera_.SetExposure(exposure_s); !s.ok()) return s.error();
    return camera_.Snap();
  };
  auto f = snap();
  std::shared_ptr<const FrameView> kept;
  if (f.ok()) {
    FrameView about;
    about.source = "snap";
    about.exposure_s = exposure_s;
    kept = frames_.Put(f->image, o_.run_start.engine.linear_limit_adu, std::move(about));
  }
  {
    std::lock_guard lock(mu_);
    camera_lent_ = false;
  }
  cv_.notify_all();
  if (!f.ok()) return f.error();
  return kept;
}

Status Controller::Pause() {
  std::lock_guard lock(mu_);
  if (state_ != State::kRunning)
    return NotNow(std::string("nothing to pause: the instrument is ") + ToString(state_));
  stop_reason_ = StopReason::kPause;
  stop_ = true;
  events_.Publish("log", {{"message", "pause requested: after the current point is stored"}});
  return OkStatus();
}

Status Controller::Resume() {
  std::lock_guard lock(mu_);
  if (state_ != State::kPaused && state_ != State::kFault && state_ != State::kSuspended)
    return NotNow(std::string("nothing to resume: the instrument is ") + ToString(state_));
  resume_requested_ = true;
  cv_.notify_all();
  return OkStatus();
}

Status Controller::Abort() {
  std::unique_lock lock(mu_);
  switch (state_) {
    case State::kRunning:
    case State::kCooling:
      stop_reason_ = StopReason::kAbort;
      stop_ = true;
      SetState(State::kAborting,
               "abort requested: the current point finishes, then the stages stop");
      return OkStatus();
    case State::kPaused:
    case State::kSuspended:
    case State::kFault:
      // The worker is not in the engine: end the run here (stages are already still).
      resume_requested_ = false;
      FinishCurrent(JobState::kAborted, "aborted by the operator");
      SetState(State::kIdle, "");
      cv_.notify_all();
      return OkStatus();
    default:
      return NotNow(std::string("nothing to abort: the instrument is ") + ToString(state_));
  }
}

StatusReport Controller::Report() const {
  std::lock_guard lock(mu_);
  StatusReport r;
  r.state = state_;
  r.reason = reason_;
  r.job = current_;
  r.progress = progress_;
  r.queued = static_cast<int>(queue_.size());
  return r;
}

bool Controller::WaitIdle(double timeout_s) {
  std::unique_lock lock(mu_);
  return cv_.wait_for(lock, std::chrono::duration<double>(timeout_s),
                      [&] { return state_ == State::kIdle && queue_.empty() && !current_; });
}

void Controller::SetState(State s, const std::string& reason) {
  state_ = s;
  reason_ = reason;
  events_.Publish("state", {{"state", ToString(s)}, {"reason", reason}});
  cv_.notify_all();
}

void Controller::SaveJob(const Job& j) {
  if (Status st = jobs_.Update(ToRecord(j)); !st.ok())
    events_.Publish(
        "log", {{"level", "error"},
                {"message", "job " + std::to_string(j.id) + " not stored: " + st.error().message}});
  events_.Publish("job", ToJson(j));
}

void Controller::FinishCurrent(JobState end, const std::string& message) {
  if (!current_) return;
  current_->state = end;
  current_->message = message;
  if (current_->run) {
    (void)db_.SetRunStatus(*current_->run, RunStatusOf(end));
    if (!message.empty()) (void)db_.AddEvent(*current_->run, ToString(end), message);
  }
  SaveJob(*current_);
  finished_.push_back(*current_);
  current_.reset();
  progress_.reset();
  // What suspended this job does not carry over to the next (an abort while suspended).
  fault_logged_.clear();
  suspended_since_ = 0;
}

void Controller::SafeState() {
  // Stages still; the shutter closed where there is one (a camera without one says so: fine).
  (void)stages_.StopAll();
  (void)camera_.SetShutter(false);
}

void Controller::Worker() {
  std::unique_lock lock(mu_);
  while (!shutdown_) {
    const double now = UnixNow();
    const bool due =
        !queue_.empty() && (!queue_.front().start_at_unix || *queue_.front().start_at_unix <= now);
    const bool start_next = state_ == State::kIdle && !current_ && due && !camera_lent_;
    const bool resume =
        resume_requested_ && current_ &&
        (state_ == State::kPaused || state_ == State::kFault || state_ == State::kSuspended);
    if (start_next || resume) {
      if (start_next) {
        current_ = queue_.front();
        queue_.pop_front();
      }
      resume_requested_ = false;
      RunCurrent(lock);
      continue;
    }
    if (state_ == State::kSuspended && current_) {
      // Wait a poll interval (a device fault is retried no faster), then check the condition
      // without the lock (it talks to devices).
      cv_.wait_for(lock, std::chrono::duration<double>(o_.suspenders.poll_s),
                   [&] { return shutdown_ || resume_requested_ || state_ != State::kSuspended; });
      if (shutdown_ || resume_requested_ || state_ != State::kSuspended) continue;
      lock.unlock();
      // The links first: a run suspended by a device gone resumes only once every link answers.
      auto why = o_.suspenders.link_check_s > 0 ? LinkLost() : std::nullopt;
      if (!why) why = SuspendCondition();
      lock.lock();
      if (state_ != State::kSuspended || shutdown_) continue;
      if (!why) {
        // A device fault's retry is logged as cleared only once a point is measured (OnPoint).
        if (fault_logged_.empty()) {
          events_.Publish("suspend", {{"cleared", true}, {"run", *current_->run}});
          if (current_->run) (void)db_.AddEvent(*current_->run, "suspend_cleared", reason_);
        }
        resume_requested_ = true;
        continue;
      }
      if (NowS() - suspended_since_ > o_.suspenders.fault_give_up_s) {
        SetState(State::kFault,
                 *why + " (not cleared for " +
                     std::to_string(static_cast<int>(o_.suspenders.fault_give_up_s)) +
                     " s; resume retries, abort ends the run)");
      }
      continue;
    }
    if (camera_lent_ && state_ == State::kIdle && !current_) {
      cv_.wait(lock, [&] { return shutdown_ || !camera_lent_; });  // a Snap has the camera
      continue;
    }
    if (state_ == State::kIdle && !current_ && !queue_.empty()) {
      // The next job has a start time: wait for it (or for a change of the queue).
      const double wait_s =
          std::max(0.05, static_cast<double>(*queue_.front().start_at_unix) - now);
      if (reason_.empty()) {
        reason_ = "job " + std::to_string(queue_.front().id) + " starts in " +
                  std::to_string(static_cast<long>(std::ceil(wait_s))) + " s";
        events_.Publish("state", {{"state", ToString(state_)}, {"reason", reason_}});
      }
      cv_.wait_for(lock, std::chrono::duration<double>(std::min(wait_s, 60.0)));
      reason_.clear();
      continue;
    }
    cv_.wait(lock);
  }
  // Shutdown with a run in hand: it stays paused in the database for the next start.
  if (current_ && current_->run) {
    (void)db_.SetRunStatus(*current_->run, acquisition::RunStatus::kPaused);
    current_->state = JobState::kPaused;
    SaveJob(*current_);
  }
}

void Controller::RunCurrent(std::unique_lock<std::mutex>& lock) {
  Job& job = *current_;
  auto plan =
      acquisition::LoadPlanText(job.plan_text, job.name.empty() ? "plan" : job.name, context_);
  if (!plan.ok()) {  // validated at submit; the context cannot change, but say so if it did
    FinishCurrent(JobState::kFailed, plan.error().message);
    SetState(State::kIdle, "");
    return;
  }
  // A pause or an abort asked for from here on (while the estimate is made) is honoured.
  stop_ = false;
  stop_reason_ = StopReason::kNone;
  if (!shutdown_) interrupt_ = false;  // a link watch's interrupt ended the last attempt
  link_lost_ = false;
  if (!job.run && !StartRun(job, *plan, lock)) return;
  const std::int64_t run = *job.run;
  if (job.cooler && !job.cooled && !CoolFirst(job, run, lock)) return;
  job.state = JobState::kRunning;
  SaveJob(job);
  // A retry after a device fault runs (pause and abort act on it as on any run) and says so.
  SetState(State::kRunning, fault_logged_.empty() ? "" : "retrying after " + fault_logged_);

  lock.unlock();
  const gonio::Status s = MeasureWatched(run, *plan);
  if (!s.ok()) SafeState();
  lock.lock();
  if (!current_) return;  // cannot happen: only the worker finishes a running job
  if (!s.ok()) {
    OnMeasureFailed(run, s);
    return;
  }
  OnMeasureReturned(run, lock);
}

// The engine's run ended with an error: the link watch's suspension, or a device fault the
// drivers' retries did not clear (suspended, or in fault once it lasts). mu_ held.
void Controller::OnMeasureFailed(std::int64_t run, const gonio::Status& s) {
  const StopReason why = stop_reason_;
  if (why == StopReason::kSuspend && !fault_logged_.empty()) {
    // The link watch suspended the run (and logged why) before the engine's own call failed.
    current_->state = JobState::kPaused;
    SaveJob(*current_);
    SetState(State::kSuspended, fault_logged_);
    return;
  }
  // A device fault the drivers' retries did not clear: the engine left the run paused. The
  // worker retries each poll interval; only the outage's first failure (or a new one) is logged.
  const std::string fault = s.error().code == ErrorCode::kDeviceFault
                                ? s.error().ToString()
                                : "device fault: " + s.error().ToString();
  current_->state = JobState::kPaused;
  SaveJob(*current_);
  if (suspended_since_ == 0 || fault != fault_logged_) {
    (void)db_.AddEvent(run, "suspend", fault);
    events_.Publish("suspend", {{"run", run}, {"reason", fault}});
    fault_logged_ = fault;
  }
  if (why == StopReason::kAbort) {
    FinishCurrent(JobState::kAborted, "aborted by the operator (after a device fault)");
    SetState(State::kIdle, "");
    return;
  }
  if (suspended_since_ == 0) suspended_since_ = NowS();
  if (NowS() - suspended_since_ > o_.suspenders.fault_give_up_s) {
    SetState(State::kFault, "not cleared by retries: " + fault);
  } else {
    SetState(State::kSuspended, fault);
  }
}

// The engine's run returned: done (its cost logged, its fit made), or stopped by a request after
// a stored point. mu_ held, released for the fit.
void Controller::OnMeasureReturned(std::int64_t run, std::unique_lock<std::mutex>& lock) {
  const StopReason why = stop_reason_;
  auto info = db_.GetRun(run);
  if (info.ok() && info->status == acquisition::RunStatus::kDone) {
    if (const std::string cost = acquisition::DescribeExposureAgainstEstimate(*info); !cost.empty())
      (void)db_.AddEvent(run, "bench_time", cost);
    if (!current_->fit.empty()) {
      const Job finished = *current_;
      lock.unlock();
      FitAfterRun(finished);
      lock.lock();
    }
    FinishCurrent(JobState::kDone, "");
    SetState(State::kIdle, "");
    return;
  }
  // Stopped by a request, after a stored point.
  current_->state = JobState::kPaused;
  switch (why) {
    case StopReason::kAbort:
      lock.unlock();
      SafeState();
      lock.lock();
      FinishCurrent(JobState::kAborted, "aborted by the operator");
      SetState(State::kIdle, "");
      break;
    case StopReason::kSuspend:
      SaveJob(*current_);
      if (suspended_since_ == 0) suspended_since_ = NowS();
      SetState(State::kSuspended, fault_logged_.empty() ? reason_ : fault_logged_);
      break;
    case StopReason::kShutdown:
      (void)db_.AddEvent(run, "paused", "daemon shutdown");
      SaveJob(*current_);
      break;
    default:
      (void)db_.AddEvent(run, "paused", "paused by the operator");
      SaveJob(*current_);
      SetState(State::kPaused, "paused by the operator");
      break;
  }
}

// The job's run created (acquisition/run_start.h) and its estimate recorded; false when the job
// ended or the worker stops instead. mu_ held, released for the estimate.
bool Controller::StartRun(Job& job, const acquisition::Plan& plan,
                          std::unique_lock<std::mutex>& lock) {
  const auto points = acquisition::ExpandPoints(plan, context_);
  auto run = acquisition::CreateRun(db_, o_.run_start, plan, points);
  if (!run.ok()) {
    FinishCurrent(JobState::kFailed, run.error().message);
    SetState(State::kIdle, "");
    return false;
  }
  job.run = *run;
  SaveJob(job);  // a restart finds the run through its job
  // What it is expected to cost, kept beside what it will cost. An estimate that
  // cannot be made does not stop the run. An adaptive plan's simulates its runs (a second or
  // a few): made without the lock, so that status and the API answer meanwhile, in a state
  // that says a job is in hand (idle here once let `gonioctl wait` return before the run).
  SetState(State::kRunning, "estimating the run's time");
  lock.unlock();
  auto e = acquisition::EstimateNewRun(db_, o_.run_start, plan, points);
  lock.lock();
  if (e.ok()) (void)acquisition::RecordEstimate(db_, *run, *e);
  if (stop_reason_ == StopReason::kShutdown) return false;  // the run stays planned
  if (stop_reason_ == StopReason::kAbort) {
    FinishCurrent(JobState::kAborted, "aborted by the operator before its first point");
    SetState(State::kIdle, "");
    return false;
  }
  return true;
}

// The CCD cooled to the job's setpoint and held, once per process (a pause does not wait again,
// a restart does); false when the job ended or the worker stops instead. mu_ held, released for
// the wait.
bool Controller::CoolFirst(Job& job, std::int64_t run, std::unique_lock<std::mutex>& lock) {
  const CoolerWait w = *job.cooler;
  job.cooled = true;  // once per process: a pause does not wait again, a restart does
  SetState(State::kCooling, "cooling to " + std::to_string(w.setpoint_c) + " C");
  lock.unlock();
  const gonio::Status cooled = CoolDown(w);
  lock.lock();
  if (!cooled.ok()) {
    const bool aborted = stop_reason_ == StopReason::kAbort;
    const bool stopping = stop_reason_ == StopReason::kShutdown;
    if (stopping) return false;  // the run stays planned; the worker exits
    FinishCurrent(aborted ? JobState::kAborted : JobState::kFailed,
                  aborted ? "aborted while cooling" : cooled.error().message);
    SetState(State::kIdle, "");
    return false;
  }
  (void)acquisition::RecordCooled(db_, run, w.setpoint_c);
  return true;
}

// The engine on the run, with its frames shown and the devices' links watched beside it; without
// mu_, on the worker thread.
gonio::Status Controller::MeasureWatched(std::int64_t run, const acquisition::Plan& plan) {
  acquisition::Engine engine(stages_, camera_, monitor_, db_, o_.run_start.engine);
  engine.InterruptOn(&interrupt_);
  const std::optional<acquisition::Rectangle> rectangle = plan.rectangle;
  engine.ShowFramesTo(
      [this, run, rectangle](const cv::Mat1w& image, const acquisition::PlannedPoint& p, double t) {
        FrameView about;
        about.source = "run";
        about.run = run;
        about.point = p.index;
        about.exposure_s = t;
        about.rectangle = rectangle;
        frames_.Put(image, o_.run_start.engine.linear_limit_adu, std::move(about));
      });
  std::atomic<bool> engine_done{false};
  std::thread watch;
  if (o_.suspenders.link_check_s > 0) watch = std::thread([&] { WatchLinks(engine_done); });
  const gonio::Status s = engine.Run(run, plan, stop_, [this](const Progress& p) { OnPoint(p); });
  engine_done = true;
  if (watch.joinable()) watch.join();
  return s;
}

void Controller::OnPoint(const Progress& p) {
  const auto why = SuspendCondition();  // worker thread: devices are ours between points
  std::lock_guard lock(mu_);
  progress_ = p;
  if (link_lost_) {
    // The point whose frames were all in before the device went (the engine stores it as it
    // stops): the outage goes on, and its end is logged at the first point after the resume.
    nlohmann::json event = ToJson(p);
    event["run"] = current_ && current_->run ? *current_->run : 0;
    events_.Publish("progress", event);
    return;
  }
  if (!fault_logged_.empty() && current_ && current_->run) {
    const double gap = suspended_since_ > 0 ? NowS() - suspended_since_ : 0;
    const std::string what = "measuring again after " +
                             std::to_string(static_cast<int>(std::lround(gap))) + " s (" +
                             std::to_string(p.done) + " of " + std::to_string(p.total) +
                             " points done); it was " + fault_logged_;
    (void)db_.AddEvent(*current_->run, "suspend_cleared", what);
    events_.Publish("suspend", {{"cleared", true}, {"run", *current_->run}});
  }
  fault_logged_.clear();
  suspended_since_ = 0;  // a point was measured: whatever suspended the run has cleared
  nlohmann::json event = ToJson(p);
  event["run"] = current_ && current_->run ? *current_->run : 0;
  events_.Publish("progress", event);
  if (why && stop_reason_ == StopReason::kNone) {
    stop_reason_ = StopReason::kSuspend;
    stop_ = true;
    reason_ = *why;
    if (current_ && current_->run) (void)db_.AddEvent(*current_->run, "suspend", *why);
    events_.Publish("suspend", {{"reason", *why}});
  }
}

Status Controller::CoolDown(const CoolerWait& w) {
  if (!camera_.Capabilities().cooler) return OkStatus();  // said once at Start; nothing to wait for
  devices::TemperatureWait t;
  t.setpoint_c = w.setpoint_c;
  t.tolerance_c = w.tolerance_c;
  t.hold_s = w.hold_s;
  t.timeout_s = w.timeout_s;
  t.poll_s = 0.1;
  t.cancel = &stop_;  // abort and shutdown end the wait
  return camera_.CoolAndWait(t);
}

void Controller::FitAfterRun(const Job& job) {
  auto fits = FitRun(db_, *job.run, job.fit, FitProgressEvents(events_, *job.run));
  if (!fits.ok()) {
    (void)db_.AddEvent(*job.run, "fit_failed", fits.error().message);
    events_.Publish("fit", {{"run", *job.run}, {"error", fits.error().message}});
    return;
  }
  for (const RunFit& f : *fits) {
    events_.Publish("fit", {{"run", *job.run},
                            {"model", f.model},
                            {"status", fitting::ToString(f.summary.status)},
                            {"width", f.summary.width.value},
                            {"width_sigma", f.summary.width.sigma},
                            {"reduced_chi2", f.summary.reduced_chi2},
                            {"samples", f.samples}});
  }
}

std::optional<std::string> Controller::LinkLost() {
  if (Status s = stages_.CheckLink(); !s.ok())
    return "device fault: the stage controller does not answer: " + s.error().message;
  if (Status s = camera_.CheckLink(); !s.ok())
    return "device fault: the camera does not answer its control channel: " + s.error().message;
  if (monitor_ != nullptr)
    if (Status s = monitor_->CheckLink(); !s.ok())
      return "device fault: the source monitor does not answer: " + s.error().message;
  return std::nullopt;
}

void Controller::WatchLinks(const std::atomic<bool>& done) {
  const auto period = std::chrono::duration<double>(o_.suspenders.link_check_s);
  auto next = std::chrono::steady_clock::now() + period;
  while (!done) {
    // Slices of 20 ms: the engine's end is seen at once, not a period later.
    if (std::chrono::steady_clock::now() < next) {
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
      continue;
    }
    next += std::chrono::duration_cast<std::chrono::steady_clock::duration>(period);
    if (auto lost = LinkLost(); lost && !done) {
      OnLinkLost(*lost);
      return;  // the run stops; the worker's suspended loop checks the links from here
    }
  }
}

void Controller::OnLinkLost(const std::string& why) {
  std::lock_guard lock(mu_);
  if (!current_ || stop_reason_ != StopReason::kNone) return;  // a stop is under way already
  stop_reason_ = StopReason::kSuspend;
  stop_ = true;
  interrupt_ = true;  // the exposure in hand is abandoned (its point stays pending)
  link_lost_ = true;
  reason_ = why;
  fault_logged_ = why;  // the first point measured after it logs the outage's end
  suspended_since_ = NowS();
  if (current_->run) (void)db_.AddEvent(*current_->run, "suspend", why);
  events_.Publish("suspend", {{"run", current_->run ? *current_->run : 0}, {"reason", why}});
  SetState(State::kSuspended, why);  // seen now, not once the engine has let go of the point
}

std::optional<std::string> Controller::SuspendCondition() {
  const Suspenders& s = o_.suspenders;
  if (s.temperature_setpoint_c) {
    auto t = camera_.TemperatureC();
    if (!t.ok()) return "sensor temperature unreadable: " + t.error().message;
    if (std::abs(*t - *s.temperature_setpoint_c) > s.temperature_band_c)
      return "sensor temperature " + std::to_string(*t) + " C is outside " +
             std::to_string(*s.temperature_setpoint_c) + " +- " +
             std::to_string(s.temperature_band_c) + " C";
  }
  if (s.monitor_floor_w && monitor_ != nullptr) {
    auto w = monitor_->PowerW();
    if (!w.ok()) return "source monitor unreadable: " + w.error().message;
    if (*w < *s.monitor_floor_w)
      return "source monitor reads " + std::to_string(*w) + " W, below its floor of " +
             std::to_string(*s.monitor_floor_w) + " W";
  }
  return std::nullopt;
}

}  // namespace gonio::daemon
