#include "fitting/internal/fit_once.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <iomanip>
#include <memory>
#include <sstream>
#include <string>
#include <tuple>
#include <vector>

#include "fitting/internal/response_budget.h"
#include "fitting/internal/uncertainty.h"

namespace gonio::fitting::internal {
namespace {

double Median(std::vector<double> v) {
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

}  // namespace

Result<FitSummary> FitOnce(std::span<const Sample> input, const SolveOptions& o) {
  const auto t0 = std::chrono::steady_clock::now();
  // The dark sets' shared parts come out of each sample's sigma (and its statistical part) into
  // one nuisance per set (DarkUse): the samples' own sigmas below are the independent parts.
  const DarkSets dark = DarkSetsOf(input);
  std::vector<Sample> independent;
  if (dark.count > 0) {
    independent.assign(input.begin(), input.end());
    for (std::size_t i = 0; i < independent.size(); ++i) {
      Sample& s = independent[i];
      if (dark.set[i] < 0) continue;
      const double d2 = s.sigma_dark * s.sigma_dark;
      s.sigma = std::sqrt(s.sigma * s.sigma - d2);
      s.sigma_stat = std::sqrt(std::max(s.sigma_stat * s.sigma_stat - d2, 0.0));
    }
  }
  const std::span<const Sample> samples =
      dark.count > 0 ? std::span<const Sample>(independent) : input;
  // Geometry at the starting (or fixed) eta, computed once for every sample: the scan's.
  std::vector<FixedGeometry> geometry;
  geometry.reserve(samples.size());
  for (const Sample& s : samples) geometry.push_back(PrecomputeGeometry(s.light, s.view, o.eta));

  std::vector<ScanPoint> starts = Starts(samples, geometry, o);
  if (starts.empty())
    return Error{ErrorCode::kNumerical,
                 "the model is zero at every sample for every width tried: are the light and "
                 "view directions a geometry (transmission or reflection) the model can reach?"};

  // The samples' models, decided at the best start; every set stays alive while a problem that
  // was built on it may be the winner's.
  ResponseCache cache(samples.size());
  ReportProgress(o, std::string("a solve of ") + std::to_string(samples.size()) + " samples, floor " +
              (o.floor == Floor::kFit ? "fitted" : "off") + ": deciding their responses");
  auto modes = DecideModes(samples, o, cache, starts[0].width, starts[0].k, o.eta);
  if (!modes.ok()) return modes.error();
  // The samples as fitted: sigma with the quadrature's error where the budget held a model.
  std::vector<Sample> fitted;
  auto capped = WithQuadrature(samples, cache, fitted);
  std::vector<std::unique_ptr<std::vector<SampleModel>>> model_sets;
  auto build = [&](const std::vector<int>& m, double eta) {
    auto set = std::make_unique<std::vector<SampleModel>>();
    for (std::size_t i = 0; i < samples.size(); ++i)
      set->push_back(BuildModel(samples[i], i, cache, m[i], eta));
    model_sets.push_back(std::move(set));
    return std::span<const SampleModel>(*model_sets.back());
  };
  std::vector<double> sigmas;
  for (const Sample& s : samples) sigmas.push_back(s.sigma);
  auto decided = DecidedLevels(*modes, cache);
  // The held samples' corrections the models were built with (each with its slope and the width
  // it was taken at): a round whose corrections move a prediction by more than half the tolerance
  // from what the models carried them to has not settled either.
  struct Built {
    double correction, slope, log_width;
  };
  auto corrections = [&cache] {
    std::vector<Built> c;
    for (const auto& one : cache.of) c.push_back({one.correction, one.slope, one.log_width});
    return c;
  };
  std::vector<Built> built_with = corrections();
  Problem p{fitted,         build(*modes, o.eta), o.floor == Floor::kFit,
            Median(sigmas), o.stage.get(),        &dark};
  ReportProgress(o, DescribeModels(*modes, p.models, capped.first));

  // Local fits: the caller's start and the half-width estimate always run, then the best scan
  // minima, up to max_local_fits (plus those first two).
  const std::size_t n_fits = std::min(
      starts.size(), static_cast<std::size_t>(o.max_local_fits) + (o.initial_width ? 1 : 0) + 1);
  std::unique_ptr<LocalFit> winner;
  std::string first_failure;
  FitSummary out;
  out.model = o.model;
  for (std::size_t k = 0; k < n_fits; ++k) {
    std::unique_ptr<LocalFit> f = SolveFrom(p, o, starts[k].width, starts[k].k, o.eta, 0);
    ++out.local_fits;
    {
      std::ostringstream t;
      t << "local fit " << k + 1 << " of " << n_fits << " from " << WidthName(o.model.family) << " "
        << starts[k].width << ": " << (f->converged ? "converged" : "did not converge") << " after "
        << f->iterations << " iterations";
      ReportProgress(o, t.str());
    }
    if (f->converged && (!winner || f->cost < winner->cost))
      winner = std::move(f);
    else if (!f->converged && first_failure.empty())
      first_failure = f->message;
  }
  out.n_points = static_cast<int>(samples.size());
  out.n_params = o.NumParams();
  if (!winner) {
    out.status = FitStatus::kFailed;
    out.message = "no start converged: " + first_failure;
    return out;
  }
  // The response where it matters at the solution, until the decision settles.
  out.response.rounds = 1;
  for (int round = 0; round < 4; ++round) {
    const double w = std::exp(winner->x[0]), k = std::exp(winner->x[1]);
    const double eta = o.fit_eta ? EtaFromRaw(winner->x[2]) : o.eta;
    auto next = DecideModes(samples, o, cache, w, k, eta);
    if (!next.ok()) return next.error();
    auto now = DecidedLevels(*next, cache);
    const std::vector<Built> corrected = corrections();
    bool moved = false;
    for (std::size_t i = 0; i < samples.size(); ++i) {
      const Built& b = built_with[i];
      const double carried = b.correction * std::exp(b.slope * (std::log(w) - b.log_width));
      moved = moved || std::abs(corrected[i].correction - carried) * std::abs(samples[i].value) >
                           0.5 * o.response_tolerance * samples[i].sigma;
    }
    if (now == decided && !moved) break;
    decided = std::move(now);
    built_with = corrected;
    modes = std::move(next);
    capped = WithQuadrature(samples, cache, fitted);
    p.models = build(*modes, o.eta);
    ReportProgress(o,
         "responses re-decided at the solution: " + DescribeModels(*modes, p.models, capped.first));
    auto f = SolveFrom(p, o, w, k, eta, winner->x[3] * p.floor_unit);
    ++out.response.rounds;
    if (!f->converged) {
      out.status = FitStatus::kFailed;
      out.message = "the fit with the instrument response did not converge: " + f->message;
      return out;
    }
    winner = std::move(f);
  }
  // The held samples' error traced one level finer at the solution, and the solve again with
  // it: their models stay as decided, corrected to the streamed level.
  if (o.held_error == HeldError::kTraced && capped.first > 0) {
    const double w = std::exp(winner->x[0]), k = std::exp(winner->x[1]);
    const double eta = o.fit_eta ? EtaFromRaw(winner->x[2]) : o.eta;
    ReportProgress(o, "tracing the next level of the " + std::to_string(capped.first) +
                " samples held to the ray budget, at the solution");
    auto traced = TraceHeld(samples, o, cache, w, k, eta);
    if (!traced.ok()) return traced.error();
    out.response.capped_untraced_largest = capped.second;
    out.response.traced = *traced;
    capped = WithQuadrature(samples, cache, fitted);
    auto f = SolveFrom(p, o, w, k, eta, winner->x[3] * p.floor_unit);
    if (!f->converged) {
      out.status = FitStatus::kFailed;
      out.message = "the fit with the held samples' traced error did not converge: " + f->message;
      return out;
    }
    winner = std::move(f);
    std::ostringstream t;
    t << "the held samples' error traced (" << *traced << " of " << capped.first
      << "): the largest is " << std::setprecision(3) << capped.second
      << " of the sample's own sigma, where the change to the next level was "
      << out.response.capped_untraced_largest;
    ReportProgress(o, t.str());
  }
  const LocalFit& best = *winner;

  out.width.value = std::exp(best.x[0]);
  out.scale.value = std::exp(best.x[1]);
  out.eta.value = o.fit_eta ? EtaFromRaw(best.x[2]) : o.eta;
  out.floor.value = p.fit_floor ? best.x[3] * p.floor_unit : 0;
  out.floor_fitted = p.fit_floor;
  out.alpha_equivalent = AlphaEquivalent(o.model.family, out.width.value);
  out.iterations = best.iterations;
  for (std::size_t i = 0; i < samples.size(); ++i) {
    out.response.samples_with_response += samples[i].response.has_value();
    out.response.rectangle += (*modes)[i] >= 1;
    out.response.apertures += (*modes)[i] == 2;
    out.response.rays += static_cast<long>(p.models[i].g.size());
  }
  std::tie(out.response.capped, out.response.capped_largest) = capped;
  out.dark.sets = dark.count;
  out.dark.samples = dark.samples;
  for (int d = 0; d < dark.count; ++d)
    out.dark.largest_z = std::max(out.dark.largest_z, std::abs(best.dark_z[d]));
  FillStatistics(p, o, *winner, out);
  const bool cov_ok = FillUncertainties(*winner, p, o, out);
  JudgeFit(cov_ok, out);
  out.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  {
    std::ostringstream t;
    t << "solved: " << WidthName(o.model.family) << " " << out.width.value << ", chi2/dof "
      << out.reduced_chi2 << ", " << std::setprecision(3) << out.seconds << " s";
    ReportProgress(o, t.str());
  }
  return out;
}

}  // namespace gonio::fitting::internal
