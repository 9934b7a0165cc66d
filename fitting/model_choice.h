// Choosing among fitted models (Walter 2007 section 6 compares Beckmann, GGX and Phong; Sun 2008
// adds a fourth): the smallest model the data support, by BIC.
#pragma once

#include <cstddef>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "fitting/fitter.h"

namespace gonio::fitting {

struct ModelChoice {
  std::optional<std::size_t> chosen;  // index into the fits; nullopt: the data cannot decide
  std::string reason;
  std::vector<double> delta_bic;  // BIC - min BIC, per fit (inf for failed fits)
};

// Picks the smallest model the data support: among converged (or poor), constrained fits within
// `decisive_delta_bic` of the lowest BIC (10 = "very strong" evidence, Kass & Raftery 1995), the
// one with the fewest parameters; if several share that count, none (the data cannot tell them
// apart).
ModelChoice SelectModel(std::span<const FitSummary> fits, double decisive_delta_bic = 10.0);

}  // namespace gonio::fitting
