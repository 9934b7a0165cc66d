#include "sim/stage/axis.h"

#include <algorithm>
#include <cmath>

namespace gonio::sim {

using namespace stage_reg;

SimulatedAxis::SimulatedAxis(const Clock& clock, AxisOptions options, std::string name,
                             FaultPlan* faults)
    : clock_(clock),
      o_(options),
      name_(std::move(name)),
      faults_(faults),
      move_(clock.Now(), 0, 0, 1, 1, 1),
      settle_rng_(options.settle_seed) {
  Refresh();
}

double SimulatedAxis::MotorAt(double t) const {
  if (hard_stop_ && t >= hard_stop_->time) return hard_stop_->position;
  if (silent_stall_ && t >= silent_stall_->time) return silent_stall_->position;
  return move_.PositionAt(t);
}

double SimulatedAxis::CommandAt(double t) const {
  if (hard_stop_ && t >= hard_stop_->time) return hard_stop_->position;
  return move_.PositionAt(t);
}

bool SimulatedAxis::ReadyAt(double t) const {
  if (alarm_ || MovingAt(t) || t < not_ready_until_) return false;
  if (o_.latched_inputs && (inputs_ & kInStop)) return false;  // STOP held on
  return t >= move_.EndTime() + o_.ready_delay_s;              // settled after the last profile
}

int SimulatedAxis::IgnoredOperations() const {
  std::lock_guard lock(mu_);
  return ignored_;
}

bool SimulatedAxis::MovingAt(double t) const {
  if (hard_stop_ && t >= hard_stop_->time) return false;
  return t < move_.EndTime();
}

double SimulatedAxis::LoadAt(double t) const {
  // A dead band of width b: within one monotone move the load is the anchor dragged by the
  // nearer edge of [motor - b/2, motor + b/2].
  const double m = MotorAt(t), half = 0.5 * o_.backlash_steps;
  return std::clamp(load_anchor_, m - half, m + half);
}

bool SimulatedAxis::Moving() const {
  std::lock_guard lock(mu_);
  return MovingAt(clock_.Now());
}

double SimulatedAxis::PositionSteps() const {
  std::lock_guard lock(mu_);
  return LoadAt(clock_.Now()) + settle_offset_;
}

double SimulatedAxis::MotorSteps() const {
  std::lock_guard lock(mu_);
  return MotorAt(clock_.Now());
}

std::uint16_t SimulatedAxis::Read(std::uint16_t address) {
  std::lock_guard lock(mu_);
  Refresh();
  return regs_[address];
}

void SimulatedAxis::Snapshot(std::uint16_t (&out)[kCount]) {
  std::lock_guard lock(mu_);
  Refresh();
  for (std::uint16_t a = 0; a < kCount; ++a) out[a] = regs_[a];
}

void SimulatedAxis::Write(std::uint16_t address, const std::uint16_t* values, int count) {
  std::lock_guard lock(mu_);
  Refresh();  // a hard stop that is due becomes an alarm before the write acts
  for (int k = 0; k < count; ++k) regs_[address + k] = values[k];
  auto touched = [&](std::uint16_t reg) { return address <= reg + 1 && reg < address + count; };
  const double now = clock_.Now();
  if (touched(kAlarmReset)) {
    const std::uint32_t v = Get32(kAlarmReset);
    // Latched: the reset acts on 0 -> 1 and the register keeps what was written.
    if (v == 1 && (!o_.latched_inputs || !alarm_reset_held_)) ResetAlarm(now);
    alarm_reset_held_ = v == 1;
    if (!o_.latched_inputs) Set32(kAlarmReset, 0);
  }
  if (touched(kInputCommand)) {
    const std::uint32_t in = Get32(kInputCommand);
    // Pulsed: every bit written acts. Latched: only bits that went from off to on act, and the
    // register keeps its value (a STOP left on blocks operations until cleared).
    const std::uint32_t act = o_.latched_inputs ? in & ~inputs_ : in;
    inputs_ = o_.latched_inputs ? in : 0;
    if (act & kInAlarmReset) ResetAlarm(now);
    if (act & kInStop) Stop();
    if (act & kInHome) Home();
    if (act & kInStart) StartDirectData();
    if (!o_.latched_inputs) Set32(kInputCommand, 0);
  }
  if (touched(kTrigger) && Get32(kTrigger) == 1) {
    StartDirectData();
    Set32(kTrigger, 0);
  }
  Refresh();
}

void SimulatedAxis::NewMove(double now, const TrapezoidalMove& move) {
  load_anchor_ = LoadAt(now);
  // A move to where the motor already is leaves the stage where it was.
  if (o_.settle_error_steps > 0 && move.target() != MotorAt(now))
    settle_offset_ = std::uniform_real_distribution<double>(-o_.settle_error_steps,
                                                            o_.settle_error_steps)(settle_rng_);
  move_ = move;  // built from where the motor is (MotorAt), a silent stall included
  hard_stop_.reset();
  silent_stall_.reset();
}

void SimulatedAxis::ResetAlarm(double now) {
  if (alarm_ == 0) return;
  alarm_ = 0;
  not_ready_until_ = now + o_.ready_delay_s;
}

void SimulatedAxis::Alarm(std::uint32_t code) {
  alarm_ = code;
  Stop();
}

void SimulatedAxis::Stop() {
  const double now = clock_.Now();
  NewMove(now, MovingAt(now) ? move_.StoppedAt(now)
                             : TrapezoidalMove(now, MotorAt(now), MotorAt(now), 1, 1, 1));
  homing_ = false;
}

void SimulatedAxis::Home() {
  const double now = clock_.Now();
  if (!ReadyAt(now)) {  // not READY: ignored, as the real driver does
    ++ignored_;
    return;
  }
  NewMove(now, TrapezoidalMove(now, MotorAt(now), 0, o_.home_speed, o_.home_acceleration,
                               o_.home_acceleration));
  homing_ = true;
}

void SimulatedAxis::StartDirectData() {
  const double now = clock_.Now();
  if (!ReadyAt(now)) {  // not READY: ignored
    ++ignored_;
    return;
  }
  const double here = MotorAt(now);
  const std::uint32_t type = Get32(kOperationType);
  const auto pos = static_cast<std::int32_t>(Get32(kPosition));
  const double speed = Get32(kSpeed), acc = Get32(kAcceleration), dec = Get32(kDeceleration);
  if ((type != 1 && type != 2) || speed <= 0 || acc <= 0 || dec <= 0) return Alarm(kAlarmBadData);
  const double target = type == 1 ? pos : std::round(here) + pos;
  if (target < o_.min_steps || target > o_.max_steps) return Alarm(kAlarmSoftwareOvertravel);
  const TrapezoidalMove move(now, here, target, speed, acc, dec);
  NewMove(now, move);
  // A limit switch on the path: the motor stops dead where it presses it. The profile is
  // monotone, so the crossing time is found by bisection.
  if (o_.limit_switches && (target > o_.limit_max_steps || target < o_.limit_min_steps)) {
    const double edge = target > o_.limit_max_steps ? o_.limit_max_steps : o_.limit_min_steps;
    const double sign = target > here ? 1 : -1;
    double lo = now, hi = move.EndTime();
    for (int i = 0; i < 60; ++i) {
      const double mid = 0.5 * (lo + hi);
      (sign * (move.PositionAt(mid) - edge) < 0 ? lo : hi) = mid;
    }
    hard_stop_ = HardStop{hi, edge, kAlarmHardwareOvertravel};
  }
  // The fault plan's stall: the motor stops half way through the profile, and the controller
  // notices the position deviation then (AZ alarm 0x10).
  if (MaybeFire(faults_, FaultKind::kAxisStall, name_, now) && target != here) {
    const double t = now + 0.5 * (move.EndTime() - now);
    if (!o_.stall_alarm)
      silent_stall_ = HardStop{t, move.PositionAt(t), 0};
    else if (!hard_stop_ || t < hard_stop_->time)
      hard_stop_ = HardStop{t, move.PositionAt(t), kAlarmPositionDeviation};
  }
}

void SimulatedAxis::Refresh() {
  const double now = clock_.Now();
  if (hard_stop_ && now >= hard_stop_->time) {  // the stop happened: rest there, in alarm
    const HardStop hs = *hard_stop_;
    NewMove(hs.time, TrapezoidalMove(hs.time, hs.position, hs.position, 1, 1, 1));
    alarm_ = hs.alarm;
    homing_ = false;
  }
  if (auto e = MaybeFire(faults_, FaultKind::kAxisAlarm, name_, now)) {
    alarm_ = e->code ? e->code : kAlarmOverload;
    Stop();
  }
  const bool moving = MovingAt(now);
  const bool settled = now >= move_.EndTime() + o_.settle_s;
  if (homing_ && !moving) {
    homing_ = false;
    homed_ = true;
  }
  const double pos = MotorAt(now), commanded = CommandAt(now);
  std::uint32_t out = 0;
  if (homed_ && !moving && std::abs(commanded) < 0.5) out |= kOutHomeEnd;
  if (ReadyAt(now)) out |= kOutReady;
  if (alarm_) out |= kOutAlarm;
  if (moving) out |= kOutBusy | kOutMove;
  if (settled && !alarm_) out |= kOutInPos;
  if (o_.limit_switches && pos >= o_.limit_max_steps) out |= kOutLimitPlus;
  if (o_.limit_switches && pos <= o_.limit_min_steps) out |= kOutLimitMinus;
  Set32(kOutputStatus, out);
  Set32(kPresentAlarm, alarm_);
  Set32(kCommandPosition,
        static_cast<std::uint32_t>(static_cast<std::int32_t>(std::lround(commanded))));
  Set32(kFeedbackPosition, static_cast<std::uint32_t>(static_cast<std::int32_t>(std::lround(pos))));
}

}  // namespace gonio::sim
