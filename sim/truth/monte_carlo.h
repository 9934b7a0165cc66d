// Ground truth that does not go through the microfacet BTDF formulas: Monte Carlo
// transmission through rough dielectric surfaces with multiple scattering and total internal
// reflection. Two methods, both producing a BtdfTable:
//
//  * StatisticalMonteCarlo - Sun 2008 section 4: the surface is statistical (Gaussian heights,
//    Beckmann slopes with alpha = 2/s), the next hit's height follows Smith's uncorrelated
//    visibility, the hit facet follows the distribution of visible normals, and every hit splits
//    into Fresnel-weighted reflected and transmitted rays (eq. 26-28). Written in the exact
//    random-walk form of Heitz et al. 2016 (heights tracked through C1(h)); branches below
//    `split_threshold` are continued by Russian roulette, which keeps the estimate unbiased
//    (Sun's plain cutoff would lose energy).
//  * ExplicitSurfaceMonteCarlo - Sun 2008's future work: periodic Gaussian random height fields
//    of RMS sigma and correlation length tau (Gaussian C(r) = exp(-r^2/tau^2)), made by filtering
//    white noise in the Fourier domain (OpenCV DFT), traced exactly as triangle meshes, averaged
//    over realisations. No Smith assumption anywhere.
//
// Conventions: light arrives from above at theta_i (phi = 0); n_above is the index of the medium
// above (where the light is), n_below below. Sun's relative index n is n_below / n_above.
// Smoothness s = tau / sigma; the Beckmann width with the same slope statistics is alpha = 2 / s
// (docs/ground_truth.md).
#pragma once

#include <cstdint>

#include "sim/truth/btdf_table.h"

namespace gonio::sim {

struct MonteCarloOptions {
  std::int64_t rays = 200'000;
  int batches = 20;               // for standard errors (rays are split evenly)
  double split_threshold = 0.01;  // below: Russian roulette instead of splitting
  int max_depth = 64;             // hits per path before it is dropped (counted in neither R nor T)
  std::uint64_t seed = 1;
  int threads = 0;               // 0: all hardware threads
  int n_theta = 45, n_phi = 24;  // table bins (2 x 15 degrees)
};

BtdfTable StatisticalMonteCarlo(double s, double n_above, double n_below, double theta_i_deg,
                                const MonteCarloOptions& options = {});

struct SurfaceOptions {
  int grid = 256;               // samples per side (power of two is fastest for the DFT)
  double samples_per_tau = 10;  // grid spacing dx = tau / samples_per_tau
  int realisations = 4;         // independent surfaces; batches cycle through them
};

BtdfTable ExplicitSurfaceMonteCarlo(double s, double n_above, double n_below, double theta_i_deg,
                                    const MonteCarloOptions& options = {},
                                    const SurfaceOptions& surface = {});

// Statistics of one generated surface (for tests and docs): RMS height, RMS mesh slope per axis,
// and the height correlation at lag tau along x (exp(-1) for the requested C(r)).
struct SurfaceStats {
  double rms_height = 0, rms_slope_x = 0, rms_slope_y = 0, correlation_at_tau = 0;
};
SurfaceStats MeasureSurface(double s, const SurfaceOptions& surface, std::uint64_t seed);

// The Beckmann alpha of an explicit surface: 2/s for the continuous surface; the triangle mesh at
// spacing dx has slightly smaller slopes, per axis variance 2 sigma^2 (1 - exp(-dx^2/tau^2))/dx^2.
double PredictedAlpha(double s);
double PredictedAlphaOfMesh(double s, double samples_per_tau);

}  // namespace gonio::sim
