// The C++ side of the scipy peer comparison (bench/scipy_peer.py): one local fit from a given
// start, repeated, on a samples CSV. Prints one JSON object: the optimum and the time per fit.
//
//   fit_peer samples.csv beckmann 0.3 [repeats]
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <string>

#include "fitting/fitter.h"
#include "fitting/samples_csv.h"

int main(int argc, char** argv) {
  using namespace gonio::fitting;
  if (argc < 4) {
    std::cerr << "usage: fit_peer SAMPLES.csv MODEL START [REPEATS]\n";
    return 2;
  }
  auto samples = ReadSamplesCsv(argv[1]);
  if (!samples) {
    std::cerr << "fit_peer: " << samples.error().message << "\n";
    return 2;
  }
  auto family = ParseFamily(argv[2]);
  if (!family) {
    std::cerr << "fit_peer: unknown model " << argv[2] << "\n";
    return 2;
  }
  FitOptions o;
  o.model.family = *family;
  o.initial_width = std::atof(argv[3]);
  o.automatic_starts = false;
  o.inflate_by_reduced_chi2 = false;
  const int repeats = argc > 4 ? std::atoi(argv[4]) : 50;
  FitSummary f;
  const auto t0 = std::chrono::steady_clock::now();
  for (int k = 0; k < repeats; ++k) {
    auto r = Fit(*samples, o);
    if (!r || r->status == FitStatus::kFailed) {
      std::cerr << "fit_peer: fit failed\n";
      return 1;
    }
    f = *r;
  }
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() / repeats;
  std::printf(
      "{\"width\": %.17g, \"scale\": %.17g, \"chi2\": %.17g, \"iterations\": %d, "
      "\"seconds_per_fit\": %.9g}\n",
      f.width.value, f.scale.value, f.chi2, f.iterations, seconds);
  return 0;
}
