// gonio-fit's tables: the fits of a protocol as a person reads them, in lines of at most 100
// columns. By default a table row per model, the width's sigma split into its parts, the floor
// and any warning; with `explain`, also the long account of each fit (how the geometry, the
// instrument response, the ray budget, the dark sets and the floor's choice entered it), wrapped.
// The same figures, and more, are in fit_summary.json (gonio-fit --out).
#pragma once

#include <ostream>
#include <string>
#include <vector>

#include "fitting/fit_protocol.h"
#include "fitting/fitter.h"

namespace gonio::fitting {

inline constexpr std::size_t kReportColumns = 100;

struct ReportOptions {
  bool explain = false;  // the long account of each fit (gonio-fit --explain, -v)
};

// The header line: samples, incidences and what was held fixed.
void PrintSamplesLine(std::ostream& out, std::size_t samples, const FitProtocolResult& result,
                      double eta, bool eta_fitted);

// The fits of `result` under their titles: the normal-incidence fits and their predictions of
// the other incidences (under Walter's protocol), then the joint fit and the model choice.
void PrintProtocolResult(std::ostream& out, const FitProtocolResult& result,
                         const ReportOptions& options);

}  // namespace gonio::fitting
