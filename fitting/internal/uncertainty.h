// The uncertainty's room: chi-square, the information criteria and the residuals at a solution;
// the parameters' sigmas from the solution's covariance by the delta method, inflated by the
// reduced chi-square (or the robust scatter) and split into the samples' statistical part; and
// the fit's verdict (converged, unconstrained, poor fit) - fitting/fitter.h states the contract.
// Internal to fitting/.
#pragma once

#include "fitting/fitter.h"
#include "fitting/internal/solve.h"

namespace gonio::fitting::internal {

// chi2/dof and the information criteria from chi2, the model's parameters and the nuisance ones
// the data fixed.
void SetInformation(FitSummary& out);

// Residuals, chi2 (with the sample stage's priors) and the information criteria at the solution.
void FillStatistics(const Problem& p, const FitOptions& o, const LocalFit& f, FitSummary& out);

// The parameters' sigmas from the covariance of (log width, log k[, eta raw][, floor]) by the
// delta method. False when the covariance is singular or not positive.
bool FillUncertainties(LocalFit& winner, const Problem& p, const FitOptions& o, FitSummary& out);

// A fit judged on what the data constrain and on its chi2. A chi2 whose p-value is below 1e-6
// makes it a poor fit whatever else holds: the family does not describe the data, which is the
// first thing to say of it (a width's sigma inflated by a chi2/dof of 1e6 looks unconstrained
// only because of it). With honest sigmas a correct model gives p ~ U(0, 1). The degrees of
// freedom count the nuisance parameters the data fixed (FitSummary::n_nuisance). Judged again
// when those change. For a converged solve only.
void JudgeFit(bool cov_ok, FitSummary& out);

// Whether the data constrain the width of a judged fit (its covariance was regular if it has a
// sigma).
bool WidthConstrained(const FitSummary& f);

}  // namespace gonio::fitting::internal
