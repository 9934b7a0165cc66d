// The instrument's configuration file (TOML): which devices the daemon and gonio-hw open and how
// - the camera (by numeric IP or USB3 id, its format, region, cooling feature names), the stage
// controller (Modbus TCP or RTU link, register profile, each axis's gearing, limits and motion),
// the optional source monitor (USB ids, or gonio-sim's loopback socket), and the bench's optical
// geometry (the instrument response's). The example with
// every key: config/instrument.toml, which drives the simulated instrument of config/sim.toml.
// Errors name the file and line; unknown keys are refused. Plain data: opening the devices it
// describes is the daemon's (daemon/instrument/instrument.h), the one place that names backends.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "common/result.h"
#include "devices/camera.h"
#include "devices/stage.h"
#include "devices/usbtmc_transport.h"
#include "fitting/response.h"

namespace gonio::config {

struct MonitorConfig {
  bool enabled = false;
  std::string transport = "usb";  // usb | socket (gonio-sim's meter)
  devices::UsbDeviceId usb;
  std::string host = "127.0.0.1";
  int port = 5021;
  double wavelength_nm = 633;
  int averaging = 100;
  int timeout_ms = 1000;
};

struct InstrumentConfig {
  bool camera_enabled = true;
  devices::CameraSettings camera;
  devices::ModbusLink stage_link;
  devices::StageRegisterProfile registers;
  std::vector<devices::AxisSettings> axes;
  MonitorConfig monitor;
  // [beam_block]: where the flag of the axis named "beam_block" is open and where it blocks the
  // source beam; nullopt: the bench has no beam block (no measured backgrounds).
  std::optional<devices::BeamBlockSettings> beam_block;
  // [bench]: the optics' geometry that each point's instrument response is computed from
  // (fitting/response.h). Absent: runs carry no response and are fitted with the point model.
  std::optional<fitting::BenchOptics> bench;
};

Result<InstrumentConfig> LoadInstrumentConfig(const std::string& path);

}  // namespace gonio::config
