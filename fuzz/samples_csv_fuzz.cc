// The fitter's samples CSV (the export's format, with its response line): refused naming
// file:line or read, never a crash.
#include <string_view>

#include "fitting/samples_csv.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  (void)gonio::fitting::ParseSamplesCsv(text, "fuzz.csv");
  return 0;
}
