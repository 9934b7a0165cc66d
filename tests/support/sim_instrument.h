// The simulated instrument in-process (sim::Instrument), reached through the real backends the
// way goniod reaches it (daemon::OpenInstrument on the instrument's ClientConfig): two axes over
// Modbus TCP on 127.0.0.1, the cooled CCD over GigE Vision (Aravis's fake camera), the source
// monitor over the USBTMC socket transport. For tests and benchmarks of what sits on the device
// interfaces (the engine, the daemon).
// One GigE camera per machine: tests using it hold the CTest resource lock "gvcp".
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <vector>

#include "daemon/instrument/instrument.h"
#include "sim/instrument.h"
#include "sim/truth/ground_truth.h"

namespace gonio::testing {

struct SimInstrumentOptions {
  double clock_speed = 300;
  double gain_db = 12;  // more counts per electron: the stray floor is reached sooner
  sim::LampOptions lamp{.drift_per_hour = 0, .wander_amplitude = 0, .flicker_rms = 0};
  std::shared_ptr<const sim::GroundTruth> truth;  // null: Walter 2007's ground glass
  std::vector<sim::FaultEvent> faults;            // injected by the simulated devices
  double frame_timeout_s = 5;                     // the camera driver's, beyond the exposure
  // A third axis: the beam block's flag (role "beam_block", unit 3), out at 0 deg, in at 90.
  bool beam_block = false;
  // The noise's seed: the lamp's, the meter's and the camera's (its sensor's draws and hot pixels),
  // as gonio-sim's [clock] seed. One seed, one realisation of every run on the instrument.
  std::uint64_t seed = 1;
};

class SimInstrument {
 public:
  // Starts the devices and opens the backends on them; the first that does not come up is the
  // error.
  Status Start(const SimInstrumentOptions& o) {
    sim::SimConfig c = sim::TwoAxisConfig(o.clock_speed);
    c.lamp = o.lamp;
    c.faults = o.faults;
    c.seed = c.camera.seed = o.seed;
    if (o.beam_block) {
      sim::AxisConfig flag{
          .role = "beam_block", .steps_per_degree = 100, .degrees_at_zero = 0, .options = {}};
      flag.options.min_steps = 0;
      flag.options.max_steps = 18'000;
      flag.options.latched_inputs = true;
      flag.options.ready_delay_s = 0.05;
      c.axes.push_back(flag);
    }
    auto started = sim::Instrument::Start(
        c, o.truth ? o.truth : sim::MicrofacetTruth("beckmann", 0.344, 1.51));
    if (!started.ok()) return started.error();
    simulated = std::move(started).value();

    // The client's side: the limits are the axes' own; the speeds these tests were written for.
    config::InstrumentConfig client = simulated->ClientConfig();
    client.camera.gain_db = o.gain_db;
    client.camera.frame_timeout_s = o.frame_timeout_s;
    client.monitor.averaging = 100;
    for (devices::AxisSettings& a : client.axes) a.speed_deg_s = 30, a.acceleration_deg_s2 = 300;
    auto opened = daemon::OpenInstrument(client, {});
    if (!opened.ok()) return opened.error();
    opened_ = std::move(opened).value();
    clock = &simulated->clock();
    scene = &simulated->scene();
    sim_camera = simulated->camera();
    stages = opened_.stages.get();
    camera = opened_.camera.get();
    meter = opened_.monitor.monitor.get();
    axes = client.axes;
    beam_block = client.beam_block;
    gain_db = o.gain_db;
    return OkStatus();
  }

  ~SimInstrument() {
    // The backends close before the devices they talk to stop; the meter before its transport.
    opened_.monitor.monitor.reset();
    opened_ = {};
    simulated.reset();
  }

  std::unique_ptr<sim::Instrument> simulated;
  daemon::Instrument opened_;
  // Views of the two, named as the tests use them.
  const sim::Clock* clock = nullptr;
  const sim::Scene* scene = nullptr;
  sim::SimulatedCamera* sim_camera = nullptr;
  devices::StageController* stages = nullptr;
  devices::Camera* camera = nullptr;
  devices::SourceMonitor* meter = nullptr;
  std::vector<devices::AxisSettings> axes;
  std::optional<devices::BeamBlockSettings> beam_block;  // with the option
  double gain_db = 12;
};

}  // namespace gonio::testing
