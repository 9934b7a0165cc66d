// gonio-sim's config (config/sim.toml's format): refused naming file:line or loaded.
#include "fuzz/fuzz_support.h"
#include "sim/sim_config.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  (void)gonio::sim::LoadSimConfig(gonio::fuzz::AsFile(data, size, ".toml"));
  return 0;
}
