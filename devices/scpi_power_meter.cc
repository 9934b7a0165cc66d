#include "devices/scpi_power_meter.h"

#include <cerrno>
#include <cstdlib>
#include <sstream>

namespace gonio::devices {

Result<std::string> ScpiPowerMeter::QueryWithReopen(const std::string& q) {
  std::lock_guard lock(mu_);
  auto r = tmc_.Query(q);
  if (r.ok() || r.error().code != ErrorCode::kNotConnected) return r;
  // The meter left the bus (a cable, a hub reset): reopen once and retry the query.
  if (Status s = tmc_.Reopen(); !s.ok())
    return Error{ErrorCode::kNotConnected,
                 "source monitor disconnected, reopen failed: " + s.error().message};
  return tmc_.Query(q);
}

Status ScpiPowerMeter::Clear() {
  std::lock_guard lock(mu_);
  if (Status s = tmc_.Clear(); !s.ok())
    return Error{s.error().code, "source monitor: clearing it failed: " + s.error().message};
  return tmc_.Write("*CLS");
}

Result<std::string> ScpiPowerMeter::Identity() { return QueryWithReopen("*IDN?"); }

Status ScpiPowerMeter::CheckLink() {
  auto r = Identity();
  return r.ok() ? OkStatus() : Status(r.error());
}

Result<std::string> ScpiPowerMeter::NextError() { return QueryWithReopen("SYST:ERR?"); }

Result<double> ScpiPowerMeter::PowerW() {
  auto r = QueryWithReopen("MEAS:POW?");
  if (!r.ok()) return r.error();
  const char* begin = r->c_str();
  char* end = nullptr;
  errno = 0;
  const double w = std::strtod(begin, &end);
  if (end == begin || errno != 0)
    return Error{ErrorCode::kProtocol, "source monitor: MEAS:POW? answered '" + *r + "'"};
  return w;
}

Status ScpiPowerMeter::SetAndCheck(const std::string& command) {
  std::lock_guard lock(mu_);  // the write and its error query together
  if (Status s = tmc_.Write(command); !s.ok()) return s;
  auto e = NextError();
  if (!e.ok()) return e.error();
  if (e->rfind("0,", 0) == 0 || e->rfind("+0,", 0) == 0) return OkStatus();
  return Error{ErrorCode::kInvalidArgument, "source monitor refused '" + command + "': " + *e};
}

Status ScpiPowerMeter::SetWavelengthNm(double nm) {
  std::ostringstream s;
  s << "SENS:CORR:WAV " << nm;
  return SetAndCheck(s.str());
}

Status ScpiPowerMeter::SetAveraging(int count) {
  return SetAndCheck("SENS:AVER:COUN " + std::to_string(count));
}

}  // namespace gonio::devices
