// The simulated instrument, whole, from a SimConfig: the rotation stages behind Modbus TCP (and
// Modbus RTU on a pty when configured), the cooled CCD on GigE Vision, the source monitor (a USBTMC
// device, also served over the loopback socket), the lamp, the scene with its ground truth and
// the fault plan, all on one clock. gonio-sim serves one; tests and benchmarks start one
// in-process and reach it through the real backends, with ClientConfig() saying how.
//
// One GigE camera per machine (GVCP's port 3956): an instrument with its camera enabled needs
// the CTest resource lock "gvcp" in tests.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "common/result.h"
#include "config/instrument_config.h"
#include "sim/camera/camera.h"
#include "sim/clock.h"
#include "sim/faults/fault_plan.h"
#include "sim/monitor/monitor_server.h"
#include "sim/monitor/power_meter.h"
#include "sim/scene/lamp.h"
#include "sim/scene/scene.h"
#include "sim/sim_config.h"
#include "sim/stage/axis.h"
#include "sim/stage/modbus_rtu_server.h"
#include "sim/stage/modbus_tcp_server.h"
#include "sim/truth/ground_truth.h"

namespace gonio::sim {

class Instrument {
 public:
  // Starts every device the config enables; the first that does not come up is the error (and
  // what had started is stopped). `truth` replaces the config's microfacet sample when set.
  static Result<std::unique_ptr<Instrument>> Start(
      SimConfig config, std::shared_ptr<const GroundTruth> truth = nullptr);
  ~Instrument();  // the camera first (it reads the stages), then the servers, then the devices
  Instrument(const Instrument&) = delete;
  Instrument& operator=(const Instrument&) = delete;

  // What a client needs to reach this instrument through the real backends: the camera's
  // address, the Modbus TCP port, each axis's unit id and gearing (as sim.toml and
  // instrument.toml mirror each other), its travel limits from the axis's soft limits, and the
  // monitor's socket. Motion settings (speed, tolerance, backlash) are the client's defaults.
  config::InstrumentConfig ClientConfig() const;

  const SimConfig& config() const { return config_; }
  const Clock& clock() const { return *clock_; }
  FaultPlan& faults() { return *faults_; }
  const Lamp& lamp() const { return *lamp_; }
  const Scene& scene() const { return *scene_; }
  // The axes in the order of config().axes.
  const std::vector<std::unique_ptr<SimulatedAxis>>& axes() const { return axes_; }
  StageAngles Angles() const;  // what the stages show the camera now
  int modbus_port() const { return modbus_port_; }
  // The stages' Modbus TCP server goes away (its connections close, nothing listens on its
  // port) and comes back on the same port: a gateway or controller power-cycled while the axes
  // keep their state. Start is an error when the port is taken meanwhile.
  void StopStageServer();
  Status StartStageServer();
  const StageModbusRtuServer* rtu() const { return rtu_.get(); }
  SimulatedCamera* camera() { return camera_.get(); }                    // null when disabled
  SimulatedPowerMeter* meter() { return meter_.get(); }                  // null when disabled
  const MonitorSocketServer* monitor() const { return monitor_.get(); }  // null when disabled

 private:
  explicit Instrument(SimConfig config) : config_(std::move(config)) {}

  // Declared in dependency order, so that members go in reverse: servers before what they serve.
  SimConfig config_;
  std::unique_ptr<ScaledClock> clock_;
  std::unique_ptr<FaultPlan> faults_;
  std::vector<std::unique_ptr<SimulatedAxis>> axes_;
  std::unique_ptr<Lamp> lamp_;
  std::unique_ptr<Scene> scene_;
  std::unique_ptr<SimulatedPowerMeter> meter_;
  std::unique_ptr<StageModbusTcpServer> tcp_;
  int modbus_port_ = 0;
  std::unique_ptr<StageModbusRtuServer> rtu_;
  std::unique_ptr<MonitorSocketServer> monitor_;
  std::unique_ptr<SimulatedCamera> camera_;
};

}  // namespace gonio::sim
