// The stage controller over Modbus (libmodbus), TCP or RTU. The register map is a profile from the
// config, not constants: StageRegisterProfile's defaults are the map that the simulated
// controller implements (docs/stage_register_map.md, after Oriental Motor AZ direct data).
//
// Bus faults: a request that times out or fails its CRC is retried (up to `retries` times); a
// dropped TCP connection is reconnected and the request retried; a Modbus exception is a protocol
// error and is not retried. Alarms and limit switches are kDeviceFault at once.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <string>

#include "devices/stage.h"

namespace gonio::backends {

using devices::AxisSettings;
using devices::AxisStatus;
using devices::ModbusLink;
using devices::StageController;
using devices::StageRegisterProfile;

class ModbusStageController final : public StageController {
 public:
  // Connects and checks every axis answers its status. Errors name the link and the axis.
  static Result<std::unique_ptr<ModbusStageController>> Open(ModbusLink link,
                                                             std::vector<AxisSettings> axes,
                                                             StageRegisterProfile profile = {});
  ~ModbusStageController() override;

  const std::vector<AxisSettings>& axes() const override { return axes_; }
  Status MoveTo(const std::vector<std::pair<std::string, double>>& targets) override;
  Status Home(const std::vector<std::string>& names = {}) override;
  Status StopAll() override;
  Result<AxisStatus> ReadStatus(const std::string& name) override;
  Status ResetAlarm(const std::string& name) override;
  // A status read of the first axis, as StageController's; but a request already retrying after
  // a lost connection (which holds the bus through its retries and reconnects, for seconds) is
  // the answer at once: the link watch does not wait behind it to learn what it already shows.
  Status CheckLink() override;

  // How many requests were retried, and reconnections made (for logs and tests).
  int retried() const { return retried_; }
  int reconnects() const { return reconnects_; }
  int Reconnections() const override { return reconnects_; }

 private:
  ModbusStageController() = default;
  Result<const AxisSettings*> Find(const std::string& name) const;
  Status Connect();
  // One request with the retry policy; `what` names it in errors.
  Status Read(const AxisSettings& a, std::uint16_t address, int count, std::uint16_t* out,
              const std::string& what);
  Status Write(const AxisSettings& a, std::uint16_t address, int count, const std::uint16_t* values,
               const std::string& what);
  Status Write32(const AxisSettings& a, std::uint16_t address, std::uint32_t v,
                 const std::string& what);
  Status StartMove(const AxisSettings& a, double deg);
  // Waits until every axis in `list` satisfies `done` (IN-POS, or HOME-END), failing on alarms.
  Status WaitAll(const std::vector<const AxisSettings*>& list, bool homing, double timeout_s,
                 const std::vector<double>& targets_deg);
  std::string AlarmText(const AxisSettings& a, std::uint32_t code) const;
  // Status bits and alarm (one request), and positions (commanded and feedback: one request when
  // they lie within 8 registers of each other).
  Result<AxisStatus> ReadBits(const AxisSettings& a);
  Status ReadPositions(const AxisSettings& a, AxisStatus& s);
  // Polls until the axis is READY (profile's ready_timeout_s); `before` names what waits.
  Status WaitReady(const AxisSettings& a, const char* before);
  // An input command (or the alarm reset) as the profile says the controller takes it.
  Status Command(const AxisSettings& a, std::uint16_t address, std::uint32_t value,
                 const std::string& what);
  std::chrono::microseconds PollInterval() const;
  std::string BitsText(const AxisStatus& s) const;
  // What a status read saw last, per axis, for the message when the link is lost for good.
  void Remember(const AxisSettings& a, const AxisStatus& s, bool positions);
  std::string LastKnown();
  Error Lost(const Error& e);  // a link failure mid-move: STOP tried, the message completed

  ModbusLink link_;
  std::vector<AxisSettings> axes_;
  StageRegisterProfile p_;
  // One request on the bus at a time; recursive, so that CheckLink holds it (taken with a
  // timeout, watching for a retry meanwhile) through the status read's own requests.
  std::recursive_timed_mutex mu_;
  // Set while a request retries after a lost connection, with what it saw.
  std::atomic<bool> retrying_{false};
  std::mutex retrying_mu_;
  std::string retrying_why_;  // under retrying_mu_
  void* ctx_ = nullptr;       // modbus_t*
  int retried_ = 0;
  std::atomic<int> reconnects_{0};  // read by the engine's readout thread (Reconnections)
  std::map<std::string, AxisStatus> last_known_;  // under mu_

  template <typename Op>
  Status WithRetries(const std::string& what, Op op);
};

}  // namespace gonio::backends
