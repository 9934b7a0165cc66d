// Evaluations per second of the optics layer: D, G1 (exact vs rational), and the whole BTDF, per
// distribution. Each G1 benchmark also reports its maximum relative error against the exact Smith
// G1 of its own distribution (counter max_rel_err; Phong's by quadrature, as it has no closed
// form), so one run gives both axes of the speed/accuracy chart (bench/plot_g1_tradeoff.py).
#include <benchmark/benchmark.h>

#include <boost/math/quadrature/gauss.hpp>
#include <cmath>
#include <random>
#include <vector>

#include "optics/microfacet.h"
#include "optics/sun2008.h"

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

// Exact Smith G1 of any height-field distribution from the projected-area identity
// (geometric seed eq. 2a-3): cos(theta_v) (1 + Lambda(v)) = integral of max(0, v.m) D(m) dm.
// Phong has no closed form (Walter section 5.2); this quadrature is its reference.
template <typename Dist>
double SmithG1ByQuadrature(const Dist& d, const Vec3<double>& v) {
  using boost::math::quadrature::gauss;
  constexpr int kCells = 48;
  double integral = 0;
  for (int a = 0; a < kCells; ++a)
    for (int b = 0; b < kCells; ++b) {
      const double t0 = 0.5 * kPi * a / kCells, t1 = 0.5 * kPi * (a + 1) / kCells;
      const double p0 = 2 * kPi * b / kCells, p1 = 2 * kPi * (b + 1) / kCells;
      integral += gauss<double, 6>::integrate(
          [&](double t) {
            const double st = std::sin(t), ct = std::cos(t);
            return st * gauss<double, 6>::integrate(
                            [&](double phi) {
                              const Vec3<double> m = SphericalDirection(st, ct, phi);
                              return std::max(0.0, Dot(v, m)) * d.D(m);
                            },
                            p0, p1);
          },
          t0, t1);
    }
  return CosTheta(v) / integral;  // = 1 / (1 + Lambda)
}

// Max relative error of a distribution's G1 against its own exact Smith G1, for view angles
// 0..88 deg. `reference` gives the exact value; 0 error means the G1 is exact.
template <typename Dist, typename Ref>
double MaxRelError(const Dist& d, const Ref& reference, int n_angles) {
  double worst = 0;
  for (int k = 0; k < n_angles; ++k) {
    const Vec3<double> v = DirectionInPlane((88.0 * kPi / 180) * k / (n_angles - 1));
    const double e = reference(v);
    if (e > 0) worst = std::max(worst, std::abs(d.G1(v) - e) / e);
  }
  return worst;
}

template <typename Dist, typename Ref>
void BM_G1(benchmark::State& state, Dist d, Ref reference, int n_angles) {
  const auto v = Directions(true, 2);
  for (auto _ : state)
    for (const auto& w : v) benchmark::DoNotOptimize(d.G1(w));
  state.SetItemsProcessed(state.iterations() * kBatch);
  state.counters["max_rel_err"] = MaxRelError(d, reference, n_angles);
}

const BeckmannDistribution<double> kBeckmannExact(0.344, SmithG1::kExact);
const PhongDistribution<double> kPhong(BeckmannToPhongExponent(0.344));
const GgxDistribution<double> kGgx(0.394);

auto BeckmannReference = [](const Vec3<double>& v) { return kBeckmannExact.G1(v); };
auto GgxReference = [](const Vec3<double>& v) { return kGgx.G1(v); };
auto PhongReference = [](const Vec3<double>& v) { return SmithG1ByQuadrature(kPhong, v); };

BENCHMARK_CAPTURE(BM_G1, beckmann_exact, kBeckmannExact, BeckmannReference, 20000);
BENCHMARK_CAPTURE(BM_G1, beckmann_rational, BeckmannDistribution<double>(0.344, SmithG1::kRational),
                  BeckmannReference, 20000);
BENCHMARK_CAPTURE(BM_G1, phong_rational, kPhong, PhongReference, 89);
BENCHMARK_CAPTURE(BM_G1, ggx_exact, kGgx, GgxReference, 20000);

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
BENCHMARK(BM_Btdf_sun2008)->Name("BM_Btdf/sun2008");

}  // namespace

BENCHMARK_MAIN();
