#include "daemon/instrument/instrument.h"

#include <algorithm>
#include <chrono>
#include <fstream>
#include <future>
#include <sstream>
#include <thread>
#include <utility>

#include "backends/aravis_camera.h"
#include "backends/libusb_transport.h"
#include "backends/modbus_stage.h"
#include "backends/usbtmc_socket.h"
#include "devices/scpi_power_meter.h"

namespace gonio::daemon {

Result<std::unique_ptr<devices::Camera>> OpenCamera(const config::InstrumentConfig& c) {
  if (!c.camera_enabled) return InvalidArgument("the camera is disabled in the configuration");
  auto cam = backends::AravisCamera::Open(c.camera);
  if (!cam.ok()) return cam.error();
  return std::unique_ptr<devices::Camera>(std::move(cam).value());
}

Result<std::unique_ptr<devices::StageController>> OpenStages(const config::InstrumentConfig& c) {
  auto st = backends::ModbusStageController::Open(c.stage_link, c.axes, c.registers);
  if (!st.ok()) return st.error();
  return std::unique_ptr<devices::StageController>(std::move(st).value());
}

Result<OpenedMonitor> OpenMonitor(const config::InstrumentConfig& c) {
  OpenedMonitor m;
  if (c.monitor.transport == config::MonitorTransport::kSocket) {
    auto t = backends::UsbTmcSocketTransport::Connect(c.monitor.host, c.monitor.port);
    if (!t.ok()) return t.error();
    m.transport = std::move(t).value();
  } else {
    auto t = backends::LibUsbTmcTransport::Open(c.monitor.usb);
    if (!t.ok()) return t.error();
    m.transport = std::move(t).value();
  }
  auto meter = std::make_unique<devices::ScpiPowerMeter>(*m.transport, c.monitor.timeout_ms);
  // A client that died mid-query (a killed gonio-acquire) can have left a response queued.
  if (Status s = meter->Clear(); !s.ok()) return s.error();
  if (Status s = meter->SetWavelengthNm(c.monitor.wavelength_nm); !s.ok()) return s.error();
  if (Status s = meter->SetAveraging(c.monitor.averaging); !s.ok()) return s.error();
  m.monitor = std::move(meter);
  return m;
}

acquisition::PlanContext PlanContextOf(const config::InstrumentConfig& c,
                                       std::vector<acquisition::Specimen> specimens) {
  acquisition::PlanContext ctx;
  ctx.specimens = std::move(specimens);
  ctx.axes = c.axes;
  ctx.beam_block = c.beam_block;
  if (c.bench) {
    fitting::ResponseSetup s;
    s.bench = *c.bench;
    // The camera's region origin is in sensor pixels; binning applies to both axes.
    s.rectangle.offset_x = c.camera.roi_x;
    s.rectangle.offset_y = c.camera.roi_y;
    s.rectangle.binning_h = s.rectangle.binning_v = std::max(1, c.camera.binning);
    ctx.response = s;
  }
  return ctx;
}

std::string ResponseJsonFor(const config::InstrumentConfig& c, const acquisition::Plan& plan) {
  const auto s = acquisition::ResponseSetupFor(PlanContextOf(c, {}), plan, plan.rectangle);
  return s ? s->ToJson() : "";
}

Result<acquisition::RunStart> RunStartFor(const config::InstrumentConfig& c,
                                          const std::string& config_path) {
  acquisition::RunStart start;
  start.engine.linear_limit_adu = c.camera.linear_limit_adu;
  start.engine.axes = c.axes;  // prices an adaptive run's moves against its budget
  if (c.throughput) start.throughput = acquisition::ThroughputOf(*c.throughput);
  std::ifstream file(config_path);
  if (!file)
    return Error{ErrorCode::kIo, config_path + ": cannot be read again to store with runs"};
  std::stringstream text;
  text << file.rdbuf();
  start.config_text = text.str();
  start.response_for = [c](const acquisition::Plan& p) { return ResponseJsonFor(c, p); };
  return start;
}

Result<Instrument> OpenInstrument(const config::InstrumentConfig& c,
                                  std::vector<acquisition::Specimen> specimens) {
  Instrument in;
  in.context = PlanContextOf(c, std::move(specimens));
  auto camera = OpenCamera(c);
  if (!camera.ok()) return camera.error();
  in.camera = std::move(camera).value();
  auto size = in.camera->ImageSize();
  if (!size.ok()) return size.error();
  in.context.image_width = size->width;
  in.context.image_height = size->height;
  const devices::CameraCapabilities caps = in.camera->Capabilities();
  if (!caps.temperature || !caps.shutter)
    in.context.camera_missing = !caps.temperature && !caps.shutter
                                    ? "no temperature sensor and no shutter"
                                : !caps.temperature ? "no temperature sensor"
                                                    : "no shutter for dark frames";
  auto stages = OpenStages(c);
  if (!stages.ok()) return stages.error();
  in.stages = std::move(stages).value();
  if (c.monitor.enabled) {
    auto m = OpenMonitor(c);
    if (!m.ok()) return m.error();
    in.monitor = std::move(m).value();
  }
  return in;
}

bool StopStagesWithin(devices::StageController& stages, double seconds) {
  // Not std::async: its future would wait for the request when it went out of scope.
  auto answered = std::make_shared<std::promise<bool>>();
  std::future<bool> result = answered->get_future();
  std::thread([&stages, answered] { answered->set_value(stages.StopAll().ok()); }).detach();
  return result.wait_for(std::chrono::duration<double>(seconds)) == std::future_status::ready &&
         result.get();
}

}  // namespace gonio::daemon
