// The floor's choice (Floor::kAuto, fitting/fitter.h): fits without and with a constant floor,
// BIC's choice between them, and the width's move between the two in sigma where BIC cannot show
// the floor. Internal to fitting/.
#pragma once

#include <span>

#include "common/result.h"
#include "fitting/fitter.h"
#include "fitting/internal/solve.h"

namespace gonio::fitting::internal {

// Fit's work once the input is valid: with Floor::kAuto, the fits without and with a floor and
// BIC's choice between them.
Result<FitSummary> FitWithFloor(std::span<const Sample> samples, const SolveOptions& o);

}  // namespace gonio::fitting::internal
