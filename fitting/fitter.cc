// Fit's front door: the options' and samples' checks, then the rooms of fitting/internal/ in
// turn (the floor's choice over FitOnce, then the geometry's profile), and Predict through the
// response at the geometry a fit found.
#include "fitting/fitter.h"

#include <chrono>
#include <memory>
#include <string>
#include <utility>

#include "fitting/internal/floor_choice.h"
#include "fitting/internal/geometry_profile.h"
#include "fitting/internal/response_budget.h"
#include "fitting/internal/solve.h"

namespace gonio::fitting {

using internal::ModelAt;
using internal::MoveToFitted;
using internal::StageSlope;

const char* ToString(FitStatus s) {
  switch (s) {
    case FitStatus::kConverged:
      return "converged";
    case FitStatus::kUnconstrained:
      return "unconstrained";
    case FitStatus::kPoorFit:
      return "poor fit";
    case FitStatus::kFailed:
      return "failed";
  }
  return "?";
}

Status FitOptions::Validate() const {
  if (!(eta > 1 && eta < 3)) return InvalidArgument("eta must lie in (1, 3)");
  if (!(loss_scale > 0)) return InvalidArgument("loss_scale must be > 0");
  if (initial_width && !(*initial_width > 0 && std::isfinite(*initial_width)))
    return InvalidArgument("initial_width must be a finite number > 0");
  if (max_local_fits < 1) return InvalidArgument("max_local_fits must be >= 1");
  if (scan_points < 4) return InvalidArgument("scan_points must be >= 4");
  if (max_iterations < 1) return InvalidArgument("max_iterations must be >= 1");
  if (!(std::isfinite(response_tolerance) && response_tolerance >= 0))
    return InvalidArgument("response_tolerance must be a finite number >= 0");
  if (max_response_rays < 1) return InvalidArgument("max_response_rays must be >= 1");
  if (!(floor_width_tolerance >= 0))  // infinity: BIC alone decides
    return InvalidArgument("floor_width_tolerance must be >= 0");
  if (!automatic_starts && !initial_width)
    return InvalidArgument("automatic_starts = false needs an initial_width");
  return OkStatus();
}

double Predict(const FitSummary& fit, const Sample& sample) {
  const double w = fit.width.value, k = fit.scale.value, eta = fit.eta.value;
  double value = MeasurementModel(fit.model, sample.light, sample.view, w, k, eta);
  if (sample.response && sample.response->setup) {
    Sample s = sample;  // at the geometry the fit found
    ResponseSetup moved = *s.response->setup;
    MoveToFitted(fit.geometry, moved);
    s.response->setup = std::make_shared<const ResponseSetup>(std::move(moved));
    value = ModelAt(fit, s, s.response->at);
    // The sample stage's offset of the first group read back at this angle (a sample alone does
    // not say which visit to the angle it was taken in), through the slope at the fitted
    // geometry.
    for (const StageOffset& g : fit.geometry.sample_stage)
      if (g.sample_deg == sample.response->at.sample_deg) {
        if (g.offset_deg != 0)
          value += StageSlope(fit, s, &StagePosition::sample_deg) * g.offset_deg;
        break;
      }
  }
  return value + fit.floor.value;
}

Result<FitSummary> Fit(std::span<const Sample> samples, const FitOptions& o) {
  if (Status s = o.Validate(); !s) return s.error();
  if (Status s = ValidateSamples(samples, o.NumParams()); !s) return s.error();
  if (IsReflection(samples[0]) && !HasBrdf(o.model.family))
    return InvalidArgument(std::string(Name(o.model.family)) +
                           " is a transmission model (Sun 2008 gives no BRDF): it cannot fit "
                           "reflection samples; fit beckmann, ggx or phong");
  const auto t0 = std::chrono::steady_clock::now();
  auto fit = internal::FitWithFloor(samples, internal::SolveOptions(o));
  if (!fit.ok()) return fit;
  auto out = internal::WithGeometry(samples, o, std::move(fit).value());
  if (out.ok())
    out->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return out;
}

}  // namespace gonio::fitting
