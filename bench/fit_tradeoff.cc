// Speed against accuracy of the fitter's variants (issue #3): derivative method, exact vs rational
// G1, robust loss, and how many starts. For each variant, over repeated noise draws of the same
// sweep, it reports the time per fit, the RMS relative error of alpha against the truth (noise +
// bias), and the largest relative deviation from the reference variant's optimum on the same
// data (what the variant itself changes), and how many fits failed or converged elsewhere
// (> 10 % from the reference: a wrong local minimum). Prints a table and writes JSON for
// bench/plot_fit_tradeoff.py.
//
//   fit_tradeoff OUT.json [draws]
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <functional>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "fitting/fitter.h"
#include "fitting/synthetic.h"

namespace {

using namespace gonio::fitting;

struct Variant {
  std::string name;
  std::function<void(FitOptions&)> apply;
};

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: fit_tradeoff OUT.json [draws]\n");
    return 2;
  }
  const int draws = argc > 2 ? std::atoi(argv[2]) : 40;
  const double truth = 0.344;  // ground glass, Beckmann (Figure 12)
  const std::vector<Variant> variants = {
      {"default (autodiff, exact G1, 3 starts)", [](FitOptions&) {}},
      {"numeric derivatives", [](FitOptions& o) { o.derivatives = Derivatives::kNumeric; }},
      {"rational G1 (eq. 27)",
       [](FitOptions& o) { o.model.g1 = gonio::optics::SmithG1::kRational; }},
      {"Huber loss", [](FitOptions& o) { o.loss = Loss::kHuber; }},
      {"Cauchy loss", [](FitOptions& o) { o.loss = Loss::kCauchy; }},
      {"1 start (0.25), no scan",
       [](FitOptions& o) {
         o.automatic_starts = false;
         o.initial_width = 0.25;
       }},
      {"1 start (0.01), no scan",
       [](FitOptions& o) {
         o.automatic_starts = false;
         o.initial_width = 0.01;
       }},
      {"scan + 1 local fit", [](FitOptions& o) { o.max_local_fits = 1; }},
      {"scan + 6 local fits", [](FitOptions& o) { o.max_local_fits = 6; }},
  };
  for (bool joint : {false, true}) {
    std::vector<std::vector<Sample>> data;
    for (int d = 0; d < draws; ++d) {
      SyntheticSweep s;
      s.width = truth;
      s.scale = 0.542;
      s.seed = 500 + d;
      if (joint) s.theta_l_deg = {0, 30, 60, 80};
      data.push_back(MakeSyntheticSweep(s));
    }
    std::vector<double> reference(draws);
    nlohmann::json rows;
    std::printf("\n%s (%zu samples, %d draws)\n%-40s %10s %14s %16s %8s\n",
                joint ? "joint 0/30/60/80" : "normal incidence", data[0].size(), draws, "variant",
                "ms/fit", "rms err alpha", "max dev vs ref", "wrong");
    for (std::size_t v = 0; v < variants.size(); ++v) {
      double seconds = 0, sum2 = 0, max_dev = 0;
      int wrong = 0;  // failed, or converged more than 10 % away from the reference optimum
      for (int d = 0; d < draws; ++d) {
        FitOptions o;
        variants[v].apply(o);
        const auto t0 = std::chrono::steady_clock::now();
        auto r = Fit(data[d], o);
        seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        if (!r) {
          std::fprintf(stderr, "fit_tradeoff: %s\n", r.error().message.c_str());
          return 1;
        }
        const double a = r->width.value;
        if (v == 0) reference[d] = a;
        const double dev = std::abs(a - reference[d]) / reference[d];
        if (r->status == FitStatus::kFailed || dev > 0.1) {
          ++wrong;
          continue;
        }
        sum2 += std::pow((a - truth) / truth, 2);
        max_dev = std::max(max_dev, dev);
      }
      const int good = draws - wrong;
      const double ms = 1e3 * seconds / draws, rms = good ? std::sqrt(sum2 / good) : std::nan("");
      std::printf("%-40s %10.3f %14.2e %16.2e %8d\n", variants[v].name.c_str(), ms, rms, max_dev,
                  wrong);
      rows.push_back({{"variant", variants[v].name},
                      {"ms_per_fit", ms},
                      {"rms_rel_error_alpha", rms},
                      {"max_rel_deviation_from_reference", max_dev},
                      {"wrong", wrong},
                      {"draws", draws}});
    }
    static nlohmann::json all;
    all[joint ? "joint" : "normal"] = rows;
    std::ofstream(argv[1]) << all.dump(2) << "\n";
  }
  return 0;
}
