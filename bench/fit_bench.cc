// Time per fit (Google Benchmark): one normal-incidence sweep (179 samples, every degree) and one
// joint fit of four incidences (0, 30, 60, 80: 716 samples), per model, with the fitter's default
// options (width scan, automatic starts, autodiff). Counters: Ceres iterations of the winning
// local fit, and the number of local fits run.
#include <benchmark/benchmark.h>

#include "fitting/fitter.h"
#include "fitting/synthetic.h"

namespace {

using namespace gonio::fitting;

std::vector<Sample> Data(Family f, bool joint) {
  SyntheticSweep s;
  s.model.family = f;
  // Ground glass of Figure 12, in each family's own width unit.
  switch (f) {
    case Family::kBeckmann:
      s.width = 0.344, s.scale = 0.542;
      break;
    case Family::kGgx:
      s.width = 0.394, s.scale = 0.755;
      break;
    case Family::kPhong:
      s.width = *WidthFromAlphaEquivalent(Family::kPhong, 0.344), s.scale = 0.542;
      break;
    case Family::kSun2008:
      s.width = 2 / 0.344, s.scale = 0.542;
      break;
  }
  if (joint) s.theta_l_deg = {0, 30, 60, 80};
  return MakeSyntheticSweep(s);
}

void BM_Fit(benchmark::State& state, Family f, bool joint) {
  const auto data = Data(f, joint);
  FitOptions o;
  o.model.family = f;
  FitSummary last;
  for (auto _ : state) {
    auto r = Fit(data, o);
    if (!r.ok() || !r->ok()) {
      state.SkipWithError("fit failed");
      return;
    }
    last = *r;
  }
  state.counters["samples"] = static_cast<double>(data.size());
  state.counters["iterations"] = last.iterations;
  state.counters["local_fits"] = last.local_fits;
  state.SetLabel(joint ? "joint 0/30/60/80" : "normal incidence");
}

BENCHMARK_CAPTURE(BM_Fit, beckmann_normal, Family::kBeckmann, false)->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_Fit, ggx_normal, Family::kGgx, false)->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_Fit, phong_normal, Family::kPhong, false)->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_Fit, sun2008_normal, Family::kSun2008, false)->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_Fit, beckmann_joint, Family::kBeckmann, true)->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_Fit, ggx_joint, Family::kGgx, true)->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_Fit, phong_joint, Family::kPhong, true)->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(BM_Fit, sun2008_joint, Family::kSun2008, true)->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();
