// Empirical D (Walter 2007 section 6, the bottom plots of Figures 10, 11, 13 and 14): the
// microfacet distribution read back from the samples with G = 1 and the fitted scale, beside the
// fitted model's D.
#pragma once

#include <span>
#include <vector>

#include "fitting/fitter.h"
#include "fitting/sample.h"

namespace gonio::fitting {

struct EmpiricalDPoint {
  double theta_h_deg = 0;  // angle of the half vector (h_t, or h_r for reflection) from the normal
  double d = 0;            // eq. 21 (20) solved for D with G = 1 and the fitted scale
  double d_sigma = 0;
};

// Uses samples with |l.n| > 0.5 and |v.n| > 0.5 whose value exceeds both
// min_relative * (largest value) and min_snr * sigma (stray light and noise are excluded).
std::vector<EmpiricalDPoint> EmpiricalD(std::span<const Sample> samples, double scale, double eta,
                                        double min_relative = 1e-3, double min_snr = 3.0);

// The fitted D(theta_h) of a fit, for plotting beside the empirical points.
double FittedD(const FitSummary& fit, double theta_h_deg);

}  // namespace gonio::fitting
