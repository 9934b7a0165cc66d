// The instrument's configuration file (TOML): which devices the daemon and gonio-hw open and how
// - the camera (by numeric IP or USB3 id, its format, region, cooling feature names), the stage
// controller (Modbus TCP or RTU link, register profile, each axis's gearing, limits and motion),
// and the optional source monitor (USB ids, or gonio-sim's loopback socket). The example with
// every key: config/instrument.toml, which drives the simulated instrument of config/sim.toml.
// Errors name the file and line; unknown keys are refused.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "common/result.h"
#include "drivers/camera/camera.h"
#include "drivers/monitor/libusb_transport.h"
#include "drivers/monitor/source_monitor.h"
#include "drivers/monitor/usbtmc_transport.h"
#include "drivers/stage/modbus_stage.h"

namespace gonio::config {

struct MonitorConfig {
  bool enabled = false;
  std::string transport = "usb";  // usb | socket (gonio-sim's meter)
  drivers::UsbDeviceId usb;
  std::string host = "127.0.0.1";
  int port = 5021;
  double wavelength_nm = 633;
  int averaging = 100;
  int timeout_ms = 1000;
};

struct InstrumentConfig {
  bool camera_enabled = true;
  drivers::CameraSettings camera;
  drivers::ModbusLink stage_link;
  drivers::StageRegisterProfile registers;
  std::vector<drivers::AxisSettings> axes;
  MonitorConfig monitor;
};

Result<InstrumentConfig> LoadInstrumentConfig(const std::string& path);

// Opening the configured devices with their real backends: what the daemon and gonio-hw do.
// Nothing else names a concrete backend.
Result<std::unique_ptr<drivers::Camera>> OpenCamera(const InstrumentConfig& c);
Result<std::unique_ptr<drivers::StageController>> OpenStages(const InstrumentConfig& c);

// A monitor and the transport under it, applied the config's wavelength and averaging.
struct OpenedMonitor {
  std::unique_ptr<drivers::UsbTmcTransport> transport;
  std::unique_ptr<drivers::SourceMonitor> monitor;
};
// Precondition: c.monitor.enabled.
Result<OpenedMonitor> OpenMonitor(const InstrumentConfig& c);

}  // namespace gonio::config
