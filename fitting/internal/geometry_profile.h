// The geometry's room (GeometryUse, fitting/fitter.h): the angle read-back through each sample's
// sigma and the sample stage's offsets in the solve; the thickness and the rectangle's position
// as nuisance parameters profiled together by least-squares refits, the fit redone at the most
// probable geometry; the degrees of freedom they take. Internal to fitting/.
#pragma once

#include <span>

#include "common/result.h"
#include "fitting/fitter.h"

namespace gonio::fitting::internal {

// The geometry's stated uncertainties (the samples' BenchOptics) into `fit`, a fit of `samples`
// with `o` (FitWithFloor's): a failed fit, or samples without a response, come back as they went
// in (the note says the geometry is not in sigma).
Result<FitSummary> WithGeometry(std::span<const Sample> samples, const FitOptions& o,
                                FitSummary fit);

}  // namespace gonio::fitting::internal
