// Synthetic sweeps of a known model with realistic noise, for tests and benchmarks of the fitter.
// This is not the instrument simulator (sim/): no images, stages or cameras, just
// S = k f |cos theta_l| at chosen geometries (f_t in transmission, f_r in reflection) with photon
// shot noise and read noise.
#pragma once

#include <cstdint>
#include <vector>

#include "fitting/model.h"
#include "fitting/sample.h"

namespace gonio::fitting {

struct SyntheticSweep {
  ModelSpec model;
  double width = 0.344;  // family's unit
  double scale = 1.0;    // k
  double eta = 1.51;
  std::vector<double> theta_l_deg = {0.0};
  // The camera on the light side (reflection samples, the BRDF) rather than through the glass.
  bool reflection = false;
  // View angles: from -theta_v_max to +theta_v_max in steps of theta_v_step (degrees, bench
  // convention), plus a finer step inside +-fine_half_width around the straight-through
  // direction (the mirror direction in reflection) when fine_step > 0 (narrow lobes).
  double theta_v_max = 89.0;
  double theta_v_step = 1.0;
  double fine_step = 0.0;
  double fine_half_width = 0.0;
  // Noise, stated as the signal level: the largest expected value of the normal-incidence (or
  // first) sweep corresponds to peak_electrons; each sample has Poisson (Gaussian approximation)
  // shot noise plus Gaussian read noise. sigma is the true standard deviation (an instrument
  // estimates it from frame statistics). peak_electrons <= 0 gives noise-free data, sigma 1 %
  // of each value plus 1e-6 of the peak.
  double peak_electrons = 2e4;
  double read_noise_electrons = 10;
  std::uint64_t seed = 1;
};

std::vector<Sample> MakeSyntheticSweep(const SyntheticSweep& spec);

}  // namespace gonio::fitting
