// gonio-sim's configuration file (TOML): which devices to serve, the sample's ground truth, the
// bench and the clock. The example with every key and its default: config/sim.toml. Errors name
// the file and line ("sim.toml:12: ...") and nothing starts until the whole file is valid.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "common/result.h"
#include "sim/camera/camera.h"
#include "sim/faults/fault_plan.h"
#include "sim/monitor/power_meter.h"
#include "sim/scene/lamp.h"
#include "sim/scene/scene.h"
#include "sim/stage/axis.h"

namespace gonio::sim {

// One rotation stage: its role in the scene and its gearing (what the daemon's config must
// mirror for the same motor). Angle (deg) = degrees_at_zero + steps / steps_per_degree.
struct AxisConfig {
  // "sample", "arm", "azimuth" or "beam_block" (a flag that covers the source beam ahead of the
  // sample from 45 to 135 deg, for stray-light backgrounds); unit id = position in the file + 1
  std::string role;
  double steps_per_degree = 1000;
  double degrees_at_zero = 0;
  AxisOptions options;
};

struct SimConfig {
  double clock_speed = 1.0;  // simulated seconds per real second
  std::uint64_t seed = 1;
  int modbus_port = 5020;  // Modbus TCP on 127.0.0.1; 0: any free port
  std::string rtu_link;    // when set: Modbus RTU on a pty too, symlinked here
  std::vector<AxisConfig> axes;
  bool monitor_enabled = true;
  int monitor_port = 5021;  // the USBTMC socket transport on 127.0.0.1; 0: any free port
  PowerMeterOptions monitor;
  std::uint64_t fault_seed = 1;
  std::vector<FaultEvent> faults;  // none by default
  bool camera_enabled = true;
  CameraOptions camera;
  std::string sample_model = "beckmann";  // beckmann | ggx
  double sample_alpha = 0.344;            // Walter 2007 Figure 12, ground glass
  double sample_eta = 1.51;
  BenchGeometry bench;
  SceneOptions scene;
  LampOptions lamp;
};

// The defaults when no file is given: four axes (sample, arm at 180 deg, azimuth, the beam
// block's flag), the camera, ground glass.
SimConfig DefaultSimConfig();
// The two-axis bench that tests and benchmarks start in-process (sim/instrument.h): the sample
// axis (-90..90 deg) and the arm (0..360 deg, 180 at zero steps), 1000 steps per degree, the
// camera and the monitor, on any free ports, the clock at `clock_speed`.
SimConfig TwoAxisConfig(double clock_speed);
// Parses and validates a file; errors carry "path:line: what is wrong".
Result<SimConfig> LoadSimConfig(const std::string& path);

// Stage angles from the axes' positions (steps) in the order of config.axes.
StageAngles AnglesFromSteps(const std::vector<AxisConfig>& axes, const std::vector<double>& steps);

}  // namespace gonio::sim
