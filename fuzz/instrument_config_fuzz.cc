// The instrument config (config/instrument.toml's format): refused naming file:line or loaded.
#include "config/instrument_config.h"
#include "fuzz/fuzz_support.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  (void)gonio::config::LoadInstrumentConfig(gonio::fuzz::AsFile(data, size, ".toml"));
  return 0;
}
