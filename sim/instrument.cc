#include "sim/instrument.h"

#include <algorithm>
#include <utility>

namespace gonio::sim {

Result<std::unique_ptr<Instrument>> Instrument::Start(SimConfig config,
                                                      std::shared_ptr<const GroundTruth> truth) {
  std::unique_ptr<Instrument> in(new Instrument(std::move(config)));
  const SimConfig& c = in->config_;
  in->clock_ = std::make_unique<ScaledClock>(c.clock_speed);
  in->faults_ = std::make_unique<FaultPlan>(c.faults, c.fault_seed);
  std::vector<SimulatedAxis*> raw;
  for (const AxisConfig& a : c.axes) {
    in->axes_.push_back(
        std::make_unique<SimulatedAxis>(*in->clock_, a.options, a.role, in->faults_.get()));
    raw.push_back(in->axes_.back().get());
  }
  in->lamp_ = std::make_unique<Lamp>(c.lamp, c.seed);
  if (!truth) truth = MicrofacetTruth(c.sample_model, c.sample_alpha, c.sample_eta);
  in->scene_ = std::make_unique<Scene>(c.bench, std::move(truth), c.scene);

  auto tcp = StageModbusTcpServer::Start(raw, c.modbus_port, in->faults_.get(), in->clock_.get());
  if (!tcp.ok()) return tcp.error();
  in->tcp_ = std::move(tcp).value();
  in->modbus_port_ = in->tcp_->port();
  if (!c.rtu_link.empty()) {
    auto rtu = StageModbusRtuServer::Start(raw, c.rtu_link, in->faults_.get(), in->clock_.get());
    if (!rtu.ok()) return rtu.error();
    in->rtu_ = std::move(rtu).value();
  }
  if (c.monitor_enabled) {
    in->meter_ = std::make_unique<SimulatedPowerMeter>(*in->clock_, *in->lamp_, c.monitor, c.seed,
                                                       in->faults_.get());
    auto m = MonitorSocketServer::Start(*in->meter_, c.monitor_port);
    if (!m.ok()) return m.error();
    in->monitor_ = std::move(m).value();
  }
  if (c.camera_enabled) {
    const Instrument* self = in.get();
    auto cam = SimulatedCamera::StartGigE(
        *in->clock_, *in->scene_, [self] { return self->Angles(); }, *in->lamp_, c.camera,
        in->faults_.get());
    if (!cam.ok()) return cam.error();
    in->camera_ = std::move(cam).value();
  }
  return in;
}

Instrument::~Instrument() {
  camera_.reset();  // the camera's firmware reads the stages: stop it before anything else
  monitor_.reset();
  rtu_.reset();
  tcp_.reset();
}

void Instrument::StopStageServer() { tcp_.reset(); }

Status Instrument::StartStageServer() {
  if (tcp_) return OkStatus();
  std::vector<SimulatedAxis*> raw;
  for (const auto& a : axes_) raw.push_back(a.get());
  auto tcp = StageModbusTcpServer::Start(raw, modbus_port_, faults_.get(), clock_.get());
  if (!tcp.ok()) return tcp.error();
  tcp_ = std::move(tcp).value();
  return OkStatus();
}

StageAngles Instrument::Angles() const {
  std::vector<double> steps;
  steps.reserve(axes_.size());
  for (const auto& a : axes_) steps.push_back(a->PositionSteps());
  return AnglesFromSteps(config_.axes, steps);
}

config::InstrumentConfig Instrument::ClientConfig() const {
  config::InstrumentConfig c;
  c.camera_enabled = camera_ != nullptr;
  c.camera.address = config_.camera.address;
  c.stage_link.kind = devices::ModbusTransport::kTcp;
  c.stage_link.host = "127.0.0.1";
  c.stage_link.port = modbus_port_;
  for (std::size_t k = 0; k < config_.axes.size(); ++k) {
    const AxisConfig& a = config_.axes[k];
    devices::AxisSettings s;
    s.name = a.role;
    s.slave_id = static_cast<int>(k) + 1;  // unit id = position in the config + 1
    s.steps_per_degree = a.steps_per_degree;
    s.degrees_at_zero = a.degrees_at_zero;
    const double lo = a.degrees_at_zero + a.options.min_steps / a.steps_per_degree;
    const double hi = a.degrees_at_zero + a.options.max_steps / a.steps_per_degree;
    s.min_deg = std::min(lo, hi);
    s.max_deg = std::max(lo, hi);
    c.axes.push_back(s);
    // The flag covers the beam from 45 to 135 deg (sim_config.h): out at 0, in at 90.
    if (a.role == "beam_block") c.beam_block = devices::BeamBlockSettings{0, 90};
  }
  c.monitor.enabled = monitor_ != nullptr;
  c.monitor.transport = config::MonitorTransport::kSocket;
  c.monitor.host = "127.0.0.1";
  if (monitor_) c.monitor.port = monitor_->port();
  return c;
}

}  // namespace gonio::sim
