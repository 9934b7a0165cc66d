// The simulated instrument in-process, reached through the real drivers: two axes over Modbus TCP
// on 127.0.0.1, the cooled CCD over GigE Vision (Aravis's fake camera), the source monitor over
// USBTMC framing. For tests and benchmarks of what sits on the driver interfaces (the engine, the
// daemon).
// One GigE camera per machine: tests using it hold the CTest resource lock "gvcp".
#pragma once

#include <memory>
#include <vector>

#include "drivers/camera/aravis_camera.h"
#include "drivers/monitor/scpi_power_meter.h"
#include "drivers/stage/modbus_stage.h"
#include "sim/camera/camera.h"
#include "sim/monitor/power_meter.h"
#include "sim/stage/modbus_tcp_server.h"
#include "sim/truth/ground_truth.h"

namespace gonio::testing {

struct SimInstrumentOptions {
  double clock_speed = 300;
  double gain_db = 12;  // more counts per electron: the stray floor is reached sooner
  sim::LampOptions lamp{.drift_per_hour = 0, .wander_amplitude = 0, .flicker_rms = 0};
  std::shared_ptr<const sim::GroundTruth> truth;  // null: Walter 2007's ground glass
};

class SimInstrument {
 public:
  // Starts the devices and opens the drivers on them; the first that does not come up is the
  // error.
  Status Start(const SimInstrumentOptions& o) {
    clock = std::make_unique<sim::ScaledClock>(o.clock_speed);
    sample_axis = std::make_unique<sim::SimulatedAxis>(*clock, sim::AxisOptions{}, "sample");
    arm_axis = std::make_unique<sim::SimulatedAxis>(*clock, sim::AxisOptions{}, "arm");
    lamp = std::make_unique<sim::Lamp>(o.lamp);
    scene = std::make_unique<sim::Scene>(
        sim::BenchGeometry{}, o.truth ? o.truth : sim::MicrofacetTruth("beckmann", 0.344, 1.51));
    auto tcp = sim::StageModbusTcpServer::Start({sample_axis.get(), arm_axis.get()}, 0, nullptr,
                                                clock.get());
    if (!tcp.ok()) return tcp.error();
    tcp_server = std::move(*tcp);
    auto cam = sim::SimulatedCamera::StartGigE(
        *clock, *scene,
        [this] {
          return sim::StageAngles{sample_axis->PositionSteps() / 1000,
                                  180 + arm_axis->PositionSteps() / 1000, 0};
        },
        *lamp);
    if (!cam.ok()) return cam.error();
    sim_camera = std::move(*cam);
    meter_device = std::make_unique<sim::SimulatedPowerMeter>(*clock, *lamp);
    meter = std::make_unique<drivers::ScpiPowerMeter>(*meter_device);
    if (Status m = meter->SetAveraging(100); !m.ok()) return m;

    drivers::ModbusLink link;
    link.port = tcp_server->port();
    drivers::AxisSettings s{.name = "sample", .slave_id = 1};
    s.min_deg = -90, s.max_deg = 90, s.speed_deg_s = 30, s.acceleration_deg_s2 = 300;
    drivers::AxisSettings a = s;
    a.name = "arm", a.slave_id = 2, a.degrees_at_zero = 180, a.min_deg = 0, a.max_deg = 360;
    auto st = drivers::ModbusStageController::Open(link, {s, a});
    if (!st.ok()) return st.error();
    stages = std::move(*st);
    axes = {s, a};
    drivers::CameraSettings cs;
    cs.gain_db = o.gain_db;
    gain_db = o.gain_db;
    auto c = drivers::AravisCamera::Open(cs);
    if (!c.ok()) return c.error();
    camera = std::move(*c);
    return OkStatus();
  }

  // Declared in dependency order: destroyed drivers first, then the servers, then what they read.
  std::unique_ptr<sim::ScaledClock> clock;
  std::unique_ptr<sim::SimulatedAxis> sample_axis, arm_axis;
  std::unique_ptr<sim::Lamp> lamp;
  std::unique_ptr<sim::Scene> scene;
  std::unique_ptr<sim::StageModbusTcpServer> tcp_server;
  std::unique_ptr<sim::SimulatedCamera> sim_camera;
  std::unique_ptr<sim::SimulatedPowerMeter> meter_device;
  std::unique_ptr<drivers::ScpiPowerMeter> meter;
  std::unique_ptr<drivers::StageController> stages;
  std::vector<drivers::AxisSettings> axes;
  std::unique_ptr<drivers::Camera> camera;
  double gain_db = 12;
};

}  // namespace gonio::testing
