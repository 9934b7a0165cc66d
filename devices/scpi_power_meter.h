// A SCPI optical power meter over USBTMC (Thorlabs PM100 family command set, docs/reference.md
// section 4): *IDN?, MEAS:POW?, SENS:CORR:WAV, SENS:AVER:COUN, SYST:ERR?. Settings are checked
// against the meter's error queue. When the meter leaves the bus, one reopen is tried before an
// error is returned. Each call is one exchange at a time (thread-safe).
#pragma once

#include <memory>
#include <mutex>

#include "devices/source_monitor.h"
#include "devices/usbtmc.h"

namespace gonio::devices {

class ScpiPowerMeter final : public SourceMonitor {
 public:
  // The transport must outlive the meter.
  explicit ScpiPowerMeter(UsbTmcTransport& transport, int timeout_ms = 1000)
      : tmc_(transport, timeout_ms) {}

  // Starts a session clean; call it once after opening. USBTMC INITIATE_CLEAR empties the
  // meter's buffers, where a client that died mid-query (a killed process) can have left a
  // response that the next query would read as its own; *CLS empties the error queue, so the
  // first setting's check reads only its own error.
  Status Clear();
  Result<std::string> Identity() override;
  Result<double> PowerW() override;
  Status SetWavelengthNm(double nm) override;
  Status SetAveraging(int count) override;
  Status CheckLink() override;
  // The first entry of the error queue ("0,\"No error\"" when empty).
  Result<std::string> NextError();

 private:
  Result<std::string> QueryWithReopen(const std::string& q);
  Status SetAndCheck(const std::string& command);
  UsbTmc tmc_;
  // One exchange with the meter at a time: the daemon's link watch queries it beside a run.
  std::recursive_mutex mu_;
};

}  // namespace gonio::devices
