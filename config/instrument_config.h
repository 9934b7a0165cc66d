// The instrument's configuration file (TOML): which devices the daemon and gonio-hw open and how
// - the camera (by numeric IP or USB3 id, its format, region, cooling feature names), the stage
// controller (Modbus TCP or RTU link, register profile, each axis's gearing, limits and motion),
// the optional source monitor (USB ids, or gonio-sim's loopback socket), and the bench's optical
// geometry (the instrument response's), and the bench's measured throughput. The example with
// every key: config/instrument.toml, which drives the simulated instrument of config/sim.toml.
// Errors name the file and line; unknown keys are refused. Plain data: opening the devices it
// describes is the daemon's (daemon/instrument/instrument.h), the one place that names backends.
#pragma once

#include <array>
#include <optional>
#include <string>
#include <vector>

#include "common/result.h"
#include "devices/camera.h"
#include "devices/stage.h"
#include "devices/usbtmc_transport.h"
#include "optics/bench_optics.h"

namespace gonio::config {

// How the source monitor is reached: USBTMC over libusb, or the same framing over a socket
// (gonio-sim's meter).
enum class MonitorTransport { kUsb, kSocket };
inline constexpr std::array<const char*, 2> kMonitorTransportNames = {"usb", "socket"};

struct MonitorConfig {
  bool enabled = false;
  MonitorTransport transport = MonitorTransport::kUsb;
  devices::UsbDeviceId usb;
  std::string host = "127.0.0.1";
  int port = 5021;
  double wavelength_nm = 633;
  int averaging = 100;
  int timeout_ms = 1000;
};

// [throughput]: what the bench delivers per unit of a specimen's BTDF, and its noise per frame,
// measured once on a finished run with a fit (`gonioctl throughput RUN` prints the table; the
// operator's guide says when). It prices a plan's exposures on a database that has no such run
// of its own: a new database's first dry run. The fields are acquisition's Throughput and
// FrameNoise (acquisition/exposure.h), in the same units.
struct ThroughputConfig {
  double scale = 0;          // stored value per unit of f |cos theta_l| (a fit's k)
  double floor = 0;          // the stray-light floor, stored value units
  double adu_per_value = 0;  // rectangle-mean ADU per second per unit of stored value
  double dark_adu = 0;       // the dark's rectangle mean
  // The noise per frame, sigma^2 x frames = shot S/t + dark/t + read/t^2 + lamp S^2; absent
  // (all four 0): adaptive plans are priced by their coarse scan and budget only.
  double noise_shot = 0, noise_read = 0, noise_lamp = 0, noise_dark = 0;
  int from_run = 0;  // the run it was measured on, for the operator (0: not said)
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
  std::optional<optics::BenchOptics> bench;
  // [throughput]: nullopt when absent (a database's own runs are then the only basis).
  std::optional<ThroughputConfig> throughput;
};

Result<InstrumentConfig> LoadInstrumentConfig(const std::string& path);

}  // namespace gonio::config
