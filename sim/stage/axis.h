// One simulated rotation-stage driver at the register level: the Modbus holding registers of an
// Oriental Motor AZ-style driver in "direct data operation" (docs/reference.md section 4), the map
// written out in full in docs/stage_register_map.md. One axis is one Modbus slave, as AZ drivers
// on an RS-485 line. The protocol servers (libmodbus TCP and RTU) wrap it: after a
// write they call OnWrite(); before a read they call Refresh(). No networking here.
#pragma once

#include <array>
#include <cstdint>
#include <mutex>
#include <random>

#include <optional>
#include <string>

#include "sim/clock.h"
#include "sim/faults/fault_plan.h"
#include "sim/stage/motion.h"

namespace gonio::sim {

// Register addresses (holding registers; 32-bit values are two registers, upper word first).
namespace stage_reg {
inline constexpr std::uint16_t kDirectData = 0x0058;        // 16 registers, see below
inline constexpr std::uint16_t kDataNumber = 0x0058;        // 32-bit, unused by the simulator
inline constexpr std::uint16_t kOperationType = 0x005A;     // 32-bit: 1 absolute, 2 incremental
inline constexpr std::uint16_t kPosition = 0x005C;          // 32-bit signed, steps
inline constexpr std::uint16_t kSpeed = 0x005E;             // 32-bit, steps/s
inline constexpr std::uint16_t kAcceleration = 0x0060;      // 32-bit, steps/s^2
inline constexpr std::uint16_t kDeceleration = 0x0062;      // 32-bit, steps/s^2
inline constexpr std::uint16_t kCurrent = 0x0064;           // 32-bit, 0.1 %; stored, not modelled
inline constexpr std::uint16_t kTrigger = 0x0066;           // 32-bit: 1 = start with all data
inline constexpr std::uint16_t kInputCommand = 0x007C;      // 32-bit bit field, see kIn*
inline constexpr std::uint16_t kOutputStatus = 0x007E;      // 32-bit bit field, see kOut*
inline constexpr std::uint16_t kPresentAlarm = 0x0080;      // 32-bit alarm code, 0 = none
inline constexpr std::uint16_t kCommandPosition = 0x00C6;   // 32-bit signed, steps: commanded
inline constexpr std::uint16_t kFeedbackPosition = 0x00CC;  // 32-bit signed, steps: the encoder
inline constexpr std::uint16_t kAlarmReset = 0x0180;        // 32-bit: write 1 to reset the alarm
inline constexpr std::uint16_t kCount = 0x0200;             // registers 0x0000..0x01FF exist

// Input command bits (kInputCommand, lower word).
inline constexpr std::uint32_t kInStart = 1u << 3;  // start with the stored direct data
inline constexpr std::uint32_t kInHome = 1u << 4;   // ZHOME: return to position 0 (home)
inline constexpr std::uint32_t kInStop = 1u << 5;   // decelerate to a stop
inline constexpr std::uint32_t kInAlarmReset = 1u << 7;

// Output status bits (kOutputStatus, lower word).
inline constexpr std::uint32_t kOutHomeEnd = 1u << 4;      // homed since power-up, and at home
inline constexpr std::uint32_t kOutReady = 1u << 5;        // accepts a new operation
inline constexpr std::uint32_t kOutAlarm = 1u << 7;        // ALM-A: an alarm is present
inline constexpr std::uint32_t kOutBusy = 1u << 8;         // SYS-BSY: an operation is under way
inline constexpr std::uint32_t kOutMove = 1u << 13;        // the motor is moving
inline constexpr std::uint32_t kOutInPos = 1u << 14;       // settled within the in-position band
inline constexpr std::uint32_t kOutLimitPlus = 1u << 10;   // +LS: the + limit switch is pressed
inline constexpr std::uint32_t kOutLimitMinus = 1u << 11;  // -LS: the - limit switch is pressed

// Alarm codes (kPresentAlarm), after the AZ family's.
inline constexpr std::uint32_t kAlarmPositionDeviation = 0x10;   // the motor stalled
inline constexpr std::uint32_t kAlarmOverload = 0x30;            // the fault plan's default alarm
inline constexpr std::uint32_t kAlarmHardwareOvertravel = 0x66;  // a limit switch was hit
inline constexpr std::uint32_t kAlarmSoftwareOvertravel = 0x67;
inline constexpr std::uint32_t kAlarmBadData = 0x70;  // operation data out of range
}  // namespace stage_reg

struct AxisOptions {
  // Software travel limits (steps), inclusive; a target outside raises 0x67 and does not move.
  std::int32_t min_steps = -200'000, max_steps = 200'000;
  double home_speed = 2000;  // steps/s for ZHOME
  double home_acceleration = 20000;
  double settle_s = 0.05;  // IN-POS after the profile ends plus this settling time
  // Limit switches (steps): reaching one stops the motor at once with alarm 0x66. Real stages put
  // them just beyond the software limits; a profile whose soft limits are wider than its switches
  // (or a stage without soft limits) meets them.
  bool limit_switches = false;
  std::int32_t limit_min_steps = -210'000, limit_max_steps = 210'000;
  // Lost motion in the gearing (steps): the stage (load) lags the motor by up to this much after
  // a reversal. The encoder (0x00C6) reads the motor; the camera sees the load. A driver that
  // always approaches from the same side sees a constant offset instead of a hysteresis.
  double backlash_steps = 0;
  // Where a move leaves the load against the motor's step: uniform within +-settle_error_steps,
  // drawn afresh for each move (a stepper's step-angle accuracy, the gearing's play within a
  // step). The encoder reads the motor, so its read-back is off from the stage by that much:
  // +-0.5 steps gives the read-back a sigma of 1/sqrt(12) of a step, the instrument's stated
  // angle_sigma_deg (config/instrument.toml). 0: the load stops exactly on the step.
  double settle_error_steps = 0;
  std::uint64_t settle_seed = 1;  // the draws' seed (each axis its own)
  // How the real AZ driver differs from a forgiving one (docs/stage_register_map.md, "Handshakes"):
  // Input commands latched: the input-command register keeps what was written, a command acts on
  // its bit's off-to-on edge, and a STOP left on blocks every operation until it is cleared.
  // Otherwise each write acts as a pulse and the register reads 0 again.
  bool latched_inputs = false;
  // READY stays off this long after a motion ends (a move, a stop, a homing) and after an alarm
  // reset; an operation or ZHOME written meanwhile is ignored.
  double ready_delay_s = 0;
  // A stall (the fault plan's axis_stall) raises alarm 0x10 (true), or goes unnoticed by the
  // driver (false: a deviation under the alarm threshold): the commanded position still reaches
  // the target and IN-POS comes, while the encoder (feedback position) stays where it stalled.
  bool stall_alarm = true;
};

// Thread-safe: the protocol server's thread writes and reads registers while the camera's
// firmware reads positions.
class SimulatedAxis {
 public:
  // `name` (the axis role) is how the fault plan targets this axis; the plan may be null and must
  // outlive the axis.
  SimulatedAxis(const Clock& clock, AxisOptions options = {}, std::string name = {},
                FaultPlan* faults = nullptr);

  // Register access for the protocol layer. Addresses outside [0, kCount) are the caller's
  // Modbus "illegal data address" and never reach here.
  std::uint16_t Read(std::uint16_t address);  // refreshes the status first
  // After a write of `count` registers at `address` (already stored by Write): acts on triggers,
  // commands and alarm reset.
  void Write(std::uint16_t address, const std::uint16_t* values, int count);

  // All registers at once, refreshed (for a protocol server answering reads of any range).
  void Snapshot(std::uint16_t (&out)[stage_reg::kCount]);

  // Whether a profile is still running at the clock's now.
  bool Moving() const;
  // Where the stage (load) is now, steps, fractional during a move and after backlash: what the
  // scene's camera sees.
  double PositionSteps() const;
  // Where the motor is (what the encoder reads).
  double MotorSteps() const;
  // How many operations and ZHOMEs were ignored for want of READY (or for a STOP held on).
  int IgnoredOperations() const;
  const std::string& name() const { return name_; }

 private:
  std::uint32_t Get32(std::uint16_t a) const {
    return (std::uint32_t(regs_[a]) << 16) | regs_[a + 1];
  }
  void Set32(std::uint16_t a, std::uint32_t v) {
    regs_[a] = static_cast<std::uint16_t>(v >> 16);
    regs_[a + 1] = static_cast<std::uint16_t>(v & 0xFFFF);
  }
  void Refresh();
  void StartDirectData();
  void Home();
  void Stop();
  void Alarm(std::uint32_t code);
  // Replaces the motion from `now` on, carrying the load's backlash state over.
  void NewMove(double now, const TrapezoidalMove& move);
  // Where the motor is at t, and whether it moves, with a pending hard stop (a limit switch or a
  // stall) in effect from its time on; the load behind its backlash.
  double MotorAt(double t) const;
  double CommandAt(double t) const;  // the commanded profile (a silent stall does not stop it)
  bool MovingAt(double t) const;
  bool ReadyAt(double t) const;  // READY: accepts an operation
  void ResetAlarm(double now);
  double LoadAt(double t) const;

  struct HardStop {
    double time, position;
    std::uint32_t alarm;
  };

  mutable std::mutex mu_;
  const Clock& clock_;
  AxisOptions o_;
  std::string name_;
  FaultPlan* faults_;
  std::array<std::uint16_t, stage_reg::kCount> regs_{};
  TrapezoidalMove move_;
  double load_anchor_ = 0;    // the load at the start of move_
  double settle_offset_ = 0;  // the load against LoadAt's for the current move (settle_error_steps)
  std::mt19937_64 settle_rng_;
  // Known when the move starts (a switch on the path, a stall drawn by the fault plan); becomes
  // an alarm at the first register access after its time.
  std::optional<HardStop> hard_stop_;
  std::uint32_t alarm_ = 0;
  bool homed_ = false, homing_ = false;
  std::uint32_t inputs_ = 0;       // latched_inputs: the input command as last written
  bool alarm_reset_held_ = false;  // latched_inputs: 0x0180 holds 1
  double not_ready_until_ = -1;    // ready_delay_s after an alarm reset
  int ignored_ = 0;
  // A stall that the driver does not notice (stall_alarm false): the motor rests at `position`
  // from `time` on while the commanded profile (move_) goes on.
  std::optional<HardStop> silent_stall_;
};

}  // namespace gonio::sim
