// Cost against accuracy of the ground-truth models (issue #8), and the failure map of the
// single-scattering models. Writes JSON for bench/plot_truth.py and prints tables.
//
//   truth_bench OUT.json [quick]
// Part 1, for s in {0.5, 1, 3, 6} (air -> glass 1.51, theta_i 30): error against a converged
// explicit-surface reference (3e6 rays), for the analytic Walter model, the statistical MC and
// the explicit MC at increasing ray counts, with seconds. Part 2: Walter's and Sun's error
// against explicit surfaces (4e5 rays) over s, theta_i and n. Errors are the relative L1 of the
// transmitted lobes beyond the Monte Carlo noise of the tables compared (ExcessL1).
#include <chrono>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <nlohmann/json.hpp>

#include "sim/truth/compare.h"
#include "sim/truth/monte_carlo.h"

using namespace gonio::sim;

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: truth_bench OUT.json [quick]\n");
    return 2;
  }
  const bool quick = argc > 2 && std::strcmp(argv[2], "quick") == 0;
  nlohmann::json out;
  const double n_above = 1.0, n_below = 1.51, ti = 30;
  std::printf("cost against accuracy (theta_i %g, n %g): L1 vs converged explicit surfaces\n", ti,
              n_below);
  std::printf("%-6s %-12s %10s %10s %12s %10s\n", "s", "method", "rays", "seconds", "excess L1",
              "MC noise");
  for (double s : {0.5, 1.0, 3.0, 6.0}) {
    MonteCarloOptions ref_o;
    ref_o.rays = quick ? 400'000 : 3'000'000;
    ref_o.seed = 99;
    const BtdfTable ref = ExplicitSurfaceMonteCarlo(s, n_above, n_below, ti, ref_o);
    const double ref_noise = Compare(ref, ref.f).l1_noise;
    nlohmann::json rows;
    // Error = the L1 difference beyond both tables' Monte Carlo noise (ExcessL1).
    auto add = [&](const char* method, double rays, double seconds, const TableDifference& d) {
      std::printf("%-6g %-12s %10.0f %10.4f %12.4f %10.4f\n", s, method, rays, seconds, ExcessL1(d),
                  d.l1_noise);
      rows.push_back({{"method", method},
                      {"rays", rays},
                      {"seconds", seconds},
                      {"excess_l1", ExcessL1(d)},
                      {"noise_l1", d.l1_noise}});
    };
    {
      const auto t0 = std::chrono::steady_clock::now();
      const auto model = TabulateModel(ref, WalterBeckmannModel(s, n_above, n_below));
      const double sec =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      add("analytic", 0, sec, Compare(ref, model));
    }
    for (std::int64_t rays : {10'000, 30'000, 100'000, 300'000}) {
      MonteCarloOptions o;
      o.rays = rays;
      const BtdfTable st = StatisticalMonteCarlo(s, n_above, n_below, ti, o);
      add("statistical", double(rays), st.seconds, CompareTables(ref, st));
      const BtdfTable ex = ExplicitSurfaceMonteCarlo(s, n_above, n_below, ti, o);
      add("explicit", double(rays), ex.seconds, CompareTables(ref, ex));
    }
    out["cost_accuracy"].push_back({{"s", s},
                                    {"reference_rays", ref.rays},
                                    {"reference_seconds", ref.seconds},
                                    {"reference_rays_per_second", ref.rays / ref.seconds},
                                    {"reference_noise_l1", ref_noise},
                                    {"rows", rows}});
  }

  std::printf(
      "\nfailure map: L1 of single scattering vs explicit surfaces\n%-6s %-8s %-6s %10s %10s "
      "%10s\n",
      "n", "theta_i", "s", "Walter", "Sun", "MC noise");
  MonteCarloOptions o;
  o.rays = quick ? 60'000 : 400'000;
  for (double n : {1.4, 1 / 1.4})
    for (double theta_i : {0.0, 30.0, 60.0})
      for (double s : {0.5, 0.75, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0}) {
        const double na = n > 1 ? 1.0 : 1.4, nb = n > 1 ? 1.4 : 1.0;
        const BtdfTable t = ExplicitSurfaceMonteCarlo(s, na, nb, theta_i, o);
        const TableDifference w = Compare(t, TabulateModel(t, WalterBeckmannModel(s, na, nb)));
        const TableDifference su = Compare(t, TabulateModel(t, Sun2008Model(s, na, nb)));
        std::printf("%-6.3f %-8g %-6g %10.3f %10.3f %10.3f\n", n, theta_i, s, ExcessL1(w),
                    ExcessL1(su), w.l1_noise);
        out["failure_map"].push_back({{"n", n},
                                      {"theta_i", theta_i},
                                      {"s", s},
                                      {"walter_l1", ExcessL1(w)},
                                      {"sun_l1", ExcessL1(su)},
                                      {"noise_l1", w.l1_noise},
                                      {"rays_per_second", t.rays / t.seconds}});
      }
  std::ofstream(argv[1]) << out.dump(2) << "\n";
  return 0;
}
