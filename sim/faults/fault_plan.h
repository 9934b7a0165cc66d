// The fault plan: which device faults to inject, when, and how often - from gonio-sim's
// config ([[faults.event]], config/sim.toml) or from a test. Each device asks the plan at each of
// its opportunities (a Modbus request, a move, a frame, a monitor query, a firmware tick) whether
// a fault fires now, and then shows it at the protocol level as real hardware would: a Modbus
// request without a reply, a reply with a bad CRC, a closed TCP connection, a controller alarm, a
// stalled motor, a frame that never arrives or arrives with packets missing, a cooler that stops,
// a meter that leaves the bus.
//
// Deterministic under a seed: each event draws from its own generator (seed, event index), so one
// event's draws do not depend on how often other devices asked.
#pragma once

#include <cstdint>
#include <mutex>
#include <optional>
#include <random>
#include <string>
#include <string_view>
#include <vector>

namespace gonio::sim {

enum class FaultKind {
  kModbusTimeout,      // the controller does not answer one request
  kModbusCrc,          // RTU: the reply's CRC is wrong
  kModbusDrop,         // TCP: the controller closes the connection
  kAxisAlarm,          // the axis raises alarm `code` (and stops)
  kAxisStall,          // the next move stops part way: alarm 0x10, position deviation
  kFrameDrop,          // an exposure never leaves the camera (frame timeout)
  kFrameIncomplete,    // a frame leaves with GVSP packets lost
  kCoolerFail,         // the cooler stops; the sensor drifts to ambient
  kMonitorDisconnect,  // the power meter leaves the bus for `duration_s`
  kControlLost,        // the camera drops its controller, as on a missed heartbeat (GigE Vision)
  kFrameLate,          // a frame leaves the camera `duration_s` (simulated) after its readout
  kLatchSlow,          // a timestamp latch is taken `duration_s` (simulated) after its write
};

// The config's spelling: "modbus_timeout", "modbus_crc", ...
std::string_view ToString(FaultKind kind);
std::optional<FaultKind> FaultKindFromString(std::string_view name);

struct FaultEvent {
  FaultKind kind = FaultKind::kModbusTimeout;
  // Which device: an axis role ("sample", "arm", "azimuth") for axis and Modbus faults (empty:
  // any), ignored for the camera and the monitor.
  std::string target;
  // Trigger, one of: the n-th opportunity (1-based), the first opportunity at or after a
  // simulated time, or each opportunity with a probability.
  std::int64_t at_opportunity = 0;
  double at_time_s = -1;
  double probability = 0;
  int count = 1;           // how many times the event fires in all (for probability: at most)
  std::uint32_t code = 0;  // kAxisAlarm: the alarm code (e.g. 0x30 overload)
  double duration_s = 0;   // kMonitorDisconnect: how long the meter stays away; kFrameLate,
                           // kLatchSlow: the delay
};

// Shorthands for tests and config: the n-th opportunity, the first at or after time t, or each
// with probability p (at most `count` times).
inline FaultEvent OnOpportunity(FaultKind kind, std::int64_t n, std::string target = {}) {
  FaultEvent e;
  e.kind = kind;
  e.at_opportunity = n;
  e.target = std::move(target);
  return e;
}
inline FaultEvent AtTime(FaultKind kind, double t, std::string target = {}) {
  FaultEvent e;
  e.kind = kind;
  e.at_time_s = t;
  e.target = std::move(target);
  return e;
}
inline FaultEvent WithProbability(FaultKind kind, double p, int count, std::string target = {}) {
  FaultEvent e;
  e.kind = kind;
  e.probability = p;
  e.count = count;
  e.target = std::move(target);
  return e;
}

struct FiredFault {
  FaultKind kind;
  std::string target;
  double time_s;
  std::size_t event_index;
};

// Thread-safe: devices on several threads ask one plan.
class FaultPlan {
 public:
  FaultPlan() = default;
  FaultPlan(std::vector<FaultEvent> events, std::uint64_t seed);

  // One opportunity of `kind` on `target` at simulated time `now`: the event that fires, if any
  // (at most one per call). Callers that ask nothing of the result may just test it.
  std::optional<FaultEvent> Fire(FaultKind kind, std::string_view target, double now);

  // Every fault fired so far, in order: what the tests and the operator's log see.
  std::vector<FiredFault> Fired() const;
  bool empty() const { return events_.empty(); }

 private:
  struct State {
    FaultEvent event;
    std::mt19937_64 rng;
    std::int64_t opportunities = 0;
    int fired = 0;
  };
  mutable std::mutex mu_;
  std::vector<State> events_;
  std::vector<FiredFault> fired_;
};

// Convenience for devices holding an optional plan.
inline std::optional<FaultEvent> MaybeFire(FaultPlan* plan, FaultKind kind, std::string_view target,
                                           double now) {
  return plan ? plan->Fire(kind, target, now) : std::nullopt;
}

}  // namespace gonio::sim
