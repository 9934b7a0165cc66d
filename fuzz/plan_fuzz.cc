// A plan's TOML text, as goniod receives it: refused with a message or loaded, never a crash.
#include <string_view>

#include "fuzz/fuzz_support.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const gonio::acquisition::PlanContext context = gonio::fuzz::Context();
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  auto plan = gonio::acquisition::LoadPlanText(text, "fuzz.toml", context);
  if (plan.ok()) (void)gonio::acquisition::ExpandPoints(*plan, context);
  return 0;
}
