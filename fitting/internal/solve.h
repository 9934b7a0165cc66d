// The solver's room: how the fitter parameterises a solve, models each sample, finds its starts
// and runs one local Ceres solve (the contract is fitting/fitter.h's). Internal to fitting/: the
// other rooms (response_budget, uncertainty, fit_once, floor_choice, geometry_profile) build on
// it; nothing outside fitting/ includes it.
//
// A solve sees log(width), log(k), eta through a logistic map onto (1, 3), and the floor in
// units of the samples' median sigma; each sample is a SampleModel (its nominal pair, or its
// response's rays); the sample stage's groups and the dark sets add one nuisance each, with a
// Gaussian prior (StageGroups, DarkSets).
#pragma once

#include <cmath>
#include <limits>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "fitting/fitter.h"
#include "fitting/model.h"
#include "fitting/sample.h"

namespace ceres {
class Problem;
}

namespace gonio::fitting::internal {

constexpr double kEtaMin = 1.0, kEtaSpan = 2.0;  // eta in (1, 3)

// Solver-side parameterisation (see the header): x = log(width), y = log(k), z = logit of eta.
template <typename T>
T EtaFromRaw(const T& z) {
  using std::exp;
  return T(kEtaMin) + T(kEtaSpan) / (T(1) + exp(-z));
}
inline double RawFromEta(double eta) {
  const double u = (eta - kEtaMin) / kEtaSpan;
  return std::log(u / (1 - u));
}

// How one sample is modelled: at its nominal pair (one geometry, weight 1), or through its
// response's rays (eq. R1: weights w_j / N). The geometry is precomputed at the fit's eta.
struct SampleModel {
  int mode = 0;  // 0: the point model; 1: the rectangle's rays; 2: rays and apertures
  std::vector<FixedGeometry> g;
  std::vector<double> w;
  // A model held to the ray budget: its correction (in w) was taken at ln width0, and moves with
  // the width as (width / width0)^slope (CorrectionAt).
  double log_width0 = 0, slope = 0;
};

// The factor by which a held model's correction has moved since it was taken: a narrow lobe's
// coarse cones are sharper than the finer ones, so the correction depends on the width, and a
// correction held fixed would give the fit the coarse model's sensitivity to it (a width 3 of its
// sigma off, with that sigma too small, on antiglare held to 600 rays).
template <typename T>
T CorrectionAt(const SampleModel& sm, const T& width) {
  using std::exp;
  using std::log;
  if (sm.slope == 0) return T(1);
  return exp(T(sm.slope) * (log(width) - T(sm.log_width0)));
}

// The sample stage's error common to a group of points (GeometryUse): per sample its group (-1:
// none) and the fitted model's slope dS/d(sample angle) there, per group its read-back angle, and
// the prior's sigma. A group is a consecutive run of samples, so its samples are one span.
struct StageGroups {
  std::vector<int> group;
  std::vector<double> slope;        // value units per degree
  std::vector<StageOffset> groups;  // read-back angle and size (offsets: the fit's)
  double prior_deg = 0;
};

// The dark sets a fit models (DarkUse): per sample its set's index (-1: none) and its sigma_dark.
struct DarkSets {
  std::vector<int> set;
  std::vector<double> sigma;
  int count = 0;
  int samples = 0;
};

// The sets of `samples` whose shared error matters (fitter.h, DarkUse), indexed from 0.
DarkSets DarkSetsOf(std::span<const Sample> samples);

// The options a solve runs with: the caller's, and the sample stage's groups once WithGeometry
// has them. The constructor is explicit so that no helper drops the groups by taking a
// FitOptions and passing it on.
struct SolveOptions : FitOptions {
  explicit SolveOptions(const FitOptions& f) : FitOptions(f) {}
  std::shared_ptr<const StageGroups> stage;
};

// sum_j w_j factor_j D G_j: the model at k = 1 and fixed eta.
template <typename T>
T FixedEtaValue(const ModelSpec& model, const SampleModel& sm, const T& width) {
  T sum(0);
  for (std::size_t j = 0; j < sm.g.size(); ++j)
    if (sm.g[j].factor > 0)
      sum += T(sm.w[j] * sm.g[j].factor) * DTimesShadowing(model, sm.g[j], width);
  return sum * CorrectionAt(sm, width);
}

// Tells o.progress what a long fit is doing, if anyone listens.
inline void ReportProgress(const FitOptions& o, const std::string& what) {
  if (o.progress) o.progress(what);
}

// Model values at k = 1 and the weighted least-squares k for them (linear in k).
struct ScanPoint {
  double alpha_equiv = 0;
  double width = 0;
  double k = 0;
  double cost = std::numeric_limits<double>::infinity();
};

// The scan's value at one width: the model at k = 1 over `geometry` (the samples' pairs at the
// fit's eta) and the k that minimises chi-square for it.
ScanPoint EvaluateWidth(std::span<const Sample> samples, std::span<const FixedGeometry> geometry,
                        const ModelSpec& model, double width);

// The largest number, over incidences, of samples whose prediction is at least half that
// incidence's largest prediction.
int PointsInLobe(std::span<const Sample> samples, std::span<const double> predicted);

// One local solve. The problem holds pointers to x, so a LocalFit lives on the heap and never
// moves while its problem is in use (the covariance is computed on the winner's problem).
struct LocalFit {
  double x[4];  // log width, log k, eta raw, floor (in floor units)
  // The sample stage's offsets (degrees), one per group and a last one for samples in none,
  // always 0 and not in the problem; sized before the problem is built, never after (the
  // problem points into it).
  std::vector<double> delta;
  // The dark sets' nuisances (DarkSets), one per set and a last one for samples in none, as delta.
  std::vector<double> dark_z;
  // The sample of each residual row: -1 for a stage offset's prior, -2 for a dark set's.
  std::vector<int> row_sample;
  double cost = std::numeric_limits<double>::infinity();
  bool converged = false;
  int iterations = 0;
  std::string message;
  std::unique_ptr<ceres::Problem> problem;
  ~LocalFit();  // where ceres::Problem is complete (solve.cc)
};

// What a solve needs besides the options: the samples' models, the floor's unit and the sample
// stage's groups (nullptr: none).
struct Problem {
  std::span<const Sample> samples;
  std::span<const SampleModel> models;
  bool fit_floor = false;
  double floor_unit = 1;  // the floor parameter is floor / floor_unit: O(1) for the solver
  const StageGroups* stage = nullptr;
  const DarkSets* dark = nullptr;  // nullptr or none: no set modelled

  int Groups() const { return stage ? static_cast<int>(stage->groups.size()) : 0; }
  int Sets() const { return dark ? dark->count : 0; }
  // The index into LocalFit::dark_z of sample i's set (the last, always 0, for none), and its
  // sigma_dark.
  int SetOf(std::size_t i) const { return Sets() > 0 && dark->set[i] >= 0 ? dark->set[i] : Sets(); }
  double DarkOf(std::size_t i) const { return Sets() > 0 ? dark->sigma[i] : 0; }
  // The index into LocalFit::delta of sample i's offset (the last, always 0, for none), and its
  // slope.
  int DeltaOf(std::size_t i) const {
    return stage && stage->group[i] >= 0 ? stage->group[i] : Groups();
  }
  bool InGroup(std::size_t i) const { return DeltaOf(i) < Groups(); }
  double SlopeOf(std::size_t i) const { return stage ? stage->slope[i] : 0; }
};

// One local solve from (width, k, eta, floor) over the problem's samples, with the options' loss,
// derivatives and iteration limit; the result holds its Ceres problem (for the covariance).
std::unique_ptr<LocalFit> SolveFrom(const Problem& p, const FitOptions& o, double width, double k,
                                    double eta, double floor);

// Starting points for the local fits: the caller's, the half-width estimate, then the local
// minima of a scan of the width on a log grid of alpha-equivalent (k at its optimum for each
// width), best first.
std::vector<ScanPoint> Starts(std::span<const Sample> samples,
                              std::span<const FixedGeometry> geometry, const FitOptions& o);

// The model's value of every sample at a solution (`delta`: the sample stage's offsets).
std::vector<double> Predictions(const Problem& p, const FitOptions& o, const FitSummary& out,
                                std::span<const double> delta, std::span<const double> dark_z);

}  // namespace gonio::fitting::internal
