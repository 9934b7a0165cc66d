#include "fitting/model_choice.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

namespace gonio::fitting {

ModelChoice SelectModel(std::span<const FitSummary> fits, double decisive_delta_bic) {
  ModelChoice c;
  double min_bic = std::numeric_limits<double>::infinity();
  for (const auto& f : fits)
    if (f.status != FitStatus::kFailed) min_bic = std::min(min_bic, f.bic);
  for (const auto& f : fits)
    c.delta_bic.push_back(f.status != FitStatus::kFailed ? f.bic - min_bic
                                                         : std::numeric_limits<double>::infinity());
  if (!std::isfinite(min_bic)) {
    c.reason = "no fit converged";
    return c;
  }
  // Contenders: within the decisive margin of the best.
  std::vector<std::size_t> contenders;
  for (std::size_t k = 0; k < fits.size(); ++k)
    if (c.delta_bic[k] < decisive_delta_bic) contenders.push_back(k);
  for (std::size_t k : contenders)
    if (fits[k].status == FitStatus::kUnconstrained) {
      c.reason = Describe(fits[k].model) + " is a contender but the data do not constrain it (" +
                 fits[k].message + ")";
      return c;
    }
  int fewest = std::numeric_limits<int>::max();
  for (std::size_t k : contenders) fewest = std::min(fewest, fits[k].n_params);
  std::vector<std::size_t> smallest;
  for (std::size_t k : contenders)
    if (fits[k].n_params == fewest) smallest.push_back(k);
  std::ostringstream os;
  if (smallest.size() == 1) {
    c.chosen = smallest[0];
    os << Describe(fits[smallest[0]].model) << ": every other model is " << decisive_delta_bic
       << " or more worse in BIC or has more parameters";
    if (fits[smallest[0]].status == FitStatus::kPoorFit)
      os << "; but even it does not describe the data (" << fits[smallest[0]].message << ")";
  } else {
    os << "the data cannot tell apart";
    for (std::size_t k : smallest)
      os << " " << Describe(fits[k].model) << " (dBIC " << c.delta_bic[k] << ")";
    os << "; all are within " << decisive_delta_bic << " of the best";
  }
  c.reason = os.str();
  return c;
}

}  // namespace gonio::fitting
