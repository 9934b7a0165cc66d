#include "backends/modbus_stage.h"

#include <modbus/modbus.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <thread>

namespace gonio::backends {

namespace {

modbus_t* Ctx(void* p) { return static_cast<modbus_t*>(p); }

std::string Hex(std::uint32_t v) {
  char b[16];
  std::snprintf(b, sizeof b, "0x%02X", v);
  return b;
}

bool Transient(int e) { return e == ETIMEDOUT || e == EMBBADCRC || e == EMBBADDATA; }
bool ConnectionLost(int e) {
  return e == ECONNRESET || e == EPIPE || e == EBADF || e == ENOTCONN || e == ECONNREFUSED ||
         e == EIO;
}

std::int32_t ToSteps(const AxisSettings& a, double deg) {
  return static_cast<std::int32_t>(std::lround((deg - a.degrees_at_zero) * a.steps_per_degree));
}
double ToDeg(const AxisSettings& a, std::int32_t steps) {
  return a.degrees_at_zero + steps / a.steps_per_degree;
}

std::string Seconds(double s) {
  char b[32];
  std::snprintf(b, sizeof b, "%.3g s", s);
  return b;
}

}  // namespace

Result<std::unique_ptr<ModbusStageController>> ModbusStageController::Open(
    ModbusLink link, std::vector<AxisSettings> axes, StageRegisterProfile profile) {
  if (axes.empty()) return InvalidArgument("stage controller: no axes configured");
  for (const AxisSettings& a : axes) {
    if (!(a.steps_per_degree > 0) || !(a.speed_deg_s > 0) || !(a.acceleration_deg_s2 > 0) ||
        !(a.min_deg < a.max_deg) || a.backlash_overshoot_deg < 0 || !(a.tolerance_deg > 0))
      return InvalidArgument("axis '" + a.name +
                             "': steps_per_degree, speed, acceleration and tolerance must be > 0, "
                             "min_deg < max_deg, overshoot >= 0");
  }
  std::unique_ptr<ModbusStageController> c(new ModbusStageController());
  c->link_ = std::move(link);
  c->axes_ = std::move(axes);
  c->p_ = profile;
  const ModbusLink& l = c->link_;
  if (l.kind == devices::ModbusTransport::kTcp) {
    c->ctx_ = modbus_new_tcp(l.host.c_str(), l.port);
  } else if (l.kind == devices::ModbusTransport::kRtu) {
    c->ctx_ = modbus_new_rtu(l.device.c_str(), l.baud, l.parity, l.data_bits, l.stop_bits);
  } else {
    return InvalidArgument("stage link kind " + std::to_string(static_cast<int>(l.kind)) +
                           " is not tcp or rtu");
  }
  if (c->ctx_ == nullptr)
    return InvalidArgument("stage link: " + std::string(modbus_strerror(errno)));
  // The same bound for the first byte of a reply and for a silence within one (libmodbus's
  // byte timeout, 0.5 s by default whatever the response timeout): a reply that stops part-way
  // costs no more than one that never comes.
  const double t = l.response_timeout_s;
  const auto sec = static_cast<std::uint32_t>(t);
  const auto usec = static_cast<std::uint32_t>((t - std::floor(t)) * 1e6);
  modbus_set_response_timeout(Ctx(c->ctx_), sec, usec);
  modbus_set_byte_timeout(Ctx(c->ctx_), sec, usec);
  if (Status s = c->Connect(); !s.ok()) return s.error();
  for (const AxisSettings& a : c->axes_) {
    auto st = c->ReadStatus(a.name);
    if (!st.ok())
      return Error{st.error().code, "axis '" + a.name + "' (unit " + std::to_string(a.slave_id) +
                                        ") does not answer: " + st.error().message};
  }
  return c;
}

ModbusStageController::~ModbusStageController() {
  if (ctx_ != nullptr) {
    modbus_close(Ctx(ctx_));
    modbus_free(Ctx(ctx_));
  }
}

Status ModbusStageController::Connect() {
  if (modbus_connect(Ctx(ctx_)) != 0) {
    const std::string where = link_.kind == devices::ModbusTransport::kTcp
                                  ? link_.host + ":" + std::to_string(link_.port)
                                  : link_.device;
    return Error{ErrorCode::kNotConnected,
                 "stage controller at " + where + ": " + modbus_strerror(errno)};
  }
  return OkStatus();
}

Result<const AxisSettings*> ModbusStageController::Find(const std::string& name) const {
  for (const AxisSettings& a : axes_)
    if (a.name == name) return &a;
  return InvalidArgument("no axis named '" + name + "' in the stage configuration");
}

// One request under the retry policy. `op` performs it and returns libmodbus's result. Under mu_.
template <typename Op>
Status ModbusStageController::WithRetries(const std::string& what, Op op) {
  struct Retrying {  // cleared however the request ends
    std::atomic<bool>& flag;
    ~Retrying() { flag = false; }
  } clear{retrying_};
  int last = 0;
  for (int attempt = 0; attempt <= link_.retries; ++attempt) {
    if (op() != -1) return OkStatus();
    last = errno;
    if (last > MODBUS_ENOBASE && last < EMBXGTAR + 1 && !Transient(last))
      return Error{ErrorCode::kProtocol, what + ": Modbus exception: " + modbus_strerror(last)};
    if (attempt == link_.retries) break;
    ++retried_;
    if (ConnectionLost(last)) {  // not a timeout: a slow reply a retry fixes is no loss
      {
        const std::lock_guard why(retrying_mu_);
        retrying_why_ = what + ": " + modbus_strerror(last);
      }
      retrying_ = true;
    }
    if (ConnectionLost(last)) {
      modbus_close(Ctx(ctx_));
      std::this_thread::sleep_for(std::chrono::milliseconds(50 << attempt));
      if (modbus_connect(Ctx(ctx_)) == 0) ++reconnects_;
    } else {
      modbus_flush(Ctx(ctx_));  // a late or corrupt reply must not answer the next request
    }
  }
  const ErrorCode code = last == ETIMEDOUT      ? ErrorCode::kTimeout
                         : ConnectionLost(last) ? ErrorCode::kNotConnected
                                                : ErrorCode::kIo;
  return Error{code, what + ": " + modbus_strerror(last) + " (after " +
                         std::to_string(link_.retries) + " retries)"};
}

Status ModbusStageController::CheckLink() {
  if (axes_.empty()) return OkStatus();
  std::unique_lock<std::recursive_timed_mutex> bus(mu_, std::defer_lock);
  while (!bus.try_lock_for(std::chrono::milliseconds(20))) {
    if (!retrying_) continue;
    const std::lock_guard why(retrying_mu_);
    return Error{ErrorCode::kNotConnected, retrying_why_ + " (a request is being retried)"};
  }
  auto s = ReadStatus(axes_.front().name);
  return s.ok() ? OkStatus() : Status(s.error());
}

Status ModbusStageController::Read(const AxisSettings& a, std::uint16_t address, int count,
                                   std::uint16_t* out, const std::string& what) {
  std::lock_guard lock(mu_);
  modbus_set_slave(Ctx(ctx_), a.slave_id);
  return WithRetries("axis '" + a.name + "': reading " + what,
                     [&] { return modbus_read_registers(Ctx(ctx_), address, count, out); });
}

Status ModbusStageController::Write(const AxisSettings& a, std::uint16_t address, int count,
                                    const std::uint16_t* values, const std::string& what) {
  std::lock_guard lock(mu_);
  modbus_set_slave(Ctx(ctx_), a.slave_id);
  return WithRetries("axis '" + a.name + "': writing " + what,
                     [&] { return modbus_write_registers(Ctx(ctx_), address, count, values); });
}

Status ModbusStageController::Write32(const AxisSettings& a, std::uint16_t address, std::uint32_t v,
                                      const std::string& what) {
  const std::uint16_t w[2] = {static_cast<std::uint16_t>(v >> 16),
                              static_cast<std::uint16_t>(v & 0xFFFF)};
  return Write(a, address, 2, w, what);
}

std::string ModbusStageController::AlarmText(const AxisSettings& a, std::uint32_t code) const {
  const char* meaning = "see the controller's alarm list";
  switch (code) {
    case 0x10:
      meaning = "excessive position deviation: the stage stalled or is blocked";
      break;
    case 0x30:
      meaning = "overload";
      break;
    case 0x66:
      meaning = "hardware overtravel: a limit switch was reached";
      break;
    case 0x67:
      meaning = "software overtravel: the target is outside the controller's limits";
      break;
    case 0x70:
      meaning = "operation data error";
      break;
    default:
      break;
  }
  return "axis '" + a.name + "' alarm " + Hex(code) + " (" + meaning +
         "); check the stage, then reset the alarm";
}

Result<AxisStatus> ModbusStageController::ReadBits(const AxisSettings& a) {
  std::uint16_t st[4];  // output status and present alarm, adjacent in the default profile
  if (p_.present_alarm == p_.output_status + 2) {
    if (Status r = Read(a, p_.output_status, 4, st, "status"); !r.ok()) return r.error();
  } else {
    if (Status r = Read(a, p_.output_status, 2, st, "status"); !r.ok()) return r.error();
    if (Status r = Read(a, p_.present_alarm, 2, st + 2, "alarm"); !r.ok()) return r.error();
  }
  AxisStatus s;
  const std::uint32_t out = (std::uint32_t(st[0]) << 16) | st[1];
  s.alarm = (std::uint32_t(st[2]) << 16) | st[3];
  s.ready = out & p_.out_ready;
  s.moving = out & p_.out_move;
  s.in_position = out & p_.out_in_pos;
  s.homed = out & p_.out_home_end;
  if (out & p_.out_alarm && s.alarm == 0) s.alarm = 0xFFFF;  // alarm bit without a code
  return s;
}

Status ModbusStageController::ReadPositions(const AxisSettings& a, AxisStatus& s) {
  auto steps = [](const std::uint16_t* r) {
    return static_cast<std::int32_t>((std::uint32_t(r[0]) << 16) | r[1]);
  };
  const int lo = std::min(p_.command_position, p_.feedback_position);
  const int hi = std::max(p_.command_position, p_.feedback_position);
  std::uint16_t r[10];
  if (hi - lo <= 8) {  // one request for both (the default profile: 0x00C6..0x00CD)
    if (Status st = Read(a, static_cast<std::uint16_t>(lo), hi - lo + 2, r, "position"); !st.ok())
      return st;
    s.commanded_deg = ToDeg(a, steps(r + (p_.command_position - lo)));
    s.position_deg = ToDeg(a, steps(r + (p_.feedback_position - lo)));
  } else {
    if (Status st = Read(a, p_.command_position, 2, r, "commanded position"); !st.ok()) return st;
    if (Status st = Read(a, p_.feedback_position, 2, r + 2, "feedback position"); !st.ok())
      return st;
    s.commanded_deg = ToDeg(a, steps(r));
    s.position_deg = ToDeg(a, steps(r + 2));
  }
  return OkStatus();
}

Result<AxisStatus> ModbusStageController::ReadStatus(const std::string& name) {
  auto found = Find(name);
  if (!found.ok()) return found.error();
  const AxisSettings& a = **found;
  auto s = ReadBits(a);
  if (!s.ok()) return s.error();
  if (Status r = ReadPositions(a, *s); !r.ok()) return r.error();
  Remember(a, *s, true);
  return s;
}

void ModbusStageController::Remember(const AxisSettings& a, const AxisStatus& s, bool positions) {
  std::lock_guard lock(mu_);
  auto [it, added] = last_known_.try_emplace(a.name, s);
  if (added) return;
  const double pos = it->second.position_deg, cmd = it->second.commanded_deg;
  it->second = s;
  if (!positions) it->second.position_deg = pos, it->second.commanded_deg = cmd;
}

std::string ModbusStageController::LastKnown() {
  std::lock_guard lock(mu_);
  std::string text;
  for (const AxisSettings& a : axes_) {
    auto it = last_known_.find(a.name);
    text += (text.empty() ? "" : ", ") + ("'" + a.name + "' ");
    if (it == last_known_.end()) {
      text += "never read";
      continue;
    }
    char b[64];
    std::snprintf(b, sizeof b, "at %.3f deg", it->second.position_deg);
    text += b;
    text += it->second.moving ? " and moving" : " at rest";
  }
  return text;
}

std::string ModbusStageController::BitsText(const AxisStatus& s) const {
  std::string t;
  auto add = [&](bool on, const char* name) {
    if (on) t += (t.empty() ? "" : " ") + std::string(name);
  };
  add(s.ready, "READY");
  add(s.moving, "MOVE");
  add(s.in_position, "IN-POS");
  add(s.homed, "HOME-END");
  add(s.alarm != 0, "ALM-A");
  return t.empty() ? "no status bit on" : t;
}

Status ModbusStageController::WaitReady(const AxisSettings& a, const char* before) {
  const auto deadline =
      std::chrono::steady_clock::now() + std::chrono::duration<double>(p_.ready_timeout_s);
  for (;;) {
    auto st = ReadBits(a);
    if (!st.ok()) return st.error();
    if (st->alarm != 0) return Error{ErrorCode::kDeviceFault, AlarmText(a, st->alarm)};
    if (st->ready) return OkStatus();
    if (std::chrono::steady_clock::now() > deadline)
      return Error{ErrorCode::kDeviceFault,
                   "axis '" + a.name + "' not READY after " + Seconds(p_.ready_timeout_s) +
                       " (status: " + BitsText(*st) + "), so " + before +
                       " was not sent: another client may be moving it, or a STOP is held on"};
    std::this_thread::sleep_for(PollInterval());
  }
}

std::chrono::microseconds ModbusStageController::PollInterval() const {
  const double s = link_.poll_interval_s > 0                      ? link_.poll_interval_s
                   : link_.kind == devices::ModbusTransport::kRtu ? 0.02
                                                                  : 0.005;
  return std::chrono::microseconds(std::lround(s * 1e6));
}

Status ModbusStageController::Command(const AxisSettings& a, std::uint16_t address,
                                      std::uint32_t value, const std::string& what) {
  // Latched inputs act on an off-to-on edge and stay as written: clear before (something may
  // have left the bit on) and after (a STOP held on blocks every later move). A STOP is sent
  // first of all: it must not wait for a clearing write.
  const bool stop = address == p_.input_command && value == p_.in_stop;
  if (p_.inputs_latched && !stop)
    if (Status s = Write32(a, address, 0, what + " (clearing)"); !s.ok()) return s;
  if (Status s = Write32(a, address, value, what); !s.ok()) return s;
  if (p_.inputs_latched) return Write32(a, address, 0, what + " (clearing)");
  return OkStatus();
}

Status ModbusStageController::ResetAlarm(const std::string& name) {
  auto found = Find(name);
  if (!found.ok()) return found.error();
  return Command(**found, p_.alarm_reset, 1, "alarm reset");
}

Status ModbusStageController::StopAll() {
  Status first = OkStatus();
  for (const AxisSettings& a : axes_) {  // every axis, even if one fails
    Status s = Command(a, p_.input_command, p_.in_stop, "STOP");
    if (!s.ok() && first.ok()) first = s;
  }
  return first;
}

Status ModbusStageController::StartMove(const AxisSettings& a, double deg) {
  const auto steps = static_cast<std::uint32_t>(ToSteps(a, deg));
  const auto speed = static_cast<std::uint32_t>(std::lround(a.speed_deg_s * a.steps_per_degree));
  const auto acc =
      static_cast<std::uint32_t>(std::lround(a.acceleration_deg_s2 * a.steps_per_degree));
  const std::uint32_t v[8] = {0, p_.operation_absolute, steps, speed, acc, acc, p_.current, 1};
  std::uint16_t w[16];
  for (int k = 0; k < 8; ++k) {
    w[2 * k] = static_cast<std::uint16_t>(v[k] >> 16);
    w[2 * k + 1] = static_cast<std::uint16_t>(v[k] & 0xFFFF);
  }
  return Write(a, p_.direct_data, 16, w, "direct data (move)");
}

Status ModbusStageController::WaitAll(const std::vector<const AxisSettings*>& list, bool homing,
                                      double timeout_s, const std::vector<double>& targets_deg) {
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout_s);
  std::vector<bool> done(list.size(), false);
  for (;;) {
    bool all = true;
    for (std::size_t k = 0; k < list.size(); ++k) {
      if (done[k]) continue;
      const AxisSettings& a = *list[k];
      // One request per axis per poll (status and alarm); positions once it says it is done.
      auto st = ReadBits(a);
      if (!st.ok()) return Lost(st.error());
      Remember(a, *st, false);
      if (st->alarm != 0) {
        (void)StopAll();  // the others must not go on moving
        return Error{ErrorCode::kDeviceFault, AlarmText(a, st->alarm)};
      }
      if (st->moving || !(homing ? st->homed : st->in_position)) {
        all = false;
        continue;
      }
      if (Status r = ReadPositions(a, *st); !r.ok()) return Lost(r.error());
      Remember(a, *st, true);
      if (homing || std::abs(st->position_deg - targets_deg[k]) <= a.tolerance_deg) {
        done[k] = true;
      } else if (std::abs(st->commanded_deg - targets_deg[k]) <= a.tolerance_deg) {
        // The controller has finished the profile but the encoder is elsewhere: a stall the
        // controller did not alarm on (a deviation under its threshold).
        (void)StopAll();
        char b[160];
        std::snprintf(b, sizeof b,
                      "axis '%s' stalled: commanded to %.4f deg, the encoder reads %.4f deg "
                      "(feedback register %s); stages stopped",
                      a.name.c_str(), st->commanded_deg, st->position_deg,
                      Hex(p_.feedback_position).c_str());
        return Error{ErrorCode::kDeviceFault, b};
      } else {
        all = false;  // a stale IN-POS read right after the trigger: not there yet
      }
    }
    if (all) return OkStatus();
    if (std::chrono::steady_clock::now() > deadline) {
      (void)StopAll();
      std::string names;
      for (std::size_t k = 0; k < list.size(); ++k)
        if (!done[k]) names += (names.empty() ? "'" : ", '") + list[k]->name + "'";
      return Error{ErrorCode::kTimeout, "axis " + names + " not " +
                                            (homing ? "homed" : "in position") + " after " +
                                            Seconds(timeout_s) + "; stages stopped"};
    }
    std::this_thread::sleep_for(PollInterval());
  }
}

Error ModbusStageController::Lost(const Error& e) {
  // The link failed mid-move: try STOP anyway; if it cannot be sent either, say what that means.
  if (StopAll().ok()) return Error{e.code, e.message + "; stages stopped"};
  return Error{e.code, e.message +
                           "; STOP could not be sent either, so the axes may still be "
                           "moving (last known: " +
                           LastKnown() + ")"};
}

Status ModbusStageController::MoveTo(const std::vector<std::pair<std::string, double>>& targets) {
  // Everything is checked before anything moves.
  std::vector<const AxisSettings*> list;
  std::vector<double> goal;
  for (const auto& [name, deg] : targets) {
    auto found = Find(name);
    if (!found.ok()) return found.error();
    const AxisSettings& a = **found;
    if (!(deg >= a.min_deg && deg <= a.max_deg))
      return InvalidArgument("axis '" + name + "': target " + std::to_string(deg) +
                             " deg is outside the travel limits [" + std::to_string(a.min_deg) +
                             ", " + std::to_string(a.max_deg) + "]; nothing moved");
    list.push_back(&a);
    goal.push_back(deg);
  }
  // Phase 1: axes coming from above first go below their target by the overshoot; the others go
  // straight there. Phase 2: the overshooting axes come up to the target. Within the overshoot of
  // the lower limit the dip stops at the limit (a shorter approach from below); a target at the
  // limit itself is reached from above, its backlash uncompensated (devices/stage.h).
  std::vector<const AxisSettings*> first_axes, second_axes;
  std::vector<double> first_goal, second_goal;
  for (std::size_t k = 0; k < list.size(); ++k) {
    const AxisSettings& a = *list[k];
    auto st = ReadStatus(a.name);
    if (!st.ok()) return st.error();
    if (st->alarm != 0) return Error{ErrorCode::kDeviceFault, AlarmText(a, st->alarm)};
    const bool from_above = st->position_deg > goal[k] + 0.5 / a.steps_per_degree;
    const double dip = std::max(a.min_deg, goal[k] - a.backlash_overshoot_deg);
    if (a.backlash_overshoot_deg > 0 && from_above && dip < goal[k] - 0.5 / a.steps_per_degree) {
      first_axes.push_back(&a);
      first_goal.push_back(dip);
      second_axes.push_back(&a);
      second_goal.push_back(goal[k]);
    } else {
      first_axes.push_back(&a);
      first_goal.push_back(goal[k]);
    }
  }
  double timeout = 0;
  for (const AxisSettings* a : list) timeout = std::max(timeout, a->move_timeout_s);
  for (int phase = 0; phase < 2; ++phase) {
    const auto& axes = phase == 0 ? first_axes : second_axes;
    const auto& g = phase == 0 ? first_goal : second_goal;
    if (axes.empty()) continue;
    for (std::size_t k = 0; k < axes.size(); ++k) {
      // The controller ignores an operation written while READY is off.
      if (Status s = WaitReady(*axes[k], "the move"); !s.ok()) {
        (void)StopAll();
        return s;
      }
      if (Status s = StartMove(*axes[k], g[k]); !s.ok()) {
        (void)StopAll();
        return s;
      }
    }
    if (Status s = WaitAll(axes, false, timeout, g); !s.ok()) return s;
  }
  // Readback: every axis where it was sent.
  for (std::size_t k = 0; k < list.size(); ++k) {
    auto st = ReadStatus(list[k]->name);
    if (!st.ok()) return st.error();
    if (std::abs(st->position_deg - goal[k]) > list[k]->tolerance_deg)
      return Error{ErrorCode::kDeviceFault, "axis '" + list[k]->name + "' reads back " +
                                                std::to_string(st->position_deg) + " deg, target " +
                                                std::to_string(goal[k]) + " deg"};
  }
  return OkStatus();
}

Status ModbusStageController::Home(const std::vector<std::string>& names) {
  std::vector<const AxisSettings*> list;
  if (names.empty()) {
    for (const AxisSettings& a : axes_) list.push_back(&a);
  } else {
    for (const std::string& n : names) {
      auto found = Find(n);
      if (!found.ok()) return found.error();
      list.push_back(*found);
    }
  }
  double timeout = 0;
  for (const AxisSettings* a : list) {
    timeout = std::max(timeout, a->home_timeout_s);
    if (Status s = WaitReady(*a, "ZHOME"); !s.ok()) return s;
    if (Status s = Command(*a, p_.input_command, p_.in_home, "ZHOME"); !s.ok()) return s;
  }
  return WaitAll(list, true, timeout, std::vector<double>(list.size(), 0.0));
}

}  // namespace gonio::backends
