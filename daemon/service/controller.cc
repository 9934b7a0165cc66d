#include "daemon/service/controller.h"

#include <algorithm>
#include <chrono>

namespace gonio::daemon {
namespace {

using acquisition::Progress;

double NowS() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

nlohmann::json JobJson(const Job& j) {
  nlohmann::json o{{"id", j.id}, {"name", j.name}, {"state", j.state}, {"message", j.message}};
  o["run"] = j.run ? nlohmann::json(*j.run) : nlohmann::json(nullptr);
  return o;
}

Error NotNow(const std::string& what) { return Error{ErrorCode::kFailedPrecondition, what}; }

}  // namespace

const char* ToString(State s) {
  switch (s) {
    case State::kIdle:
      return "idle";
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

Controller::Controller(drivers::StageController& stages, drivers::Camera& camera,
                       drivers::SourceMonitor* monitor, acquisition::Storage& db,
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
  if (resume_interrupted) {
    auto unfinished = db_.UnfinishedRun();
    if (!unfinished.ok()) return unfinished.error();
    if (*unfinished) {
      auto info = db_.GetRun(**unfinished);
      if (!info.ok()) return info.error();
      Job j;
      j.id = next_job_id_++;
      j.name = "interrupted run " + std::to_string(info->id);
      j.plan_text = info->plan_text;
      j.run = info->id;
      j.state = "paused";
      current_ = j;
      (void)db_.SetRunStatus(info->id, "paused");
      (void)db_.AddEvent(info->id, "daemon", "found interrupted at daemon start");
      SetState(State::kPaused, "interrupted by a daemon stop; found at start");
      PublishJob(*current_);
      if (*resume_interrupted) resume_requested_ = true;
    }
  }
  started_ = true;
  worker_ = std::thread([this] { Worker(); });
  return OkStatus();
}

void Controller::Shutdown() {
  {
    std::lock_guard lock(mu_);
    if (!started_ || shutdown_) return;
    shutdown_ = true;
    stop_reason_ = StopReason::kShutdown;
    stop_ = true;
    cv_.notify_all();
  }
  if (worker_.joinable()) worker_.join();
  events_.Close();
}

Result<Job> Controller::Submit(const std::string& name, const std::string& plan_text) {
  auto plan = acquisition::LoadPlanText(plan_text, name.empty() ? "plan" : name, context_);
  if (!plan.ok()) return plan.error();
  std::lock_guard lock(mu_);
  if (shutdown_) return NotNow("the daemon is shutting down");
  Job j;
  j.id = next_job_id_++;
  j.name = name;
  j.plan_text = plan_text;
  j.state = "queued";
  queue_.push_back(j);
  PublishJob(j);
  cv_.notify_all();
  return j;
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
    j.state = "cancelled";
    j.message = "cancelled before it started";
    finished_.push_back(j);
    PublishJob(j);
    return j;
  }
  if (current_ && current_->id == id)
    return NotNow("job " + std::to_string(id) + " is " + current_->state +
                  ": abort it instead of cancelling");
  for (const Job& j : finished_)
    if (j.id == id) return NotNow("job " + std::to_string(id) + " is already " + j.state);
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
  events_.Publish("queue", {{"moved", id}, {"position", at}});
  return OkStatus();
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
      FinishCurrent("aborted", "aborted by the operator");
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

void Controller::PublishJob(const Job& j) { events_.Publish("job", JobJson(j)); }

void Controller::FinishCurrent(const std::string& state, const std::string& message) {
  if (!current_) return;
  current_->state = state;
  current_->message = message;
  if (current_->run) {
    (void)db_.SetRunStatus(*current_->run, state == "done" ? "done" : state);
    if (!message.empty()) (void)db_.AddEvent(*current_->run, state, message);
  }
  PublishJob(*current_);
  finished_.push_back(*current_);
  current_.reset();
  progress_.reset();
}

void Controller::SafeState() {
  // Stages still; the shutter closed where there is one (a camera without one says so: fine).
  (void)stages_.StopAll();
  (void)camera_.SetShutter(false);
}

void Controller::Worker() {
  std::unique_lock lock(mu_);
  while (!shutdown_) {
    const bool start_next = state_ == State::kIdle && !current_ && !queue_.empty();
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
      const auto why = SuspendCondition();
      lock.lock();
      if (state_ != State::kSuspended || shutdown_) continue;
      if (!why) {
        events_.Publish("suspend", {{"cleared", true}, {"run", *current_->run}});
        if (current_->run) (void)db_.AddEvent(*current_->run, "suspend_cleared", reason_);
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
    cv_.wait(lock);
  }
  // Shutdown with a run in hand: it stays paused in the database for the next start.
  if (current_ && current_->run) (void)db_.SetRunStatus(*current_->run, "paused");
}

void Controller::RunCurrent(std::unique_lock<std::mutex>& lock) {
  Job& job = *current_;
  auto plan =
      acquisition::LoadPlanText(job.plan_text, job.name.empty() ? "plan" : job.name, context_);
  if (!plan.ok()) {  // validated at submit; the context cannot change, but say so if it did
    FinishCurrent("failed", plan.error().message);
    SetState(State::kIdle, "");
    return;
  }
  if (!job.run) {
    auto spec = db_.EnsureSpecimen(plan->specimen);
    auto cfg = spec.ok() ? db_.StoreConfig(o_.config_text) : Result<std::int64_t>(spec.error());
    auto run = cfg.ok() ? db_.CreateRun(*spec, *cfg, plan->text,
                                        acquisition::ExpandPoints(*plan, context_))
                        : Result<std::int64_t>(cfg.error());
    if (!run.ok()) {
      FinishCurrent("failed", run.error().message);
      SetState(State::kIdle, "");
      return;
    }
    job.run = *run;
  }
  const std::int64_t run = *job.run;
  job.state = "running";
  PublishJob(job);
  stop_ = false;
  stop_reason_ = StopReason::kNone;
  SetState(State::kRunning, "");

  lock.unlock();
  acquisition::Engine engine(stages_, camera_, monitor_, db_, o_.engine);
  const gonio::Status s = engine.Run(run, *plan, stop_, [this](const Progress& p) { OnPoint(p); });
  if (!s.ok()) SafeState();
  lock.lock();

  if (!current_) return;  // cannot happen: only the worker finishes a running job
  const StopReason why = stop_reason_;
  if (!s.ok()) {
    // A device fault the drivers' retries did not clear: the engine left the run paused.
    (void)db_.AddEvent(run, "suspend", "device fault: " + s.error().message);
    current_->state = "paused";
    PublishJob(*current_);
    if (why == StopReason::kAbort) {
      FinishCurrent("aborted", "aborted by the operator (after a device fault)");
      SetState(State::kIdle, "");
      return;
    }
    if (suspended_since_ == 0) suspended_since_ = NowS();
    events_.Publish("suspend", {{"run", run}, {"reason", s.error().ToString()}});
    if (NowS() - suspended_since_ > o_.suspenders.fault_give_up_s) {
      SetState(State::kFault, "device fault not cleared by retries: " + s.error().ToString());
    } else {
      SetState(State::kSuspended, "device fault: " + s.error().ToString());
    }
    return;
  }
  auto info = db_.GetRun(run);
  if (info.ok() && info->status == "done") {
    FinishCurrent("done", "");
    SetState(State::kIdle, "");
    return;
  }
  // Stopped by a request, after a stored point.
  current_->state = "paused";
  switch (why) {
    case StopReason::kAbort:
      lock.unlock();
      SafeState();
      lock.lock();
      FinishCurrent("aborted", "aborted by the operator");
      SetState(State::kIdle, "");
      break;
    case StopReason::kSuspend:
      PublishJob(*current_);
      if (suspended_since_ == 0) suspended_since_ = NowS();
      SetState(State::kSuspended, reason_);
      break;
    case StopReason::kShutdown:
      (void)db_.AddEvent(run, "paused", "daemon shutdown");
      PublishJob(*current_);
      break;
    default:
      (void)db_.AddEvent(run, "paused", "paused by the operator");
      PublishJob(*current_);
      SetState(State::kPaused, "paused by the operator");
      break;
  }
}

void Controller::OnPoint(const Progress& p) {
  const auto why = SuspendCondition();  // worker thread: devices are ours between points
  std::lock_guard lock(mu_);
  progress_ = p;
  suspended_since_ = 0;  // a point was measured: whatever suspended the run has cleared
  events_.Publish("progress", {{"run", current_ && current_->run ? *current_->run : 0},
                               {"done", p.done},
                               {"total", p.total},
                               {"theta_l_deg", p.point.theta_l_deg},
                               {"theta_v_deg", p.point.theta_v_deg},
                               {"value", p.last.value},
                               {"sigma", p.last.sigma},
                               {"exposure_s", p.last.exposure_s},
                               {"eta_s", p.eta_s}});
  if (why && stop_reason_ == StopReason::kNone) {
    stop_reason_ = StopReason::kSuspend;
    stop_ = true;
    reason_ = *why;
    if (current_ && current_->run) (void)db_.AddEvent(*current_->run, "suspend", *why);
    events_.Publish("suspend", {{"reason", *why}});
  }
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
