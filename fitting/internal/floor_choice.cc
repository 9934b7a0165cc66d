#include "fitting/internal/floor_choice.h"

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <sstream>
#include <utility>

#include "fitting/internal/fit_once.h"

namespace gonio::fitting::internal {

Result<FitSummary> FitWithFloor(std::span<const Sample> samples, const SolveOptions& o) {
  if (o.floor != Floor::kAuto) return FitOnce(samples, o);
  SolveOptions off = o, on = o;
  off.floor = Floor::kOff;
  on.floor = Floor::kFit;
  // A background measured at every point and subtracted leaves nothing for a floor to stand for.
  if (std::all_of(samples.begin(), samples.end(),
                  [](const Sample& s) { return s.background_subtracted; })) {
    auto fit = FitOnce(samples, off);
    if (fit.ok())
      fit->floor_choice = "no floor: each point's background was measured and subtracted";
    return fit;
  }
  // The floor only when the data need it: BIC with it lower by more than 2.
  auto without = FitOnce(samples, off);
  if (!without.ok()) return without;
  if (static_cast<int>(samples.size()) < on.NumParams() + 1) {
    without->floor_choice = "no floor: too few samples to fit one";
    return without;
  }
  auto with = FitOnce(samples, on);
  if (!with.ok()) return with;
  const double seconds = without->seconds + with->seconds;
  std::ostringstream why;
  why << std::setprecision(3);
  FitSummary* chosen = &*without;
  // The move counts between two fits of the width that both describe the data, the floor's no
  // worse than the one without it (nested: a higher chi-square is a local minimum, not the floor).
  const bool both = with->status == FitStatus::kConverged &&
                    without->status == FitStatus::kConverged && with->chi2 <= without->chi2;
  const double shift = both ? with->width.value - without->width.value : 0.0;
  // How far leaving the floor out moves the width, in the width's sigma with the floor.
  const double moves = with->width.sigma > 0 ? std::abs(shift) / with->width.sigma : 0.0;
  if (with->status != FitStatus::kFailed &&
      (without->status == FitStatus::kFailed || with->bic < without->bic - 2)) {
    chosen = &*with;
    why << "floor kept: BIC lower by " << without->bic - with->bic << " with it";
  } else if (both && moves > o.floor_width_tolerance) {
    chosen = &*with;
    why << "floor kept: BIC lower by only " << without->bic - with->bic
        << " with it, but leaving it out moves the width by " << moves
        << " of its sigma (more than " << o.floor_width_tolerance << "), which is in sigma";
    // Kept because this draw put the floor-fitted width far from the other: chosen on the noise,
    // its own sigma is short (under a floor the data cannot see, the kept fits' pulls have an rms
    // near 1.2 by the selection alone). The move in sigma, as where the floor is left out.
    chosen->width.sigma_floor = std::abs(shift);
  } else if (with->status == FitStatus::kFailed) {
    why << "no floor: the fit with one failed";
  } else if (!both) {
    why << "no floor: BIC lower by only " << without->bic - with->bic
        << " with it (more than 2 needed)";
  } else {
    why << "no floor: BIC lower by only " << without->bic - with->bic
        << " with it (more than 2 needed), and leaving it out moves the width by " << moves
        << " of its sigma, which is in sigma";
    // What the floor the data could not show might have done to the width.
    without->width.sigma_floor = std::abs(shift);
  }
  chosen->width.sigma = std::hypot(chosen->width.sigma, chosen->width.sigma_floor);
  chosen->floor_width_shift = shift;
  chosen->floor_choice = why.str();
  chosen->seconds = seconds;
  return std::move(*chosen);
}

}  // namespace gonio::fitting::internal
