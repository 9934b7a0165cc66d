#include "fitting/internal/fit_once.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <iomanip>
#include <memory>
#include <sstream>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include "fitting/internal/response_budget.h"
#include "fitting/internal/uncertainty.h"

namespace gonio::fitting::internal {
namespace {

double Median(std::vector<double> v) {
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

// The samples with the dark sets' shared parts out of each sigma (and its statistical part): one
// nuisance per set carries them (DarkUse), and the sigmas left are the independent parts.
std::vector<Sample> IndependentOfDarkSets(std::span<const Sample> input, const DarkSets& dark) {
  std::vector<Sample> independent(input.begin(), input.end());
  for (std::size_t i = 0; i < independent.size(); ++i) {
    Sample& s = independent[i];
    if (dark.set[i] < 0) continue;
    const double d2 = s.sigma_dark * s.sigma_dark;
    s.sigma = std::sqrt(s.sigma * s.sigma - d2);
    s.sigma_stat = std::sqrt(std::max(s.sigma_stat * s.sigma_stat - d2, 0.0));
  }
  return independent;
}

// A held sample's correction as its model was built: with its slope and the width it was taken
// at (SampleModel::slope, log_width0).
struct BuiltCorrection {
  double correction, slope, log_width;
};

// One FitOnce: the samples' models as decided so far, the problem over them and the solve's
// winner. Every model set stays alive while a problem built on it may be the winner's.
class OneFit {
 public:
  OneFit(std::span<const Sample> samples, const SolveOptions& o, const DarkSets& dark)
      : samples_(samples), o_(o), dark_(dark), cache_(samples.size()) {}

  // The models decided at the best start, then the local fits from the starts; false (with `out`
  // failed) when none converged.
  Result<bool> SolveFromStarts(const std::vector<ScanPoint>& starts, FitSummary& out);
  // The response where it matters at the solution, until the decision settles (up to 4 rounds);
  // false (with `out` failed) when a solve with new models does not converge.
  Result<bool> SettleResponses(FitSummary& out);
  // FitOptions::held_error = kTraced: the held samples' error traced one level finer at the
  // solution, and the solve again with it (their models stay as decided).
  Result<bool> TraceHeldError(FitSummary& out);
  // The winner's values, the response's and the dark sets' use, statistics, sigmas and verdict.
  void Summarise(FitSummary& out);

 private:
  std::span<const SampleModel> Build(const std::vector<int>& modes, double eta);
  std::vector<BuiltCorrection> Corrections() const;
  std::unique_ptr<LocalFit> SolveAtWinner();

  std::span<const Sample> samples_;
  const SolveOptions& o_;
  const DarkSets& dark_;
  ResponseCache cache_;
  std::vector<std::unique_ptr<std::vector<SampleModel>>> model_sets_;
  std::vector<Sample> fitted_;  // sigma with the quadrature's error where the budget held a model
  std::pair<int, double> capped_;
  std::vector<int> modes_;
  std::vector<std::array<int, 3>> decided_;
  std::vector<BuiltCorrection> built_with_;
  Problem p_;
  std::unique_ptr<LocalFit> winner_;
};

std::span<const SampleModel> OneFit::Build(const std::vector<int>& modes, double eta) {
  auto set = std::make_unique<std::vector<SampleModel>>();
  for (std::size_t i = 0; i < samples_.size(); ++i)
    set->push_back(BuildModel(samples_[i], i, cache_, modes[i], eta));
  model_sets_.push_back(std::move(set));
  return std::span<const SampleModel>(*model_sets_.back());
}

std::vector<BuiltCorrection> OneFit::Corrections() const {
  std::vector<BuiltCorrection> c;
  for (const auto& one : cache_.of) c.push_back({one.correction, one.slope, one.log_width});
  return c;
}

std::unique_ptr<LocalFit> OneFit::SolveAtWinner() {
  const double w = std::exp(winner_->x[0]), k = std::exp(winner_->x[1]);
  const double eta = o_.fit_eta ? EtaFromRaw(winner_->x[2]) : o_.eta;
  return SolveFrom(p_, o_, w, k, eta, winner_->x[3] * p_.floor_unit);
}

Result<bool> OneFit::SolveFromStarts(const std::vector<ScanPoint>& starts, FitSummary& out) {
  ReportProgress(o_, std::string("a solve of ") + std::to_string(samples_.size()) +
                         " samples, floor " + (o_.floor == Floor::kFit ? "fitted" : "off") +
                         ": deciding their responses");
  auto modes = DecideModes(samples_, o_, cache_, starts[0].width, starts[0].k, o_.eta);
  if (!modes.ok()) return modes.error();
  modes_ = std::move(modes).value();
  capped_ = WithQuadrature(samples_, cache_, fitted_);
  std::vector<double> sigmas;
  for (const Sample& s : samples_) sigmas.push_back(s.sigma);
  decided_ = DecidedLevels(modes_, cache_);
  // A round whose corrections move a prediction by more than half the tolerance from what the
  // models carried them to has not settled either (SettleResponses).
  built_with_ = Corrections();
  p_ = Problem{fitted_,        Build(modes_, o_.eta), o_.floor == Floor::kFit,
               Median(sigmas), o_.stage.get(),        &dark_};
  ReportProgress(o_, DescribeModels(modes_, p_.models, capped_.first));

  // Local fits: the caller's start and the half-width estimate always run, then the best scan
  // minima, up to max_local_fits (plus those first two).
  const std::size_t n_fits = std::min(
      starts.size(), static_cast<std::size_t>(o_.max_local_fits) + (o_.initial_width ? 1 : 0) + 1);
  std::string first_failure;
  for (std::size_t k = 0; k < n_fits; ++k) {
    std::unique_ptr<LocalFit> f = SolveFrom(p_, o_, starts[k].width, starts[k].k, o_.eta, 0);
    ++out.local_fits;
    std::ostringstream t;
    t << "local fit " << k + 1 << " of " << n_fits << " from " << WidthName(o_.model.family) << " "
      << starts[k].width << ": " << (f->converged ? "converged" : "did not converge") << " after "
      << f->iterations << " iterations";
    ReportProgress(o_, t.str());
    if (f->converged && (!winner_ || f->cost < winner_->cost))
      winner_ = std::move(f);
    else if (!f->converged && first_failure.empty())
      first_failure = f->message;
  }
  if (winner_) return true;
  out.status = FitStatus::kFailed;
  out.message = "no start converged: " + first_failure;
  return false;
}

Result<bool> OneFit::SettleResponses(FitSummary& out) {
  out.response.rounds = 1;
  for (int round = 0; round < 4; ++round) {
    const double w = std::exp(winner_->x[0]), k = std::exp(winner_->x[1]);
    const double eta = o_.fit_eta ? EtaFromRaw(winner_->x[2]) : o_.eta;
    auto next = DecideModes(samples_, o_, cache_, w, k, eta);
    if (!next.ok()) return next.error();
    auto now = DecidedLevels(*next, cache_);
    const std::vector<BuiltCorrection> corrected = Corrections();
    bool moved = false;
    for (std::size_t i = 0; i < samples_.size(); ++i) {
      const BuiltCorrection& b = built_with_[i];
      const double carried = b.correction * std::exp(b.slope * (std::log(w) - b.log_width));
      moved = moved || std::abs(corrected[i].correction - carried) * std::abs(samples_[i].value) >
                           0.5 * o_.response_tolerance * samples_[i].sigma;
    }
    if (now == decided_ && !moved) break;
    decided_ = std::move(now);
    built_with_ = corrected;
    modes_ = std::move(next).value();
    capped_ = WithQuadrature(samples_, cache_, fitted_);
    p_.models = Build(modes_, o_.eta);
    ReportProgress(o_, "responses re-decided at the solution: " +
                           DescribeModels(modes_, p_.models, capped_.first));
    auto f = SolveAtWinner();
    ++out.response.rounds;
    if (!f->converged) {
      out.status = FitStatus::kFailed;
      out.message = "the fit with the instrument response did not converge: " + f->message;
      return false;
    }
    winner_ = std::move(f);
  }
  return true;
}

Result<bool> OneFit::TraceHeldError(FitSummary& out) {
  if (o_.held_error != HeldError::kTraced || capped_.first == 0) return true;
  const double w = std::exp(winner_->x[0]), k = std::exp(winner_->x[1]);
  const double eta = o_.fit_eta ? EtaFromRaw(winner_->x[2]) : o_.eta;
  ReportProgress(o_, "tracing the next level of the " + std::to_string(capped_.first) +
                         " samples held to the ray budget, at the solution");
  auto traced = TraceHeld(samples_, o_, cache_, w, k, eta);
  if (!traced.ok()) return traced.error();
  out.response.capped_untraced_largest = capped_.second;
  out.response.traced = *traced;
  capped_ = WithQuadrature(samples_, cache_, fitted_);
  auto f = SolveAtWinner();
  if (!f->converged) {
    out.status = FitStatus::kFailed;
    out.message = "the fit with the held samples' traced error did not converge: " + f->message;
    return false;
  }
  winner_ = std::move(f);
  std::ostringstream t;
  t << "the held samples' error traced (" << *traced << " of " << capped_.first
    << "): the largest is " << std::setprecision(3) << capped_.second
    << " of the sample's own sigma, where the change to the next level was "
    << out.response.capped_untraced_largest;
  ReportProgress(o_, t.str());
  return true;
}

void OneFit::Summarise(FitSummary& out) {
  const LocalFit& best = *winner_;
  out.width.value = std::exp(best.x[0]);
  out.scale.value = std::exp(best.x[1]);
  out.eta.value = o_.fit_eta ? EtaFromRaw(best.x[2]) : o_.eta;
  out.floor.value = p_.fit_floor ? best.x[3] * p_.floor_unit : 0;
  out.floor_fitted = p_.fit_floor;
  out.alpha_equivalent = AlphaEquivalent(o_.model.family, out.width.value);
  out.iterations = best.iterations;
  for (std::size_t i = 0; i < samples_.size(); ++i) {
    out.response.samples_with_response += samples_[i].response.has_value();
    out.response.rectangle += modes_[i] >= 1;
    out.response.apertures += modes_[i] == 2;
    out.response.rays += static_cast<long>(p_.models[i].g.size());
  }
  std::tie(out.response.capped, out.response.capped_largest) = capped_;
  out.dark.sets = dark_.count;
  out.dark.samples = dark_.samples;
  for (int d = 0; d < dark_.count; ++d)
    out.dark.largest_z = std::max(out.dark.largest_z, std::abs(best.dark_z[d]));
  FillStatistics(p_, o_, *winner_, out);
  const bool cov_ok = FillUncertainties(*winner_, p_, o_, out);
  JudgeFit(cov_ok, out);
}

}  // namespace

Result<FitSummary> FitOnce(std::span<const Sample> input, const SolveOptions& o) {
  const auto t0 = std::chrono::steady_clock::now();
  const DarkSets dark = DarkSetsOf(input);
  std::vector<Sample> independent;
  if (dark.count > 0) independent = IndependentOfDarkSets(input, dark);
  const std::span<const Sample> samples =
      dark.count > 0 ? std::span<const Sample>(independent) : input;
  // Geometry at the starting (or fixed) eta, computed once for every sample: the scan's.
  std::vector<FixedGeometry> geometry;
  geometry.reserve(samples.size());
  for (const Sample& s : samples) geometry.push_back(PrecomputeGeometry(s.light, s.view, o.eta));
  const std::vector<ScanPoint> starts = Starts(samples, geometry, o);
  if (starts.empty())
    return Error{ErrorCode::kNumerical,
                 "the model is zero at every sample for every width tried: are the light and "
                 "view directions a geometry (transmission or reflection) the model can reach?"};

  FitSummary out;
  out.model = o.model;
  out.n_points = static_cast<int>(samples.size());
  out.n_params = o.NumParams();
  OneFit fit(samples, o, dark);
  Result<bool> going = fit.SolveFromStarts(starts, out);
  if (going.ok() && *going) going = fit.SettleResponses(out);
  if (going.ok() && *going) going = fit.TraceHeldError(out);
  if (!going.ok()) return going.error();
  if (!*going) return out;  // failed, and `out` says where
  fit.Summarise(out);
  out.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  std::ostringstream t;
  t << "solved: " << WidthName(o.model.family) << " " << out.width.value << ", chi2/dof "
    << out.reduced_chi2 << ", " << std::setprecision(3) << out.seconds << " s";
  ReportProgress(o, t.str());
  return out;
}

}  // namespace gonio::fitting::internal
