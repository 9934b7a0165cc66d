// The rotation stages as acquisition sees them: named axes in degrees. Moves of several axes run
// at once and return when every axis is in position and its readback agrees with the target;
// software travel limits refuse a target before anything moves; backlash is compensated by always
// approaching a target from below. Alarms and limit hits are errors (kDeviceFault), never
// retried; transient bus faults are retried by the backend within a bound.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "common/result.h"

namespace gonio::devices {

// One axis, in the instrument config's terms.
struct AxisSettings {
  std::string name;  // "sample", "arm", "azimuth"
  int slave_id = 1;  // Modbus unit / RS-485 address
  // angle (deg) = degrees_at_zero + steps / steps_per_degree (gear ratio and offset)
  double steps_per_degree = 1000;
  double degrees_at_zero = 0;
  double min_deg = -180, max_deg = 180;  // software travel limits, inclusive
  // Approach every target from below, overshooting by this much first when coming from above
  // (0: no compensation). It must exceed the stage's backlash. Within the overshoot of min_deg
  // the dip stops at min_deg; a target at min_deg itself is reached from above (uncompensated).
  double backlash_overshoot_deg = 0;
  double speed_deg_s = 10, acceleration_deg_s2 = 50;
  double tolerance_deg = 0.005;  // readback must agree with the target within this
  double move_timeout_s = 60;    // real seconds for one move to reach IN-POS
  double home_timeout_s = 120;
};

// The Modbus stage controller's settings (backends/modbus_stage.h), plain data so that the
// instrument's config can hold them without naming the backend.
// Where the controller keeps what the driver uses; 32-bit values as two registers, upper first.
struct StageRegisterProfile {
  std::uint16_t direct_data = 0x0058;  // 16 registers: number, type, position, speed, acc, dec,
                                       // current, trigger
  std::uint32_t operation_absolute = 1;
  std::uint32_t current = 1000;  // 0.1 % units, written with each move
  std::uint16_t input_command = 0x007C;
  std::uint16_t output_status = 0x007E;
  std::uint16_t present_alarm = 0x0080;
  std::uint16_t command_position = 0x00C6;   // where the controller commands the motor
  std::uint16_t feedback_position = 0x00CC;  // where the encoder says it is: moves verify this
  std::uint16_t alarm_reset = 0x0180;
  std::uint32_t in_home = 1u << 4, in_stop = 1u << 5;
  std::uint32_t out_home_end = 1u << 4, out_ready = 1u << 5, out_alarm = 1u << 7,
                out_move = 1u << 13, out_in_pos = 1u << 14;
  // Whether the controller keeps input commands (and the alarm reset) as written, acting on each
  // bit's off-to-on edge (the AZ family), rather than taking each write as a pulse. Latched: the
  // driver writes each command as an edge and clears it again (a STOP left on blocks every
  // later move; a ZHOME left on makes the next homing no edge). Harmless on a pulsing one.
  bool inputs_latched = true;
  // How long the driver waits for READY before an operation or a homing: the controller ignores
  // one written while READY is off (during a move, shortly after a move, a stop or a reset).
  double ready_timeout_s = 2.0;
};

// The bus a Modbus stage controller is on (Modbus over TCP, or RTU on a serial line).
enum class ModbusTransport { kTcp, kRtu };
inline constexpr std::array<const char*, 2> kModbusTransportNames = {"tcp", "rtu"};
inline const char* ToString(ModbusTransport t) {
  return kModbusTransportNames[static_cast<std::size_t>(t)];
}

struct ModbusLink {
  // kTcp: host (numeric) and port; kRtu: device and line settings.
  ModbusTransport kind = ModbusTransport::kTcp;
  std::string host = "127.0.0.1";
  int port = 502;
  std::string device;
  int baud = 115200;
  char parity = 'E';
  int data_bits = 8, stop_bits = 1;
  double response_timeout_s = 0.5;
  int retries = 3;  // per request, for timeouts, CRC errors and dropped connections
  // The least time between two status polls of a moving axis (each poll is one request per
  // axis); 0: 5 ms over TCP, 20 ms over RTU (three units on a 115200-baud line stay below half
  // its capacity).
  double poll_interval_s = 0;
};

// A beam block: a flag on a rotation stage (the axis named "beam_block") that swings into the
// source beam ahead of the sample, so that a frame sees everything but the light the sample
// scatters: the stray-light background of a point (acquisition's [background] plans).
struct BeamBlockSettings {
  double open_deg = 0;      // the flag out of the beam
  double blocked_deg = 90;  // the flag in the beam
};

struct AxisStatus {
  double position_deg = 0;   // the feedback (encoder) position
  double commanded_deg = 0;  // where the controller commands it
  bool ready = false, moving = false, in_position = false, homed = false;
  std::uint32_t alarm = 0;  // 0: none
};

class StageController {
 public:
  virtual ~StageController() = default;
  virtual const std::vector<AxisSettings>& axes() const = 0;

  // Moves the named axes to their targets (deg) together and waits until all are in position.
  // Errors: kInvalidArgument (unknown axis, target outside the travel limits; nothing moves),
  // kDeviceFault (an alarm, with its code; a readback off target), kTimeout, kNotConnected.
  virtual Status MoveTo(const std::vector<std::pair<std::string, double>>& targets) = 0;
  // Homes the named axes (all when empty) together and waits for HOME-END.
  virtual Status Home(const std::vector<std::string>& names = {}) = 0;
  // Decelerates every axis to a stop (safe state); does not wait.
  virtual Status StopAll() = 0;
  virtual Result<AxisStatus> ReadStatus(const std::string& name) = 0;
  virtual Status ResetAlarm(const std::string& name) = 0;
  // How many times the link has been connected again (a dropped connection, a controller that
  // restarted). A position read before a change of this count may no longer hold.
  virtual int Reconnections() const { return 0; }
  // Whether the controller answers: one status read of the first axis, safe beside a move on
  // another thread (the daemon's link watch runs beside the run). The error is the read's.
  virtual Status CheckLink() {
    if (axes().empty()) return OkStatus();
    auto s = ReadStatus(axes().front().name);
    return s.ok() ? OkStatus() : Status(s.error());
  }
};

}  // namespace gonio::devices
