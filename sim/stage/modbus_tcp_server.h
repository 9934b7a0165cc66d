// The simulated stage controller over Modbus TCP (libmodbus), on the loopback interface only
// (docs/design.md network rules): a real protocol server that the real driver (#5) and
// third-party tools (mbpoll) talk to. Axis k answers unit identifier k + 1, with the register map
// of docs/stage_register_map.md; an unknown unit gets exception 0x0B (gateway target failed to
// respond), an address outside the map exception 0x02, as a real gateway would.
#pragma once

#include <atomic>
#include <memory>
#include <thread>
#include <vector>

#include "common/result.h"
#include "sim/clock.h"
#include "sim/faults/fault_plan.h"
#include "sim/stage/axis.h"

namespace gonio::sim {

class StageModbusTcpServer {
 public:
  // Binds 127.0.0.1:port (0: the OS picks a free port, see port()) and serves on its own thread
  // until destroyed. The axes (and the fault plan and clock, when given) must outlive the server.
  // Faults (per request, targeted by axis name): modbus_timeout (no reply), modbus_drop (the
  // connection is closed).
  static Result<std::unique_ptr<StageModbusTcpServer>> Start(std::vector<SimulatedAxis*> axes,
                                                             int port = 0,
                                                             FaultPlan* faults = nullptr,
                                                             const Clock* clock = nullptr);
  ~StageModbusTcpServer();  // stops and joins within ~50 ms
  StageModbusTcpServer(const StageModbusTcpServer&) = delete;
  StageModbusTcpServer& operator=(const StageModbusTcpServer&) = delete;

  int port() const { return port_; }

 private:
  StageModbusTcpServer() = default;
  void Loop();

  std::vector<SimulatedAxis*> axes_;
  FaultPlan* faults_ = nullptr;
  const Clock* clock_ = nullptr;
  void* ctx_ = nullptr;  // modbus_t*, kept opaque so the header needs no libmodbus
  int listen_fd_ = -1;
  int port_ = 0;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

}  // namespace gonio::sim
