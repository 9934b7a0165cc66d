// The simulated source monitor: a USBTMC optical power meter (PM100USB-like SCPI, docs/reference.md
// section 4) watching the lamp, below the transport layer that libusb would provide. It speaks the
// device side of USBTMC - bulk headers, bTag checks, responses split to the host's requested size,
// the abort and clear class requests, the clear's halt of bulk-out until the host clears it - so
// the driver's own framing (devices/usbtmc.h) runs unchanged against it.
//
// SCPI (case-insensitive, short or long forms): *IDN?, *RST, *CLS, MEAS[:SCAL]:POW? (W),
// SENS:CORR:WAV <nm> / ? (400-1100), SENS:AVER[:COUN] <n> / ? (1-10000), SYST:ERR? (-113
// undefined header, -222 data out of range, -410 a new command before a response was read: IEEE
// 488.2's query INTERRUPTED, which discards the response). A reading is the lamp's power averaged
// over n samples of 1 ms ending now, with the meter's own noise (1e-4 relative per sample).
//
// Faults: monitor_disconnect (opportunity: each bulk-out) - the meter leaves the bus for the
// event's duration: every call returns kNotConnected ("LIBUSB_ERROR_NO_DEVICE"), and Reopen
// succeeds only after the meter is back (with its state reset, as after re-enumeration).
#pragma once

#include <cstdint>
#include <deque>
#include <mutex>
#include <optional>
#include <random>
#include <string>

#include "devices/usbtmc_transport.h"
#include "sim/clock.h"
#include "sim/faults/fault_plan.h"
#include "sim/scene/lamp.h"

namespace gonio::sim {

struct PowerMeterOptions {
  std::string serial = "SIM-PM-1";
  double noise_rel = 1e-4;  // per 1 ms sample
  double sample_s = 1e-3;
};

class SimulatedPowerMeter final : public devices::UsbTmcTransport {
 public:
  // The clock, lamp and plan (may be null) must outlive the meter.
  SimulatedPowerMeter(const Clock& clock, const Lamp& lamp, PowerMeterOptions options = {},
                      std::uint64_t seed = 1, FaultPlan* faults = nullptr);

  Status BulkOut(const std::uint8_t* data, std::size_t n, int timeout_ms) override;
  Result<std::size_t> BulkIn(std::uint8_t* data, std::size_t capacity, int timeout_ms) override;
  Result<std::vector<std::uint8_t>> ClassRequest(std::uint8_t request, std::uint16_t value,
                                                 std::uint16_t length, int timeout_ms) override;
  Status ClearHalt(devices::UsbTmcEndpoint endpoint) override;
  Status Reopen() override;

  double wavelength_nm() const;
  int averaging() const;

 private:
  Status Present(double now);  // kNotConnected while away
  void Execute(const std::string& line, double now);
  void Reset();

  const Clock& clock_;
  const Lamp& lamp_;
  PowerMeterOptions o_;
  FaultPlan* faults_;
  mutable std::mutex mu_;
  std::mt19937_64 rng_;
  double away_until_ = -1;
  bool needs_reopen_ = false;
  bool bulk_out_halted_ = false;        // from INITIATE_CLEAR until the host clears the halt
  std::string input_;                   // DEV_DEP_MSG_OUT payload until a newline
  std::string output_;                  // response bytes not yet read
  std::optional<std::uint8_t> in_tag_;  // the pending REQUEST_DEV_DEP_MSG_IN
  std::uint32_t in_max_ = 0;
  std::deque<std::string> errors_;
  double wavelength_nm_ = 633;
  int averaging_ = 1;
};

}  // namespace gonio::sim
