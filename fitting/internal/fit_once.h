// One fit with the floor on or off: the starts, the local solves from the best of them, the
// per-sample response decided again at the solution until it settles (response_budget.h), the
// held samples' error traced, then the statistics, the sigmas and the verdict (uncertainty.h).
// Internal to fitting/: the floor's choice and the geometry's profile call it.
#pragma once

#include <span>

#include "common/result.h"
#include "fitting/fitter.h"
#include "fitting/internal/solve.h"

namespace gonio::fitting::internal {

// o.floor is kOff or kFit (kAuto is the floor's choice, floor_choice.h). Errors: a response that
// cannot be built (naming the sample), or a model zero at every sample for every width tried.
Result<FitSummary> FitOnce(std::span<const Sample> input, const SolveOptions& o);

}  // namespace gonio::fitting::internal
