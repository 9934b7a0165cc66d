// The rotation stages as acquisition sees them: named axes in degrees. Moves of several axes run
// at once and return when every axis is in position and its readback agrees with the target;
// software travel limits refuse a target before anything moves; backlash is compensated by always
// approaching a target from below. Alarms and limit hits are errors (kDeviceFault), never
// retried; transient bus faults are retried by the backend within a bound.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "common/result.h"

namespace gonio::drivers {

// One axis, in the instrument config's terms.
struct AxisSettings {
  std::string name;  // "sample", "arm", "azimuth"
  int slave_id = 1;  // Modbus unit / RS-485 address
  // angle (deg) = degrees_at_zero + steps / steps_per_degree (gear ratio and offset)
  double steps_per_degree = 1000;
  double degrees_at_zero = 0;
  double min_deg = -180, max_deg = 180;  // software travel limits, inclusive
  // Approach every target from below, overshooting by this much first when coming from above
  // (0: no compensation). It must exceed the stage's backlash.
  double backlash_overshoot_deg = 0;
  double speed_deg_s = 10, acceleration_deg_s2 = 50;
  double tolerance_deg = 0.005;  // readback must agree with the target within this
  double move_timeout_s = 60;    // real seconds for one move to reach IN-POS
  double home_timeout_s = 120;
};

struct AxisStatus {
  double position_deg = 0;
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
};

}  // namespace gonio::drivers
