#include "sim/faults/fault_plan.h"

#include <array>
#include <utility>

namespace gonio::sim {

namespace {
constexpr std::array<std::pair<FaultKind, std::string_view>, 12> kNames{{
    {FaultKind::kModbusTimeout, "modbus_timeout"},
    {FaultKind::kModbusCrc, "modbus_crc"},
    {FaultKind::kModbusDrop, "modbus_drop"},
    {FaultKind::kAxisAlarm, "axis_alarm"},
    {FaultKind::kAxisStall, "axis_stall"},
    {FaultKind::kFrameDrop, "frame_drop"},
    {FaultKind::kFrameIncomplete, "frame_incomplete"},
    {FaultKind::kCoolerFail, "cooler_fail"},
    {FaultKind::kMonitorDisconnect, "monitor_disconnect"},
    {FaultKind::kControlLost, "control_lost"},
    {FaultKind::kFrameLate, "frame_late"},
    {FaultKind::kLatchSlow, "latch_slow"},
}};
}  // namespace

std::string_view ToString(FaultKind kind) {
  for (const auto& [k, name] : kNames)
    if (k == kind) return name;
  return "unknown";
}

std::optional<FaultKind> FaultKindFromString(std::string_view name) {
  for (const auto& [k, n] : kNames)
    if (n == name) return k;
  return std::nullopt;
}

FaultPlan::FaultPlan(std::vector<FaultEvent> events, std::uint64_t seed) {
  for (std::size_t i = 0; i < events.size(); ++i) {
    // One stream per event: (seed, index) through seed_seq decorrelates neighbouring seeds.
    std::seed_seq seq{static_cast<std::uint32_t>(seed), static_cast<std::uint32_t>(seed >> 32),
                      static_cast<std::uint32_t>(i)};
    events_.push_back(State{std::move(events[i]), std::mt19937_64(seq)});
  }
}

std::optional<FaultEvent> FaultPlan::Fire(FaultKind kind, std::string_view target, double now) {
  std::lock_guard lock(mu_);
  for (std::size_t i = 0; i < events_.size(); ++i) {
    State& s = events_[i];
    const FaultEvent& e = s.event;
    if (e.kind != kind || (!e.target.empty() && !target.empty() && e.target != target)) continue;
    ++s.opportunities;
    if (s.fired >= e.count) continue;
    bool fire = false;
    if (e.at_opportunity > 0) {
      fire = s.opportunities >= e.at_opportunity;
    } else if (e.at_time_s >= 0) {
      fire = now >= e.at_time_s;
    } else if (e.probability > 0) {
      fire = std::uniform_real_distribution<double>(0, 1)(s.rng) < e.probability;
    }
    if (!fire) continue;
    ++s.fired;
    fired_.push_back(FiredFault{kind, std::string(target), now, i});
    return e;
  }
  return std::nullopt;
}

std::vector<FiredFault> FaultPlan::Fired() const {
  std::lock_guard lock(mu_);
  return fired_;
}

}  // namespace gonio::sim
