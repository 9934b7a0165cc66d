// Opening the instrument that a configuration describes, with the real backends: the one place
// that names Aravis, libmodbus, libusb and the socket transport to gonio-sim's meter. goniod,
// gonio-acquire and gonio-hw open their devices here; everything above works on the interfaces
// (devices/), and config/ stays plain data.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "acquisition/plan.h"
#include "acquisition/run_start.h"
#include "common/result.h"
#include "config/instrument_config.h"
#include "devices/camera.h"
#include "devices/source_monitor.h"
#include "devices/stage.h"
#include "devices/usbtmc_transport.h"

namespace gonio::daemon {

Result<std::unique_ptr<devices::Camera>> OpenCamera(const config::InstrumentConfig& c);
Result<std::unique_ptr<devices::StageController>> OpenStages(const config::InstrumentConfig& c);

// A monitor and the transport under it (declared first, so it outlives the monitor), set to the
// config's wavelength and averaging.
struct OpenedMonitor {
  std::unique_ptr<devices::UsbTmcTransport> transport;
  std::unique_ptr<devices::SourceMonitor> monitor;
};
// Precondition: c.monitor.enabled.
Result<OpenedMonitor> OpenMonitor(const config::InstrumentConfig& c);

// What plans are checked against, without opening anything: the specimens, the axes' travel
// limits and, with [bench], the optics and the camera's region (for [rectangle] auto); the image
// size is 0 (not checked).
acquisition::PlanContext PlanContextOf(const config::InstrumentConfig& c,
                                       std::vector<acquisition::Specimen> specimens);

// What rebuilds each point's instrument response for a run of `plan` (fitting::ResponseSetup as
// JSON): the [bench] geometry, the camera's region and binning with the plan's rectangle, the
// specimen's thickness. Empty when the config has no [bench] (the run is fitted with the point
// model).
std::string ResponseJsonFor(const config::InstrumentConfig& c, const acquisition::Plan& plan);

// How runs start on this instrument (acquisition/run_start.h), for goniod and gonio-acquire alike:
// the engine's linear limit and the axes' speeds from the config, its [throughput], its text as
// read from `config_path` and ResponseJsonFor. Errors: the config file cannot be read again.
Result<acquisition::RunStart> RunStartFor(const config::InstrumentConfig& c,
                                          const std::string& config_path);

struct Instrument {
  std::unique_ptr<devices::Camera> camera;
  std::unique_ptr<devices::StageController> stages;
  OpenedMonitor monitor;             // both null when the config has no monitor
  acquisition::PlanContext context;  // PlanContextOf plus the camera's image size
};

// Opens the camera, the stages and the monitor (when configured), in that order; nothing moves.
// The first error is returned as it came, naming the device.
Result<Instrument> OpenInstrument(const config::InstrumentConfig& c,
                                  std::vector<acquisition::Specimen> specimens);

// Tells every axis to stop and waits at most `seconds` for the controller to confirm; true when it
// did. For a process about to exit without waiting on a device that may not answer (goniod and
// gonio-acquire on a signal): the request goes on in a detached thread, so `stages` must live
// until the process ends.
bool StopStagesWithin(devices::StageController& stages, double seconds);

}  // namespace gonio::daemon
