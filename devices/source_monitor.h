// The source monitor as acquisition sees it: an optical power meter watching the lamp, so that
// samples can be normalised by the source's output. Optional on a bench: a config without one
// gives no SourceMonitor at all.
#pragma once

#include <string>

#include "common/result.h"

namespace gonio::devices {

class SourceMonitor {
 public:
  virtual ~SourceMonitor() = default;
  // "maker,model,serial,firmware" (SCPI *IDN?).
  virtual Result<std::string> Identity() = 0;
  // One reading in watts, averaged over the meter's averaging count. Errors: kNotConnected when
  // the meter left the bus and could not be reopened, kTimeout, kProtocol (a SCPI error).
  virtual Result<double> PowerW() = 0;
  // Wavelength correction (nm) and averaging count; refused values give kInvalidArgument with
  // the meter's own SCPI error text.
  virtual Status SetWavelengthNm(double nm) = 0;
  virtual Status SetAveraging(int count) = 0;
  // Whether the meter answers (SCPI *IDN?), safe beside a reading on another thread (the
  // daemon's link watch). OK for a meter that cannot tell.
  virtual Status CheckLink() { return OkStatus(); }
};

}  // namespace gonio::devices
