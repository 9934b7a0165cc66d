// The adaptive forecast against real runs (issue #17's estimate, #16's note): the etched glass is
// measured once on the simulated instrument and fitted into the bench's throughput and noise
// calibration; then the ground glass, never measured, is run adaptively to its target once per
// seed of the instrument's noise (the camera's, the lamp's, the meter's), each run on a copy of
// that store so that each is priced as a first run. Each run's stored estimate (the point
// simulator's median of 20 simulated runs) is set against the exposure the run took.
// EstimateBeforeTheFirstRun checks one realisation (seed 1) to 30 %; this shows the spread of the
// realisations.
//
//   build-release/bench/forecast_spread [runs=8] [clock_speed=300]
//   FORECAST_KEEP=DIR keeps each seed's store there (seed_N.sqlite: its runs, choices and events)
//   ./scripts/bench.sh forecast
//
// Holds the GigE Vision port 3956 while it runs (one simulated camera per machine).
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "sim/truth/ground_truth.h"
#include "tests/support/forecast_case.h"

using namespace gonio;
using namespace gonio::acquisition;

namespace {

int Usage() {
  std::fprintf(stderr, "usage: forecast_spread [runs=8 (1-100)] [clock_speed=300 (10-1000)]\n");
  return 2;
}

bool ParseNumber(const char* text, double lo, double hi, double* out) {
  char* end = nullptr;
  const double v = std::strtod(text, &end);
  if (end == text || *end != '\0' || !(v >= lo && v <= hi)) return false;
  *out = v;
  return true;
}

double Quantile(std::vector<double> v, double q) {
  std::sort(v.begin(), v.end());
  const double at = q * static_cast<double>(v.size() - 1);
  const auto i = static_cast<std::size_t>(at);
  if (i + 1 >= v.size()) return v.back();
  return v[i] + (at - static_cast<double>(i)) * (v[i + 1] - v[i]);
}

void RemoveStore(const std::string& path) {
  for (const char* ext : {"", "-wal", "-shm"}) std::filesystem::remove(path + ext);
}

}  // namespace

int main(int argc, char** argv) {
  double runs_d = 8, speed = 300;
  if (argc > 3 || (argc > 1 && !ParseNumber(argv[1], 1, 100, &runs_d)) ||
      (argc > 2 && !ParseNumber(argv[2], 10, 1000, &speed)) || runs_d != static_cast<int>(runs_d))
    return Usage();
  const int runs = static_cast<int>(runs_d);
  // Where each seed's store is kept (FORECAST_KEEP): made now, so that a bad path stops the
  // bench before its hour of runs rather than after the first.
  std::string keep_dir;
  if (const char* keep = std::getenv("FORECAST_KEEP"); keep != nullptr && *keep != '\0') {
    keep_dir = keep;
    std::error_code ec;
    std::filesystem::create_directories(keep_dir, ec);
    if (ec || !std::filesystem::is_directory(keep_dir))
      return std::fprintf(stderr, "FORECAST_KEEP=%s: not a directory we can make (%s)\n",
                          keep_dir.c_str(), ec ? ec.message().c_str() : "a file is in the way"),
             2;
  }
  const std::string base = (std::filesystem::temp_directory_path() /
                            ("gonio_forecast_" + std::to_string(::getpid()) + ".sqlite"))
                               .string();
  const EngineOptions eo{.linear_limit_adu = 65000};

  {  // The throughput: the etched glass, measured and fitted, in a store of its own, then closed.
    RemoveStore(base);
    auto opened = Storage::Open(base);
    if (!opened.ok()) return std::fprintf(stderr, "%s\n", opened.error().message.c_str()), 1;
    gonio::testing::SimInstrument inst;
    gonio::testing::SimInstrumentOptions o;
    o.clock_speed = speed;
    o.truth = sim::MicrofacetTruth("beckmann", 0.493, 1.51);
    if (Status st = inst.Start(o); !st.ok())
      return std::fprintf(stderr, "the simulated instrument: %s\n", st.error().message.c_str()), 1;
    auto etched = gonio::testing::MeasureThroughputRun(**opened, inst, base, eo);
    if (!etched.ok())
      return std::fprintf(stderr, "the etched glass's run: %s\n", etched.error().message.c_str()),
             1;
    std::fprintf(stderr, "the throughput run: %.0f s of exposure\n", etched->exposure_s);
  }

  std::printf("# The adaptive forecast against real runs\n\n");
  std::printf(
      "The ground glass (Beckmann alpha 0.344) run adaptively to sigma(alpha)/alpha 5e-5 on the "
      "simulated instrument at x%.0f, once per noise seed, each priced before it starts on the "
      "etched glass's run. Command: `build-release/bench/forecast_spread %d %.0f`.\n\n",
      speed, runs, speed);
  std::printf(
      "| seed | forecast exposure s | run exposure s | forecast / run | points | "
      "points at >= 5 s | outcome |\n|---|---|---|---|---|---|---|\n");
  std::vector<double> ratios, exposures;
  std::string basis;
  double forecast_s = 0;
  for (int seed = 1; seed <= runs; ++seed) {
    const std::string path = base + "." + std::to_string(seed);
    RemoveStore(path);
    std::error_code copied;
    std::filesystem::copy_file(base, path, copied);
    if (copied)
      return std::fprintf(stderr, "seed %d: copying the store: %s\n", seed,
                          copied.message().c_str()),
             1;
    auto opened = Storage::Open(path);
    if (!opened.ok()) return std::fprintf(stderr, "%s\n", opened.error().message.c_str()), 1;
    Storage& store = **opened;
    gonio::testing::SimInstrument inst;
    gonio::testing::SimInstrumentOptions o;
    o.clock_speed = speed;
    o.seed = static_cast<std::uint64_t>(seed);
    if (Status st = inst.Start(o); !st.ok())
      return std::fprintf(stderr, "the simulated instrument: %s\n", st.error().message.c_str()), 1;
    auto planned = gonio::testing::ForecastPlan(path, "ground-glass-G1", inst.axes,
                                                gonio::testing::kForecastAdaptive);
    if (!planned.ok()) return std::fprintf(stderr, "%s\n", planned.error().message.c_str()), 1;
    EngineOptions with_axes = eo;
    with_axes.axes = inst.axes;
    auto m =
        gonio::testing::MeasureAsGoniod(store, inst, planned->first, planned->second, with_axes);
    if (!m.ok()) return std::fprintf(stderr, "seed %d: %s\n", seed, m.error().message.c_str()), 1;
    auto info = store.GetRun(m->run);
    auto rows = store.Measurements(m->run);
    auto events = store.Events(m->run);
    if (!info.ok() || !info->estimate || !info->exposed_s || !rows.ok() || !events.ok())
      return std::fprintf(stderr, "seed %d: the run's record is incomplete\n", seed), 1;
    std::string outcome = "(no adaptive event)";
    for (const RunEvent& e : *events)
      if (e.kind == "adaptive") outcome = e.detail;
    const auto long_points = std::count_if(rows->begin(), rows->end(),
                                           [](const auto& r) { return r.m.exposure_s >= 5; });
    forecast_s = info->estimate->exposure_s;
    basis = info->estimate->basis;
    const double ratio = forecast_s / *info->exposed_s;
    ratios.push_back(ratio);
    exposures.push_back(*info->exposed_s);
    std::printf("| %d | %.0f | %.0f | %.2f | %zu | %td | %s |\n", seed, forecast_s,
                *info->exposed_s, ratio, rows->size(), long_points, outcome.c_str());
    std::fflush(stdout);
    opened->reset();
    if (!keep_dir.empty()) {
      const std::string kept = keep_dir + "/seed_" + std::to_string(seed) + ".sqlite";
      RemoveStore(kept);
      std::error_code ec;
      std::filesystem::copy_file(path, kept, ec);
      if (ec)
        std::fprintf(stderr, "seed %d: not kept at %s: %s\n", seed, kept.c_str(),
                     ec.message().c_str());
    }
    RemoveStore(path);
  }
  RemoveStore(base);
  const auto within =
      std::count_if(ratios.begin(), ratios.end(), [](double r) { return r >= 0.7 && r <= 1.3; });
  std::printf(
      "\nThe forecast (the same each seed, made before the run from the etched glass's run): "
      "%s.\n\nThe runs' exposure: median %.0f s, 10-90 %% %.0f-%.0f s; forecast / run: median "
      "%.2f, range %.2f-%.2f; %td of %d within the test's 0.7-1.3.\n",
      basis.c_str(), Quantile(exposures, 0.5), Quantile(exposures, 0.1), Quantile(exposures, 0.9),
      Quantile(ratios, 0.5), *std::min_element(ratios.begin(), ratios.end()),
      *std::max_element(ratios.begin(), ratios.end()), within, runs);
  return 0;
}
