#include "fitting/synthetic.h"

#include <algorithm>
#include <cmath>
#include <random>

namespace gonio::fitting {

std::vector<Sample> MakeSyntheticSweep(const SyntheticSweep& spec) {
  std::vector<Sample> out;
  for (double tl : spec.theta_l_deg) {
    // Straight-through view angle for this incidence (Snell at the mean surface), or the mirror
    // direction in reflection.
    const double straight =
        spec.reflection ? tl : -std::asin(std::sin(tl * optics::kDeg) / spec.eta) / optics::kDeg;
    std::vector<double> views;
    for (double tv = -spec.theta_v_max; tv <= spec.theta_v_max + 1e-9; tv += spec.theta_v_step)
      views.push_back(tv);
    if (spec.fine_step > 0)
      for (double d = -spec.fine_half_width; d <= spec.fine_half_width + 1e-9; d += spec.fine_step)
        if (std::abs(straight + d) < spec.theta_v_max) views.push_back(straight + d);
    for (double tv : views)
      out.push_back(spec.reflection ? SampleFromReflectionAngles(tl, 0, tv, 0, 0, 0)
                                    : SampleFromBenchAngles(tl, 0, tv, 0, 0, 0));
  }
  // Expected values, and the gain that puts the first sweep's peak at peak_electrons.
  double peak = 0;
  for (Sample& s : out) {
    s.value = MeasurementModel(spec.model, s.light, s.view, spec.width, spec.scale, spec.eta);
    if (std::abs(s.light.z - out.front().light.z) < 1e-12) peak = std::max(peak, s.value);
  }
  std::mt19937_64 rng(spec.seed);
  std::normal_distribution<double> gauss(0, 1);
  for (Sample& s : out) {
    if (spec.peak_electrons <= 0 || peak <= 0) {
      s.sigma = 0.01 * s.value + 1e-6 * peak;
      continue;
    }
    const double gain = spec.peak_electrons / peak;  // electrons per unit of S
    const double electrons = s.value * gain;
    const double sd = std::sqrt(electrons + spec.read_noise_electrons * spec.read_noise_electrons);
    s.value = (electrons + sd * gauss(rng)) / gain;
    s.sigma = sd / gain;
  }
  return out;
}

}  // namespace gonio::fitting
