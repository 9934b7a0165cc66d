// A schedule's TOML text with one plan it may name: refused or parsed, never a crash.
#include <map>
#include <string_view>

#include "daemon/schedule/schedule.h"
#include "fuzz/fuzz_support.h"

namespace {
constexpr const char* kPlan = R"(sample = "ground-glass-G1"
[geometry]
incidence_deg = [0]
view_about = "refracted"
view_from_deg = -5
view_to_deg = 5
view_step_deg = 5
[exposure]
frames = 2
[rectangle]
x = 253
y = 246
width = 6
height = 19
)";
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const gonio::acquisition::PlanContext context = gonio::fuzz::Context();
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  (void)gonio::daemon::PlanReferences(text, "fuzz.toml");
  const std::map<std::string, std::string> plans = {{"plan.toml", kPlan}};
  gonio::daemon::EstimateBasis basis;
  basis.history = [](const std::string&) { return std::nullopt; };
  (void)gonio::daemon::ParseSchedule(text, "fuzz.toml", plans, context, basis);
  return 0;
}
