// The simulated stage controller over Modbus RTU on a pseudo-terminal: the serial line that AZ
// drivers share on RS-485, with no hardware. The client opens pty_path() (or the stable symlink
// given to Start) with libmodbus RTU, or with mbpoll -m rtu; baud rate and parity are accepted and
// ignored, as a pty ignores them.
//
// As on a bus: axis k is slave k + 1; a frame for another slave, or with a bad CRC, gets no reply
// at all (the client times out); an address outside the map gets exception 0x02.
// Faults (per request, targeted by axis name): modbus_timeout (no reply), modbus_crc (the reply's
// CRC is corrupted, so the client reports "Invalid CRC").
#pragma once

#include <atomic>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "common/result.h"
#include "sim/clock.h"
#include "sim/faults/fault_plan.h"
#include "sim/stage/axis.h"

namespace gonio::sim {

// CRC-16/MODBUS (polynomial 0xA001 reflected, initial 0xFFFF); sent low byte first.
std::uint16_t ModbusCrc16(const std::uint8_t* data, std::size_t length);

class StageModbusRtuServer {
 public:
  // Opens a pty and serves on its own thread until destroyed. `link_path`, when not empty, is
  // made a symlink to the pty (replacing an old symlink, never a regular file). The axes (and
  // the plan and clock) must outlive the server.
  static Result<std::unique_ptr<StageModbusRtuServer>> Start(std::vector<SimulatedAxis*> axes,
                                                             std::string link_path = {},
                                                             FaultPlan* faults = nullptr,
                                                             const Clock* clock = nullptr);
  ~StageModbusRtuServer();  // stops and joins within ~50 ms, removes the symlink
  StageModbusRtuServer(const StageModbusRtuServer&) = delete;
  StageModbusRtuServer& operator=(const StageModbusRtuServer&) = delete;

  const std::string& pty_path() const { return pty_path_; }
  // The line's speed: each request and its reply take the time their characters (11 bits each:
  // start, 8 data, parity, stop) and the 3.5-character gaps after each would take on an RS-485
  // line at `baud`, and nothing else is served meanwhile (a half-duplex bus). 0 (the default):
  // a pty's speed. Set before the client starts.
  void SetLineRate(int baud) { baud_ = baud; }
  int requests() const { return requests_; }  // answered so far
  double line_busy_s() const {
    return line_busy_us_ * 1e-6;
  }  // the line's time so far (SetLineRate)

 private:
  StageModbusRtuServer() = default;
  void Loop();
  void Answer(const std::uint8_t* frame, int length);

  std::vector<SimulatedAxis*> axes_;
  FaultPlan* faults_ = nullptr;
  const Clock* clock_ = nullptr;
  void* ctx_ = nullptr;  // modbus_t* (RTU), writing into reply_[0]
  void* map_ = nullptr;  // modbus_mapping_t*
  int master_ = -1, slave_ = -1;
  int reply_[2] = {-1, -1};  // socketpair: libmodbus writes the reply, the loop forwards it
  std::string pty_path_, link_path_;
  std::atomic<bool> stop_{false};
  std::atomic<int> baud_{0};
  std::atomic<int> requests_{0};
  std::atomic<long long> line_busy_us_{0};
  std::thread thread_;
};

}  // namespace gonio::sim
