#include "sim/stage/axis.h"

#include <cmath>

namespace gonio::sim {

using namespace stage_reg;

SimulatedAxis::SimulatedAxis(const Clock& clock, AxisOptions options)
    : clock_(clock), o_(options), move_(clock.Now(), 0, 0, 1, 1, 1) {
  Refresh();
}

bool SimulatedAxis::Moving() const {
  std::lock_guard lock(mu_);
  return clock_.Now() < move_.EndTime();
}

double SimulatedAxis::PositionSteps() const {
  std::lock_guard lock(mu_);
  return move_.PositionAt(clock_.Now());
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
  for (int k = 0; k < count; ++k) regs_[address + k] = values[k];
  auto touched = [&](std::uint16_t reg) { return address <= reg + 1 && reg < address + count; };
  if (touched(kAlarmReset) && Get32(kAlarmReset) == 1) {
    alarm_ = 0;
    Set32(kAlarmReset, 0);
  }
  if (touched(kInputCommand)) {
    const std::uint32_t in = Get32(kInputCommand);
    if (in & kInAlarmReset) alarm_ = 0;
    if (in & kInStop) Stop();
    if (in & kInHome) Home();
    if (in & kInStart) StartDirectData();
    Set32(kInputCommand, 0);  // commands act on the write (edge), as pulses
  }
  if (touched(kTrigger) && Get32(kTrigger) == 1) {
    StartDirectData();
    Set32(kTrigger, 0);
  }
  Refresh();
}

void SimulatedAxis::Alarm(std::uint32_t code) {
  alarm_ = code;
  Stop();
}

void SimulatedAxis::Stop() {
  move_ = move_.StoppedAt(clock_.Now());
  homing_ = false;
}

void SimulatedAxis::Home() {
  if (alarm_ || clock_.Now() < move_.EndTime())
    return;  // not READY: ignored, as the real driver does
  const double now = clock_.Now();
  move_ = TrapezoidalMove(now, move_.PositionAt(now), 0, o_.home_speed, o_.home_acceleration,
                          o_.home_acceleration);
  homing_ = true;
}

void SimulatedAxis::StartDirectData() {
  if (alarm_ || clock_.Now() < move_.EndTime()) return;  // not READY: ignored
  const double now = clock_.Now();
  const double here = move_.PositionAt(now);
  const std::uint32_t type = Get32(kOperationType);
  const auto pos = static_cast<std::int32_t>(Get32(kPosition));
  const double speed = Get32(kSpeed), acc = Get32(kAcceleration), dec = Get32(kDeceleration);
  if ((type != 1 && type != 2) || speed <= 0 || acc <= 0 || dec <= 0) return Alarm(kAlarmBadData);
  const double target = type == 1 ? pos : std::round(here) + pos;
  if (target < o_.min_steps || target > o_.max_steps) return Alarm(kAlarmSoftwareOvertravel);
  move_ = TrapezoidalMove(now, here, target, speed, acc, dec);
}

void SimulatedAxis::Refresh() {
  const double now = clock_.Now();
  const bool moving = now < move_.EndTime();
  const bool settled = now >= move_.EndTime() + o_.settle_s;
  if (homing_ && !moving) {
    homing_ = false;
    homed_ = true;
  }
  const double pos = move_.PositionAt(now);
  std::uint32_t out = 0;
  if (homed_ && !moving && std::abs(pos) < 0.5) out |= kOutHomeEnd;
  if (!alarm_ && !moving) out |= kOutReady;
  if (alarm_) out |= kOutAlarm;
  if (moving) out |= kOutBusy | kOutMove;
  if (settled && !alarm_) out |= kOutInPos;
  Set32(kOutputStatus, out);
  Set32(kPresentAlarm, alarm_);
  Set32(kCommandPosition, static_cast<std::uint32_t>(static_cast<std::int32_t>(std::lround(pos))));
}

}  // namespace gonio::sim
