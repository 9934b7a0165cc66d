// Evaluations per second of the optics layer: D, G1 (exact vs rational), and the whole BTDF, per
// distribution. Each G1 benchmark also reports its maximum relative error against the exact
// Beckmann G1 (counter max_rel_err), so one run gives both axes of the speed/accuracy chart
// (bench/plot_g1_tradeoff.py).
#include <benchmark/benchmark.h>

#include <cmath>
#include <random>
#include <vector>

#include "fitting/optics/microfacet.h"
#include "fitting/optics/sun2008.h"

namespace {

using namespace gonio::optics;

constexpr int kBatch = 4096;

std::vector<Vec3<double>> Directions(bool upper, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  std::vector<Vec3<double>> w(kBatch);
  for (auto& v : w) {
    const double z = 0.02 + 0.98 * u(rng), r = std::sqrt(1 - z * z), phi = 2 * kPi * u(rng);
    v = {r * std::cos(phi), r * std::sin(phi), upper ? z : -z};
  }
  return w;
}

template <typename Dist>
void BM_D(benchmark::State& state, Dist d) {
  const auto m = Directions(true, 1);
  for (auto _ : state)
    for (const auto& w : m) benchmark::DoNotOptimize(d.D(w));
  state.SetItemsProcessed(state.iterations() * kBatch);
}
BENCHMARK_CAPTURE(BM_D, beckmann, BeckmannDistribution<double>(0.344));
BENCHMARK_CAPTURE(BM_D, ggx, GgxDistribution<double>(0.394));
BENCHMARK_CAPTURE(BM_D, phong, PhongDistribution<double>(BeckmannToPhongExponent(0.344)));

// Max relative error of a G1 against the exact Beckmann G1, over view angles 0..89.99 deg and the
// alpha of the distribution (the Phong variant compares at the mapped Beckmann width).
template <typename Dist>
double MaxRelErrorVsExactBeckmann(const Dist& d, double alpha_b) {
  BeckmannDistribution<double> exact(alpha_b);
  double worst = 0;
  for (int k = 0; k < 100000; ++k) {
    const Vec3<double> v = DirectionInPlane(k * (0.49999 * kPi) / 100000);
    const double e = exact.G1(v);
    if (e > 0) worst = std::max(worst, std::abs(d.G1(v) - e) / e);
  }
  return worst;
}

template <typename Dist>
void BM_G1(benchmark::State& state, Dist d, double alpha_b) {
  const auto v = Directions(true, 2);
  for (auto _ : state)
    for (const auto& w : v) benchmark::DoNotOptimize(d.G1(w));
  state.SetItemsProcessed(state.iterations() * kBatch);
  state.counters["max_rel_err"] = MaxRelErrorVsExactBeckmann(d, alpha_b);
}
BENCHMARK_CAPTURE(BM_G1, beckmann_exact, BeckmannDistribution<double>(0.344, SmithG1::kExact),
                  0.344);
BENCHMARK_CAPTURE(BM_G1, beckmann_rational, BeckmannDistribution<double>(0.344, SmithG1::kRational),
                  0.344);
BENCHMARK_CAPTURE(BM_G1, phong_rational, PhongDistribution<double>(BeckmannToPhongExponent(0.344)),
                  0.344);
BENCHMARK_CAPTURE(BM_G1, ggx_exact, GgxDistribution<double>(0.394), 0.344);

template <typename Dist>
void BM_Btdf(benchmark::State& state, Dist d) {
  RoughDielectricBsdf<Dist> bsdf(d, 1.51);
  const auto i = Directions(true, 3), o = Directions(false, 4);
  for (auto _ : state)
    for (int k = 0; k < kBatch; ++k) benchmark::DoNotOptimize(bsdf.Btdf(i[k], o[k]));
  state.SetItemsProcessed(state.iterations() * kBatch);
}
BENCHMARK_CAPTURE(BM_Btdf, beckmann_exact, BeckmannDistribution<double>(0.344, SmithG1::kExact));
BENCHMARK_CAPTURE(BM_Btdf, beckmann_rational,
                  BeckmannDistribution<double>(0.344, SmithG1::kRational));
BENCHMARK_CAPTURE(BM_Btdf, ggx, GgxDistribution<double>(0.394));
BENCHMARK_CAPTURE(BM_Btdf, phong, PhongDistribution<double>(BeckmannToPhongExponent(0.344)));

void BM_Btdf_sun2008(benchmark::State& state) {
  const auto i = Directions(true, 3), o = Directions(false, 4);
  for (auto _ : state)
    for (int k = 0; k < kBatch; ++k) benchmark::DoNotOptimize(Sun2008Btdf(i[k], o[k], 5.8, 1.51));
  state.SetItemsProcessed(state.iterations() * kBatch);
}
BENCHMARK(BM_Btdf_sun2008);

}  // namespace

BENCHMARK_MAIN();
