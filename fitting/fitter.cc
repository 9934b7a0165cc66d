#include "fitting/fitter.h"

#include <ceres/ceres.h>

#include <Eigen/Dense>
#include <algorithm>
#include <array>
#include <boost/math/special_functions/gamma.hpp>
#include <chrono>
#include <cmath>
#include <functional>
#include <iomanip>
#include <limits>
#include <map>
#include <memory>
#include <sstream>

namespace gonio::fitting {
namespace {

using optics::Vec3;
constexpr double kDeg = optics::kPi / 180;
constexpr double kEtaMin = 1.0, kEtaSpan = 2.0;  // eta in (1, 3)

// Solver-side parameterisation (see the header): x = log(width), y = log(k), z = logit of eta.
template <typename T>
T EtaFromRaw(const T& z) {
  using std::exp;
  return T(kEtaMin) + T(kEtaSpan) / (T(1) + exp(-z));
}
double RawFromEta(double eta) {
  const double u = (eta - kEtaMin) / kEtaSpan;
  return std::log(u / (1 - u));
}

// Whether a residual (double or Jet) and its derivatives are finite.
inline bool ResidualFinite(double x) { return std::isfinite(x); }
template <typename T>
bool ResidualFinite(const T& x) {
  return ceres::isfinite(x);
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
DarkSets DarkSetsOf(std::span<const Sample> samples) {
  std::map<int, std::pair<int, double>> sets;  // dark_set -> samples, sum of (sigma_dark/sigma)^2
  for (const Sample& s : samples)
    if (s.dark_set >= 0 && s.sigma_dark > 0) {
      auto& [n, share] = sets[s.dark_set];
      ++n;
      share += std::pow(s.sigma_dark / s.sigma, 2);
    }
  std::map<int, int> index;
  DarkSets d;
  for (const auto& [id, use] : sets)
    if (use.first >= 2 && use.second >= 0.01) index[id] = d.count++;
  d.set.assign(samples.size(), -1);
  d.sigma.assign(samples.size(), 0.0);
  for (std::size_t i = 0; i < samples.size(); ++i)
    if (auto it = index.find(samples[i].dark_set); it != index.end() && samples[i].sigma_dark > 0) {
      d.set[i] = it->second;
      d.sigma[i] = samples[i].sigma_dark;
      ++d.samples;
    }
  return d;
}

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

// Residual with eta free: the whole model on Jets, over the sample's pairs.
// `delta` is the sample stage's offset of the sample's group, entering through the slope
// (StageGroups); a sample in no group has the overload without it (no derivative to carry).
// With dark sets (DarkSets) every sample also takes its set's nuisance `z` through `dark`, its
// sigma_dark (a sample in none, or in no group, gets a constant block of 0).
struct Residual {
  ModelSpec model;
  const SampleModel* sm;
  double value, inv_sigma, floor_unit, slope, dark = 0;

  template <typename T>
  bool operator()(const T* log_width, const T* log_k, const T* eta_raw, const T* floor,
                  T* r) const {
    const T zero(0);
    return (*this)(log_width, log_k, eta_raw, floor, &zero, &zero, r);
  }

  template <typename T>
  bool operator()(const T* log_width, const T* log_k, const T* eta_raw, const T* floor,
                  const T* delta, T* r) const {
    const T zero(0);
    return (*this)(log_width, log_k, eta_raw, floor, delta, &zero, r);
  }

  template <typename T>
  bool operator()(const T* log_width, const T* log_k, const T* eta_raw, const T* floor,
                  const T* delta, const T* z, T* r) const {
    using std::exp;
    const T width = exp(log_width[0]), k = exp(log_k[0]), eta = EtaFromRaw(eta_raw[0]);
    T m(0);
    for (std::size_t j = 0; j < sm->g.size(); ++j)
      m += T(sm->w[j]) *
           MeasurementModel(model, Vec3<T>(sm->g[j].l), Vec3<T>(sm->g[j].v), width, k, eta);
    m *= CorrectionAt(*sm, width);
    r[0] = (m + floor[0] * T(floor_unit) + T(slope) * delta[0] + T(dark) * z[0] - T(value)) *
           T(inv_sigma);
    return ResidualFinite(r[0]);
  }
};

// Residual with eta fixed: the geometry is precomputed (model.h, FixedGeometry) and only
// D * shadowing is differentiated.
struct FixedEtaResidual {
  ModelSpec model;
  const SampleModel* sm;
  double value, inv_sigma, floor_unit, slope, dark = 0;

  template <typename T>
  bool operator()(const T* log_width, const T* log_k, const T* floor, T* r) const {
    const T zero(0);
    return (*this)(log_width, log_k, floor, &zero, &zero, r);
  }

  template <typename T>
  bool operator()(const T* log_width, const T* log_k, const T* floor, const T* delta, T* r) const {
    const T zero(0);
    return (*this)(log_width, log_k, floor, delta, &zero, r);
  }

  template <typename T>
  bool operator()(const T* log_width, const T* log_k, const T* floor, const T* delta, const T* z,
                  T* r) const {
    using std::exp;
    const T m = exp(log_k[0]) * FixedEtaValue(model, *sm, exp(log_width[0]));
    r[0] = (m + floor[0] * T(floor_unit) + T(slope) * delta[0] + T(dark) * z[0] - T(value)) *
           T(inv_sigma);
    return ResidualFinite(r[0]);
  }
};

// All samples in one residual block (eta fixed, no robust loss): the same arithmetic without
// Ceres' per-block bookkeeping, which dominates the cost of small fits. A robust loss applies
// per residual block, so with one the samples keep a block each. Point-model samples share the
// light part of the shadowing per incidence. One block per group of the sample stage (the
// group's offset `delta`, through each sample's slope), and one per run of samples in none.
struct BatchFixedEtaResidual {
  ModelSpec model;
  std::span<const SampleModel> sm;
  std::span<const Sample> samples;
  std::span<const double> slope;
  double floor_unit;
  std::vector<Vec3<double>> lights;   // distinct light directions of point-model samples
  std::vector<std::size_t> light_of;  // per sample, index into lights (point model only)

  BatchFixedEtaResidual(const ModelSpec& m, std::span<const SampleModel> models,
                        std::span<const Sample> s, std::span<const double> slopes,
                        double floor_scale)
      : model(m),
        sm(models),
        samples(s),
        slope(slopes),
        floor_unit(floor_scale),
        light_of(s.size()) {
    for (std::size_t i = 0; i < s.size(); ++i) {
      if (sm[i].mode != 0) continue;
      const Vec3<double>& l = sm[i].g[0].l;
      std::size_t k = 0;
      while (k < lights.size() && optics::LengthSquared(lights[k] - l) > 0) ++k;
      if (k == lights.size()) lights.push_back(l);
      light_of[i] = k;
    }
  }

  template <typename T>
  bool operator()(const T* log_width, const T* log_k, const T* floor, T* r) const {
    const T zero(0);
    return (*this)(log_width, log_k, floor, &zero, r);
  }

  template <typename T>
  bool operator()(const T* log_width, const T* log_k, const T* floor, const T* delta, T* r) const {
    using std::exp;
    const T width = exp(log_width[0]), k = exp(log_k[0]);
    std::vector<T> k_shadow_light(lights.size());
    for (std::size_t j = 0; j < lights.size(); ++j)
      k_shadow_light[j] = k * ShadowingLight(model, lights[j], width);
    const T b = floor[0] * T(floor_unit);
    for (std::size_t i = 0; i < sm.size(); ++i) {
      const FixedGeometry& g0 = sm[i].g[0];
      const T m = sm[i].mode != 0 ? k * FixedEtaValue(model, sm[i], width)
                  : g0.factor > 0 ? k_shadow_light[light_of[i]] * T(g0.factor) *
                                        DTimesShadowingView(model, g0, width)
                                  : T(0);
      // Empty slopes: the fit has no stage groups (a run in none has slopes of 0 and delta 0).
      const T shift = slope.empty() ? T(0) : T(slope[i]) * delta[0];
      r[i] = (m + b + shift - T(samples[i].value)) * T(1 / samples[i].sigma);
      // A step to a width where the model overflows is refused quietly (the trust region
      // shrinks), rather than reported by Ceres as a broken cost function.
      if (!ResidualFinite(r[i])) return false;
    }
    return true;
  }
};

// Model values at k = 1 and the weighted least-squares k for them (linear in k).
struct ScanPoint {
  double alpha_equiv = 0;
  double width = 0;
  double k = 0;
  double cost = std::numeric_limits<double>::infinity();
};

ScanPoint EvaluateWidth(std::span<const Sample> samples, std::span<const FixedGeometry> geometry,
                        const ModelSpec& model, double width) {
  ScanPoint p;
  p.width = width;
  p.alpha_equiv = AlphaEquivalent(model.family, width);
  double sym = 0, smm = 0;
  std::vector<double> m(samples.size());
  for (std::size_t k = 0; k < samples.size(); ++k) {
    const Sample& s = samples[k];
    const FixedGeometry& g = geometry[k];
    m[k] = g.factor > 0 ? g.factor * DTimesShadowing(model, g, width) : 0.0;
    const double w = 1 / (s.sigma * s.sigma);
    sym += w * s.value * m[k];
    smm += w * m[k] * m[k];
  }
  if (!(smm > 0) || !(sym > 0)) return p;
  p.k = sym / smm;
  p.cost = 0;
  for (std::size_t k = 0; k < samples.size(); ++k) {
    const double r = (p.k * m[k] - samples[k].value) / samples[k].sigma;
    p.cost += r * r;
  }
  return p;
}

// The largest number, over incidences, of samples whose prediction is at least half that
// incidence's largest prediction.
int PointsInLobe(std::span<const Sample> samples, std::span<const double> predicted) {
  std::vector<Vec3<double>> lights;
  std::vector<double> peak;
  std::vector<std::size_t> group(samples.size());
  for (std::size_t i = 0; i < samples.size(); ++i) {
    std::size_t g = 0;
    while (g < lights.size() && optics::LengthSquared(lights[g] - samples[i].light) > 1e-12) ++g;
    if (g == lights.size()) lights.push_back(samples[i].light), peak.push_back(0);
    group[i] = g;
    peak[g] = std::max(peak[g], predicted[i]);
  }
  std::vector<int> count(lights.size(), 0);
  for (std::size_t i = 0; i < samples.size(); ++i)
    count[group[i]] += peak[group[i]] > 0 && predicted[i] >= 0.5 * peak[group[i]];
  return count.empty() ? 0 : *std::max_element(count.begin(), count.end());
}

// Covariance of the solver parameters, (J^T J)^-1 from one Jacobian evaluation at the solution
// (with the robust loss's correction when there is one, as ceres::Covariance would). Returns
// false when J^T J is singular to working precision: some direction is not constrained.
bool Covariance(ceres::Problem& problem, std::vector<double*> blocks, Eigen::MatrixXd* cov,
                ceres::CRSMatrix* jacobian = nullptr) {
  ceres::Problem::EvaluateOptions eo;
  eo.parameter_blocks = blocks;
  ceres::CRSMatrix local;
  ceres::CRSMatrix& j = jacobian ? *jacobian : local;
  if (!problem.Evaluate(eo, nullptr, nullptr, nullptr, &j)) return false;
  const int p = j.num_cols;
  Eigen::MatrixXd jtj = Eigen::MatrixXd::Zero(p, p);
  for (int r = 0; r < j.num_rows; ++r)
    for (int a = j.rows[r]; a < j.rows[r + 1]; ++a)
      for (int b = j.rows[r]; b < j.rows[r + 1]; ++b)
        jtj(j.cols[a], j.cols[b]) += j.values[a] * j.values[b];
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(jtj);
  if (es.info() != Eigen::Success) return false;
  const Eigen::VectorXd ev = es.eigenvalues();  // ascending
  if (!(ev(p - 1) > 0) || !(ev(0) > 1e-14 * ev(p - 1))) return false;
  *cov = es.eigenvectors() * ev.cwiseInverse().asDiagonal() * es.eigenvectors().transpose();
  return true;
}

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

// The prior of a group's offset: a pseudo-observation of 0 with sigma prior_deg.
struct PriorResidual {
  double inv_sigma;
  template <typename T>
  bool operator()(const T* delta, T* r) const {
    r[0] = delta[0] * T(inv_sigma);
    return true;
  }
};

// A cost of `r` (owned) with automatic or numeric (central) derivatives: kResiduals residuals
// (ceres::DYNAMIC: n of them) over parameter blocks of the sizes kBlocks.
template <typename F, int kResiduals, int... kBlocks>
ceres::CostFunction* MakeCost(F* r, bool automatic, int n = 1) {
  if constexpr (kResiduals == ceres::DYNAMIC) {
    if (automatic) return new ceres::AutoDiffCostFunction<F, kResiduals, kBlocks...>(r, n);
    return new ceres::NumericDiffCostFunction<F, ceres::CENTRAL, kResiduals, kBlocks...>(
        r, ceres::TAKE_OWNERSHIP, n);
  } else {
    if (automatic) return new ceres::AutoDiffCostFunction<F, kResiduals, kBlocks...>(r);
    return new ceres::NumericDiffCostFunction<F, ceres::CENTRAL, kResiduals, kBlocks...>(r);
  }
}

std::unique_ptr<LocalFit> SolveFrom(const Problem& p, const FitOptions& o, double width, double k,
                                    double eta, double floor) {
  auto fit = std::make_unique<LocalFit>();
  LocalFit& f = *fit;
  f.x[0] = std::log(width);
  f.x[1] = std::log(k);
  f.x[2] = RawFromEta(eta);
  f.x[3] = floor / p.floor_unit;
  const int groups = p.Groups(), sets = p.Sets();
  f.delta.assign(groups + 1, 0.0);
  f.dark_z.assign(sets + 1, 0.0);
  f.problem = std::make_unique<ceres::Problem>();
  ceres::Problem* problem = f.problem.get();
  const bool automatic = o.derivatives == Derivatives::kAutomatic;
  const std::size_t n_samples = p.samples.size();
  // The batch needs its samples' nuisances to be one block; a dark set spans the stage's groups,
  // so with sets every sample has a block of its own.
  const bool per_sample = o.fit_eta || o.loss != Loss::kNone || sets > 0;
  if (!per_sample) {
    // One block per consecutive run of samples sharing an offset (the whole set without groups).
    for (std::size_t a = 0, b = 0; a < n_samples; a = b) {
      while (b < n_samples && p.DeltaOf(b) == p.DeltaOf(a)) ++b;
      const std::size_t len = b - a;
      std::span<const double> slopes;
      if (p.stage) slopes = std::span<const double>(p.stage->slope).subspan(a, len);
      auto* r = new BatchFixedEtaResidual(o.model, p.models.subspan(a, len),
                                          p.samples.subspan(a, len), slopes, p.floor_unit);
      const int n = static_cast<int>(len);
      using Batch = BatchFixedEtaResidual;
      if (p.InGroup(a))
        problem->AddResidualBlock(MakeCost<Batch, ceres::DYNAMIC, 1, 1, 1, 1>(r, automatic, n),
                                  nullptr, &f.x[0], &f.x[1], &f.x[3], &f.delta[p.DeltaOf(a)]);
      else
        problem->AddResidualBlock(MakeCost<Batch, ceres::DYNAMIC, 1, 1, 1>(r, automatic, n),
                                  nullptr, &f.x[0], &f.x[1], &f.x[3]);
      for (std::size_t i = a; i < b; ++i) f.row_sample.push_back(static_cast<int>(i));
    }
  }
  for (std::size_t i = 0; i < n_samples && per_sample; ++i) {
    const Sample& s = p.samples[i];
    ceres::LossFunction* loss = nullptr;
    if (o.loss == Loss::kHuber) loss = new ceres::HuberLoss(o.loss_scale);
    if (o.loss == Loss::kCauchy) loss = new ceres::CauchyLoss(o.loss_scale);
    // With dark sets, every sample takes a stage offset and a set's nuisance (the constant last
    // ones where it has none); without, the offset only where it is in a group.
    const bool grouped = p.InGroup(i) || sets > 0;
    ceres::CostFunction* cost = nullptr;
    if (o.fit_eta) {
      auto* r = new Residual{o.model,      &p.models[i], s.value,    1 / s.sigma,
                             p.floor_unit, p.SlopeOf(i), p.DarkOf(i)};
      cost = sets > 0  ? MakeCost<Residual, 1, 1, 1, 1, 1, 1, 1>(r, automatic)
             : grouped ? MakeCost<Residual, 1, 1, 1, 1, 1, 1>(r, automatic)
                       : MakeCost<Residual, 1, 1, 1, 1, 1>(r, automatic);
    } else {
      auto* r = new FixedEtaResidual{o.model,      &p.models[i], s.value,    1 / s.sigma,
                                     p.floor_unit, p.SlopeOf(i), p.DarkOf(i)};
      cost = sets > 0  ? MakeCost<FixedEtaResidual, 1, 1, 1, 1, 1, 1>(r, automatic)
             : grouped ? MakeCost<FixedEtaResidual, 1, 1, 1, 1, 1>(r, automatic)
                       : MakeCost<FixedEtaResidual, 1, 1, 1, 1>(r, automatic);
    }
    std::vector<double*> blocks = {&f.x[0], &f.x[1]};
    if (o.fit_eta) blocks.push_back(&f.x[2]);
    blocks.push_back(&f.x[3]);
    if (grouped) blocks.push_back(&f.delta[p.DeltaOf(i)]);
    if (sets > 0) blocks.push_back(&f.dark_z[p.SetOf(i)]);
    problem->AddResidualBlock(cost, loss, blocks);
    f.row_sample.push_back(static_cast<int>(i));
  }
  for (int g = 0; g < groups; ++g) {
    problem->AddResidualBlock(
        MakeCost<PriorResidual, 1, 1>(new PriorResidual{1 / p.stage->prior_deg}, true), nullptr,
        &f.delta[g]);
    f.row_sample.push_back(-1);
  }
  for (int d = 0; d < sets; ++d) {
    problem->AddResidualBlock(MakeCost<PriorResidual, 1, 1>(new PriorResidual{1.0}, true), nullptr,
                              &f.dark_z[d]);
    f.row_sample.push_back(-2);
  }
  // The "none" offset and nuisance stay 0 (they are in the problem only with dark sets).
  for (double* none : {&f.delta[groups], &f.dark_z[sets]})
    if (problem->HasParameterBlock(none)) problem->SetParameterBlockConstant(none);
  if (!p.fit_floor) problem->SetParameterBlockConstant(&f.x[3]);

  ceres::Solver::Options so;
  so.linear_solver_type = ceres::DENSE_QR;
  so.max_num_iterations = o.max_iterations;
  so.function_tolerance = 1e-14;
  so.parameter_tolerance = 1e-12;
  so.gradient_tolerance = 1e-14;
  so.logging_type = ceres::SILENT;
  so.num_threads = 1;
  ceres::Solver::Summary summary;
  ceres::Solve(so, problem, &summary);
  f.cost = 2 * summary.final_cost;  // Ceres' cost is half the sum of squares
  f.iterations = static_cast<int>(summary.iterations.size()) - 1;
  f.converged = summary.termination_type == ceres::CONVERGENCE && std::isfinite(f.cost);
  if (!f.converged) f.message = summary.message;
  return fit;
}

// ---- The instrument response: which samples need it ---------------------------------------

// A level held below the one asked for (the budget): the next level's value over its own, and
// their difference in value units (0 and ratio 1 where not held).
struct Held {
  double ratio = 1, change = 0;
  int streamed = -1;          // the index of the level streamed (-1: not held)
  double slope = 0;           // d ln(ratio) / d ln(width)
  double streamed_value = 0;  // at k = 1 and the decision's width
};

// Each sample's responses by refinement level (response.h), computed once per fit when first
// needed, and the levels last chosen (a sample is never coarsened again within a fit).
struct ResponseCache {
  struct PerSample {
    std::vector<std::optional<Response>> rectangle, apertures;
    // The rectangle's coarsest rays spread over the apertures' coarsest cones: whether the
    // apertures matter anywhere in the rectangle (DecideMode).
    std::optional<Response> aperture_probe;
    int rectangle_level = 0, aperture_level = 0;
    // Where FitOptions::max_response_rays held the model below the level asked for, at the last
    // decision: the next level's value over the held one's, which the model is scaled by (its
    // correction), and their difference (value units), the quadrature's error that sigma takes
    // in; 1 and 0 otherwise.
    double correction = 1;
    double quadrature = 0;
    // Each step as the last decision held it (streamed = -1 where not), and the rectangle level
    // the apertures' step stood on: TraceHeld traces one level finer than each streamed one
    // (FitOptions::held_error), reusing its streamed value at the decision's width.
    Held rectangle_held, apertures_held;
    int apertures_on = 0;
    // d ln(correction) / d ln(width) at the decision's width (SampleModel::slope).
    double slope = 0, log_width = 0;
    bool IsHeld() const { return rectangle_held.streamed >= 0 || apertures_held.streamed >= 0; }
  };
  std::vector<PerSample> of;
  explicit ResponseCache(std::size_t n) : of(n) {}
};

// sum_j w_j f(l_j, v_j) |cos theta_lj| / N at k = 1 (eq. R1), in double.
double ResponseValue(const ModelSpec& m, const Response& r, double width, double eta) {
  double sum = 0;
  for (const ResponseRay& ray : r.rays)
    sum += ray.weight * MeasurementModel(m, ray.l, ray.v, width, 1.0, eta);
  return sum / r.pixels;
}

// The aperture-averaged point model at the nominal pair, at k = 1.
double NominalAperturesValue(const ModelSpec& m, const Response& r, double width, double eta) {
  double sum = 0;
  for (const ResponseRay& ray :
       ApertureCones(r.l0, r.v0, 1.0, r.source_half_angle, r.receiver_half_angle))
    sum += ray.weight * MeasurementModel(m, ray.l, ray.v, width, 1.0, eta);
  return sum;
}

// A sample's response at a level (nullptr past the finest).
Result<const Response*> ResponseAt(ResponseCache::PerSample& c, bool apertures, int level,
                                   const Sample& s, std::size_t i) {
  const auto lv = apertures ? ApertureLevel(level, c.rectangle_level) : RectangleLevel(level);
  if (!lv) return static_cast<const Response*>(nullptr);
  auto& slots = apertures ? c.apertures : c.rectangle;
  // Sized once for every level, so that pointers to computed responses stay valid.
  if (slots.empty()) slots.resize(8);
  if (!slots[level]) {
    auto r = ComputeAtLevel(*s.response->setup, s.response->at, *lv);
    if (!r.ok())
      return Error{r.error().code, Where(s, i) + ": its instrument response: " + r.error().message};
    slots[level] = std::move(r).value();
  }
  return &*slots[level];
}

// The model at k = 1 over a level's rays without holding them (one finer than the budget).
Result<double> StreamedValue(const ModelSpec& m, const Sample& s, std::size_t i,
                             const ResponseLevel& level, double width, double eta) {
  auto v = MeanOverLevel(*s.response->setup, s.response->at, level, [&](const ResponseRay& ray) {
    return MeasurementModel(m, ray.l, ray.v, width, 1.0, eta);
  });
  if (!v.ok())
    return Error{v.error().code, Where(s, i) + ": its instrument response: " + v.error().message};
  return *v;
}

// The step in ln(width) over which a held ratio's slope is taken (forward: one more streamed
// evaluation of each level).
constexpr double kSlopeStep = 1e-3;

// d ln(finer / held) / d ln(width) from the two levels at width and at width e^kSlopeStep (at
// k = 1); 0 where a value is not positive.
double RatioSlope(double held, double finer, double held_up, double finer_up) {
  if (!(held > 0 && finer > 0 && held_up > 0 && finer_up > 0)) return 0;
  return (std::log(finer_up / held_up) - std::log(finer / held)) / kSlopeStep;
}
Held HeldAt(double held, double finer, double allowed) {
  const double change = std::abs(finer - held);
  if (change <= 0.5 * allowed) return {};
  return {held > 0 ? finer / held : 1.0, change};
}

// From level `from` on, the coarsest level whose value the next finer one changes by at most
// `allowed` / 2 (or the finest): a narrow lobe under a large rectangle needs more rays than a
// wide one. A next level of more than `max_rays` rays is evaluated streamed and not taken: the
// level returned is the last within the budget, and `*held` says by how much it falls short.
Result<int> Refine(const ModelSpec& m, ResponseCache::PerSample& c, bool apertures, int from,
                   const Sample& s, std::size_t i, double width, double k, double eta,
                   double allowed, long max_rays, Held* held) {
  *held = {};
  auto cur = ResponseAt(c, apertures, from, s, i);
  if (!cur.ok()) return cur.error();
  double value = k * ResponseValue(m, **cur, width, eta);
  for (int level = from;; ++level) {
    const auto lv =
        apertures ? ApertureLevel(level + 1, c.rectangle_level) : RectangleLevel(level + 1);
    if (lv && MaxRaysAtLevel(*s.response->setup, *lv) > max_rays) {
      auto streamed = StreamedValue(m, s, i, *lv, width, eta);
      if (!streamed.ok()) return streamed.error();
      *held = HeldAt(value, k * *streamed, allowed);
      if (held->change > 0) {
        held->streamed = level + 1;
        held->streamed_value = *streamed;
        auto here = ResponseAt(c, apertures, level, s, i);
        if (!here.ok()) return here.error();
        const double up = width * std::exp(kSlopeStep);
        auto streamed_up = StreamedValue(m, s, i, *lv, up, eta);
        if (!streamed_up.ok()) return streamed_up.error();
        held->slope =
            RatioSlope(value / k, *streamed, ResponseValue(m, **here, up, eta), *streamed_up);
      }
      return level;
    }
    auto next = ResponseAt(c, apertures, level + 1, s, i);
    if (!next.ok()) return next.error();
    if (*next == nullptr) return level;
    const double finer = k * ResponseValue(m, **next, width, eta);
    if (std::abs(finer - value) <= 0.5 * allowed) return level;
    value = finer;
  }
}

// The mode a sample needs at (width, k, eta): the point model while the response changes its
// prediction by at most tolerance * sigma, the rectangle's rays otherwise, and the apertures on
// top where they change the nominal value by more than that too; each refined until finer rays
// change it by at most half that.
Result<int> DecideMode(const ModelSpec& m, const Sample& s, std::size_t i, ResponseCache& cache,
                       double width, double k, double eta, double tolerance, long max_rays) {
  if (!s.response || !s.response->setup) return 0;
  ResponseCache::PerSample& c = cache.of[i];
  c.quadrature = 0;
  c.correction = 1;
  c.rectangle_held = c.apertures_held = {};
  auto coarse = ResponseAt(c, false, 0, s, i);
  if (!coarse.ok()) return coarse.error();
  const Response& r0 = **coarse;
  const double point = k * MeasurementModel(m, r0.l0, r0.v0, width, 1.0, eta);
  const double allowed = tolerance * s.sigma;
  Held rectangle_held;
  auto level = Refine(m, c, false, c.rectangle_level, s, i, width, k, eta, allowed, max_rays,
                      &rectangle_held);
  if (!level.ok()) return level.error();
  if (*level != c.rectangle_level) {  // the apertures' responses were built on the old rays
    c.apertures.clear();
    c.aperture_level = 0;
  }
  c.rectangle_level = *level;
  const Response& rect = *c.rectangle[c.rectangle_level];
  int mode = std::abs(k * ResponseValue(m, rect, width, eta) - point) > allowed ? 1 : 0;
  // The apertures matter where they change the nominal pair's value, or the rectangle's: under a
  // large rectangle a point in a narrow lobe's far tail takes its value from the pixels nearest
  // the lobe, which the cones reach into while the nominal pair's cones do not (antiglare under
  // 3 x 10 mm, 2 deg off its peak at normal incidence: the apertures add 1.1e-4 at the nominal
  // pair, 0.06 sigma, and 0.019 over the rectangle, 9.5 sigma; judged at the nominal pair alone,
  // the fit modelled it without them and invented a floor three times the true stray light).
  if (!c.aperture_probe) {
    auto probe = ComputeAtLevel(*s.response->setup, s.response->at,
                                *ApertureLevel(0, /*rectangle_level=*/0));
    if (!probe.ok())
      return Error{probe.error().code,
                   Where(s, i) + ": its instrument response: " + probe.error().message};
    c.aperture_probe = std::move(probe).value();
  }
  const bool apertures_matter =
      k * std::abs(NominalAperturesValue(m, r0, width, eta) - point / k) > allowed ||
      k * std::abs(ResponseValue(m, *c.aperture_probe, width, eta) -
                   ResponseValue(m, r0, width, eta)) >
          allowed;
  Held apertures_held;
  const auto coarsest = ApertureLevel(c.aperture_level, c.rectangle_level);
  if (apertures_matter &&
      MaxRaysAtLevel(*s.response->setup, *coarsest) > max_rays) {  // none fits the budget
    auto streamed = StreamedValue(m, s, i, *coarsest, width, eta);
    if (!streamed.ok()) return streamed.error();
    apertures_held = HeldAt(k * ResponseValue(m, rect, width, eta), k * *streamed, allowed);
    if (apertures_held.change > 0) {
      apertures_held.streamed = c.aperture_level;
      apertures_held.streamed_value = *streamed;
      const double up = width * std::exp(kSlopeStep);
      auto streamed_up = StreamedValue(m, s, i, *coarsest, up, eta);
      if (!streamed_up.ok()) return streamed_up.error();
      apertures_held.slope = RatioSlope(ResponseValue(m, rect, width, eta), *streamed,
                                        ResponseValue(m, rect, up, eta), *streamed_up);
    }
  } else if (apertures_matter) {
    mode = 2;
    auto ap = Refine(m, c, true, c.aperture_level, s, i, width, k, eta, allowed, max_rays,
                     &apertures_held);
    if (!ap.ok()) return ap.error();
    c.aperture_level = *ap;
  }
  // Each held step's ratio corrects the model to the finer value at this estimate, with its slope
  // in the width (the rounds take both again as the fit moves); each change, the error of a model
  // that would not be corrected, stays in sigma until the fit has settled, when TraceHeld
  // replaces it with the corrected model's own error (FitOptions::held_error).
  c.correction = rectangle_held.ratio * apertures_held.ratio;
  c.quadrature = std::hypot(rectangle_held.change, apertures_held.change);
  c.rectangle_held = rectangle_held;
  c.apertures_held = apertures_held;
  c.slope = rectangle_held.slope + apertures_held.slope;  // the ratios multiply
  c.log_width = std::log(width);
  c.apertures_on = c.rectangle_level;
  if (c.quadrature > 0 && mode == 0) mode = 1;  // the correction is the rectangle's
  return mode;
}

SampleModel BuildModel(const Sample& s, std::size_t i, const ResponseCache& cache, int mode,
                       double eta) {
  SampleModel sm;
  sm.mode = mode;
  const ResponseCache::PerSample& c = cache.of[i];
  if (c.IsHeld()) {
    sm.slope = c.slope;
    sm.log_width0 = c.log_width;
  }
  const Response* r = mode == 2   ? &*c.apertures[c.aperture_level]
                      : mode == 1 ? &*c.rectangle[c.rectangle_level]
                                  : nullptr;
  if (r == nullptr) {
    const bool has = !c.rectangle.empty() && c.rectangle[0].has_value();
    sm.g.push_back(has ? PrecomputeGeometry(c.rectangle[0]->l0, c.rectangle[0]->v0, eta)
                       : PrecomputeGeometry(s.light, s.view, eta));
    sm.w.push_back(c.correction);
    return sm;
  }
  sm.g.reserve(r->rays.size());
  for (const ResponseRay& ray : r->rays) {
    sm.g.push_back(PrecomputeGeometry(ray.l, ray.v, eta));
    sm.w.push_back(c.correction * ray.weight / r->pixels);
  }
  return sm;
}

// A setup moved to the geometry a fit found (GeometryUse's fitted offsets; 0 where not fitted).
// The rectangle d pixels along an axis is the optical axis as far the other way.
void MoveToFitted(const GeometryUse& g, ResponseSetup& c) {
  c.thickness_mm += g.thickness.offset;
  c.bench.axis_x_px -= g.rectangle_x.offset * c.rectangle.binning_h;
  c.bench.axis_y_px -= g.rectangle_y.offset * c.rectangle.binning_v;
}

// The fitted model's value for a sample as the fit models it (through its response where that
// matters, Predict's choice), with the sample's stage position moved to `at`; without the floor
// and the sample stage's offset.
double ModelAt(const FitSummary& f, const Sample& sample, const StagePosition& at) {
  const double w = f.width.value, k = f.scale.value, eta = f.eta.value;
  if (!sample.response || !sample.response->setup) {
    return MeasurementModel(f.model, sample.light, sample.view, w, k, eta);
  }
  Sample s = sample;
  const StagePosition& was = sample.response->at;
  if (at.sample_deg != was.sample_deg || at.arm_deg != was.arm_deg ||
      at.azimuth_deg != was.azimuth_deg) {  // moved: its nominal pair moves with it
    s.response->at = at;
    std::tie(s.light, s.view) = NominalDirections(at);
  }
  ResponseCache cache(1);
  const FitOptions defaults;
  auto mode = DecideMode(f.model, s, 0, cache, w, k, eta, defaults.response_tolerance,
                         defaults.max_response_rays);
  if (!mode.ok()) return MeasurementModel(f.model, s.light, s.view, w, k, eta);
  const SampleModel sm = BuildModel(s, 0, cache, *mode, eta);
  double value = 0;
  for (std::size_t j = 0; j < sm.g.size(); ++j)
    value += sm.w[j] * MeasurementModel(f.model, sm.g[j].l, sm.g[j].v, w, k, eta);
  return value;
}

// The fitted model's slopes dS/d(sample stage) and dS/d(arm) at a sample's read-back position
// (value units per degree), by central differences of the model as the fit takes it (ModelAt):
// on a narrow lobe the rectangle and the apertures widen the flanks, and the point model's slopes
// put the sample stage's offsets where the data do not (on antiglare the offsets found missed
// those the simulator drew by 2-3 of their sigmas, and the thickness and the rectangle took the
// rest). 0, 0 for a sample without a response. Each slope is two response builds.
double StageSlope(const FitSummary& f, const Sample& s, double StagePosition::*axis) {
  if (!s.response || !s.response->setup) return 0.0;
  const double h = 0.01;  // deg: the slope over a hundredth of a degree
  StagePosition a = s.response->at, b = s.response->at;
  a.*axis += h;
  b.*axis -= h;
  return (ModelAt(f, s, a) - ModelAt(f, s, b)) / (2 * h);
}

std::pair<double, double> StageSlopes(const FitSummary& f, const Sample& s) {
  return {StageSlope(f, s, &StagePosition::sample_deg), StageSlope(f, s, &StagePosition::arm_deg)};
}

}  // namespace

const char* ToString(FitStatus s) {
  switch (s) {
    case FitStatus::kConverged:
      return "converged";
    case FitStatus::kUnconstrained:
      return "unconstrained";
    case FitStatus::kPoorFit:
      return "poor fit";
    case FitStatus::kFailed:
      return "failed";
  }
  return "?";
}

Status FitOptions::Validate() const {
  if (!(eta > 1 && eta < 3)) return InvalidArgument("eta must lie in (1, 3)");
  if (!(loss_scale > 0)) return InvalidArgument("loss_scale must be > 0");
  if (initial_width && !(*initial_width > 0 && std::isfinite(*initial_width)))
    return InvalidArgument("initial_width must be a finite number > 0");
  if (max_local_fits < 1) return InvalidArgument("max_local_fits must be >= 1");
  if (scan_points < 4) return InvalidArgument("scan_points must be >= 4");
  if (max_iterations < 1) return InvalidArgument("max_iterations must be >= 1");
  if (!(std::isfinite(response_tolerance) && response_tolerance >= 0))
    return InvalidArgument("response_tolerance must be a finite number >= 0");
  if (max_response_rays < 1) return InvalidArgument("max_response_rays must be >= 1");
  if (!(floor_width_tolerance >= 0))  // infinity: BIC alone decides
    return InvalidArgument("floor_width_tolerance must be >= 0");
  if (!automatic_starts && !initial_width)
    return InvalidArgument("automatic_starts = false needs an initial_width");
  return OkStatus();
}

double Predict(const FitSummary& fit, const Sample& sample) {
  const double w = fit.width.value, k = fit.scale.value, eta = fit.eta.value;
  double value = MeasurementModel(fit.model, sample.light, sample.view, w, k, eta);
  if (sample.response && sample.response->setup) {
    Sample s = sample;  // at the geometry the fit found
    ResponseSetup moved = *s.response->setup;
    MoveToFitted(fit.geometry, moved);
    s.response->setup = std::make_shared<const ResponseSetup>(std::move(moved));
    value = ModelAt(fit, s, s.response->at);
    // The sample stage's offset of the first group read back at this angle (a sample alone does
    // not say which visit to the angle it was taken in), through the slope at the fitted
    // geometry.
    for (const StageOffset& g : fit.geometry.sample_stage)
      if (g.sample_deg == sample.response->at.sample_deg) {
        if (g.offset_deg != 0)
          value += StageSlope(fit, s, &StagePosition::sample_deg) * g.offset_deg;
        break;
      }
  }
  return value + fit.floor.value;
}

std::vector<IncidenceGroup> GroupByIncidence(std::span<const Sample> samples) {
  std::vector<IncidenceGroup> groups;
  std::vector<Vec3<double>> keys;
  for (const Sample& s : samples) {
    std::size_t g = 0;
    while (g < keys.size() && optics::LengthSquared(keys[g] - s.light) > 1e-12) ++g;
    if (g == keys.size()) {
      keys.push_back(s.light);
      groups.push_back({ThetaLightDeg(s), {}});
    }
    groups[g].samples.push_back(s);
  }
  return groups;
}

std::optional<double> EstimateAlphaFromHalfWidth(std::span<const Sample> samples, double eta) {
  // The incidence group holding the largest value; its peak view direction; the nearest view
  // direction where the signal has fallen below half the peak.
  const auto groups = GroupByIncidence(samples);
  const IncidenceGroup* best = nullptr;
  const Sample* peak = nullptr;
  for (const auto& g : groups)
    for (const Sample& s : g.samples)
      if (!peak || s.value > peak->value) peak = &s, best = &g;
  if (!peak || !(peak->value > 0)) return std::nullopt;
  double half_angle = std::numeric_limits<double>::infinity();
  for (const Sample& s : best->samples)
    if (s.value < 0.5 * peak->value)
      half_angle = std::min(half_angle, std::acos(std::clamp(Dot(s.view, peak->view), -1.0, 1.0)));
  if (!std::isfinite(half_angle) || half_angle <= 0) return std::nullopt;
  // Near normal incidence a facet tilted by theta_h deflects the refracted ray by about
  // theta_h (1 - 1/eta), and the reflected one by 2 theta_h; Beckmann's D falls to half at
  // tan(theta_h) = alpha sqrt(ln 2).
  const double deflection = IsReflection(*peak) ? 2 : 1 - 1 / eta;
  const double theta_h = std::min(half_angle / deflection, 80 * kDeg);
  return std::tan(theta_h) / std::sqrt(std::log(2.0));
}

namespace {

// Starting points for the local fits: the caller's, the half-width estimate, then the local
// minima of a scan of the width on a log grid of alpha-equivalent (k at its optimum for each
// width), best first.
std::vector<ScanPoint> Starts(std::span<const Sample> samples,
                              std::span<const FixedGeometry> geometry, const FitOptions& o) {
  // 1. Scan the width on a log grid of alpha-equivalent (k at its optimum for each width).
  std::vector<ScanPoint> scan;
  for (int k = 0; o.automatic_starts && k < o.scan_points; ++k) {
    const double a = 0.003 * std::pow(2.0 / 0.003, double(k) / (o.scan_points - 1));
    if (auto w = WidthFromAlphaEquivalent(o.model.family, a))
      scan.push_back(EvaluateWidth(samples, geometry, o.model, *w));
  }
  std::vector<ScanPoint> starts;
  auto add_start = [&](double width) {
    if (!(width > 0) || !std::isfinite(width)) return;
    for (const auto& s : starts)
      if (std::abs(std::log(s.width / width)) < 0.05) return;
    ScanPoint p = EvaluateWidth(samples, geometry, o.model, width);
    if (std::isfinite(p.cost)) starts.push_back(p);
  };
  if (o.initial_width) add_start(*o.initial_width);
  if (o.automatic_starts)
    if (auto a = EstimateAlphaFromHalfWidth(samples, o.eta))
      if (auto w = WidthFromAlphaEquivalent(o.model.family, *a)) add_start(*w);
  std::vector<ScanPoint> minima;
  for (std::size_t k = 0; k < scan.size(); ++k) {
    const bool left = k == 0 || scan[k].cost <= scan[k - 1].cost;
    const bool right = k + 1 == scan.size() || scan[k].cost <= scan[k + 1].cost;
    if (left && right && std::isfinite(scan[k].cost)) minima.push_back(scan[k]);
  }
  std::sort(minima.begin(), minima.end(),
            [](const ScanPoint& a, const ScanPoint& b) { return a.cost < b.cost; });
  for (const auto& m : minima) add_start(m.width);
  return starts;
}

// The model's value of every sample at a solution (`delta`: the sample stage's offsets).
std::vector<double> Predictions(const Problem& p, const FitOptions& o, const FitSummary& out,
                                std::span<const double> delta, std::span<const double> dark_z) {
  std::vector<double> predicted(p.samples.size());
  for (std::size_t i = 0; i < p.samples.size(); ++i) {
    const SampleModel& sm = p.models[i];
    double m = 0;
    if (o.fit_eta) {
      for (std::size_t j = 0; j < sm.g.size(); ++j)
        m += sm.w[j] * MeasurementModel(o.model, sm.g[j].l, sm.g[j].v, out.width.value,
                                        out.scale.value, out.eta.value);
      m *= CorrectionAt(sm, out.width.value);
    } else
      m = out.scale.value * FixedEtaValue(o.model, sm, out.width.value);
    predicted[i] =
        m + out.floor.value + p.SlopeOf(i) * delta[p.DeltaOf(i)] + p.DarkOf(i) * dark_z[p.SetOf(i)];
  }
  return predicted;
}

// chi2/dof and the information criteria from chi2, the model's parameters and the nuisance ones
// the data fixed.
void SetInformation(FitSummary& out) {
  const double p = out.n_params + out.n_nuisance;
  out.reduced_chi2 = out.chi2 / (out.n_points - p);
  out.aic = out.chi2 + 2.0 * p;
  out.bic = out.chi2 + p * std::log(double(out.n_points));
}

// Residuals, chi2 (with the sample stage's priors) and the information criteria at the solution.
void FillStatistics(const Problem& p, const FitOptions& o, const LocalFit& f, FitSummary& out) {
  std::vector<double> predicted = Predictions(p, o, out, f.delta, f.dark_z);
  out.residuals.clear();
  out.residuals.reserve(p.samples.size());
  out.chi2 = 0;
  for (std::size_t i = 0; i < p.samples.size(); ++i) {
    const double r = (predicted[i] - p.samples[i].value) / p.samples[i].sigma;
    out.residuals.push_back(r);
    out.chi2 += r * r;
  }
  for (int g = 0; g < p.Groups(); ++g) out.chi2 += std::pow(f.delta[g] / p.stage->prior_deg, 2);
  for (int d = 0; d < p.Sets(); ++d) out.chi2 += f.dark_z[d] * f.dark_z[d];
  SetInformation(out);
  // The lobe is judged on the surface's model, without the floor, the stage's offsets or the
  // dark sets'.
  for (std::size_t i = 0; i < p.samples.size(); ++i)
    predicted[i] -=
        out.floor.value + p.SlopeOf(i) * f.delta[p.DeltaOf(i)] + p.DarkOf(i) * f.dark_z[p.SetOf(i)];
  out.points_in_lobe = PointsInLobe(p.samples, predicted);
}

// The parameters' sigmas from the covariance of (log width, log k[, eta raw][, floor]) by the
// delta method. False when the covariance is singular or not positive.
bool FillUncertainties(LocalFit& winner, const Problem& p, const FitOptions& o, FitSummary& out) {
  std::vector<double*> blocks = {winner.x + 0, winner.x + 1};
  if (o.fit_eta) blocks.push_back(winner.x + 2);
  if (p.fit_floor) blocks.push_back(winner.x + 3);
  // The stage's offsets last: the parameters' covariance is then the marginal one, over them.
  const int first_delta = static_cast<int>(blocks.size());
  for (int g = 0; g < p.Groups(); ++g) blocks.push_back(&winner.delta[g]);
  for (int d = 0; d < p.Sets(); ++d) blocks.push_back(&winner.dark_z[d]);  // marginal over them too
  Eigen::MatrixXd c;
  ceres::CRSMatrix j;
  bool cov_ok = Covariance(*winner.problem, blocks, &c, &j);
  // Inflate when the residuals scatter more than the sigmas say. With a robust loss the outliers
  // it down-weights would dominate chi2, so the scatter is measured robustly (1.4826 MAD).
  double scatter2 = out.reduced_chi2;
  if (o.loss != Loss::kNone) {
    std::vector<double> a;
    for (double r : out.residuals) a.push_back(std::abs(r));
    std::nth_element(a.begin(), a.begin() + a.size() / 2, a.end());
    scatter2 = std::pow(1.4826 * a[a.size() / 2], 2);
  }
  const double inflate = o.inflate_by_reduced_chi2 ? std::max(1.0, scatter2) : 1.0;
  const double var_lw = cov_ok ? c(0, 0) * inflate : 0, var_lk = cov_ok ? c(1, 1) * inflate : 0;
  cov_ok = cov_ok && var_lw > 0 && var_lk > 0;
  if (cov_ok) {
    out.width.sigma = out.width.value * std::sqrt(var_lw);
    out.scale.sigma = out.scale.value * std::sqrt(var_lk);
    if (o.fit_eta) {
      const double var = c(2, 2) * inflate;
      const double u = (out.eta.value - kEtaMin) / kEtaSpan;
      out.eta.sigma = kEtaSpan * u * (1 - u) * std::sqrt(std::max(var, 0.0));
    }
    if (p.fit_floor) {
      const int i = o.fit_eta ? 3 : 2;
      out.floor.sigma = p.floor_unit * std::sqrt(std::max(c(i, i) * inflate, 0.0));
    }
    out.geometry.sample_stage.clear();
    for (int g = 0; g < p.Groups(); ++g) {
      StageOffset so = p.stage->groups[g];
      so.offset_deg = winner.delta[g];
      so.sigma_deg = std::sqrt(std::max(c(first_delta + g, first_delta + g) * inflate, 0.0));
      out.geometry.sample_stage.push_back(so);
    }
    // The statistical part: the sandwich C J^T D J C, with D_i = (sigma_stat_i / sigma_i)^2 the
    // share of each sample's variance that is statistical (LocalFit::row_sample: a row's sample;
    // a stage offset's prior is none of it, a dark set's all of it: the dark frames' noise).
    bool have_stat = j.num_rows == static_cast<int>(winner.row_sample.size());
    for (const Sample& s : p.samples) have_stat = have_stat && s.sigma_stat > 0;
    if (have_stat) {
      const int n = j.num_cols;
      Eigen::MatrixXd m = Eigen::MatrixXd::Zero(n, n);
      for (int r = 0; r < j.num_rows; ++r) {
        const int i = winner.row_sample[r];
        if (i == -1) continue;
        const double d =
            i < 0 ? 1.0 : std::pow(std::min(1.0, p.samples[i].sigma_stat / p.samples[i].sigma), 2);
        for (int a = j.rows[r]; a < j.rows[r + 1]; ++a)
          for (int b = j.rows[r]; b < j.rows[r + 1]; ++b)
            m(j.cols[a], j.cols[b]) += d * j.values[a] * j.values[b];
      }
      const Eigen::MatrixXd cs = c * m * c;
      out.width.sigma_stat = out.width.value * std::sqrt(std::max(cs(0, 0), 0.0));
      out.scale.sigma_stat = out.scale.value * std::sqrt(std::max(cs(1, 1), 0.0));
      if (p.fit_floor) {
        const int i = o.fit_eta ? 3 : 2;
        out.floor.sigma_stat = p.floor_unit * std::sqrt(std::max(cs(i, i), 0.0));
      }
    }
  }
  return cov_ok;
}

// Why the data do not constrain the width, or "" where they do: a singular covariance, fewer than
// 3 samples inside the fitted lobe's half maximum, or a relative sigma above 50 %.
std::string ConstraintProblem(bool cov_ok, const FitSummary& out) {
  std::ostringstream why;
  if (!cov_ok)
    why << "the covariance is singular: the data do not constrain every parameter";
  else if (out.points_in_lobe < 3)
    why << "only " << out.points_in_lobe
        << " sample(s) lie inside the fitted lobe's half maximum: sample the peak more finely "
           "to determine the width";
  else if (out.width.sigma > 0.5 * out.width.value)
    why << "the width's relative uncertainty is " << 100 * out.width.sigma / out.width.value
        << " %: the data barely constrain it";
  return why.str();
}

// A fit judged on what the data constrain and on its chi2. A chi2 whose p-value is below 1e-6
// makes it a poor fit whatever else holds: the family does not describe the data, which is the
// first thing to say of it (a width's sigma inflated by a chi2/dof of 1e6 looks unconstrained
// only because of it). With honest sigmas a correct model gives p ~ U(0, 1). The degrees of
// freedom count the nuisance parameters the data fixed (FitSummary::n_nuisance). Judged again
// when those change. For a converged solve only.
void JudgeFit(bool cov_ok, FitSummary& out) {
  const std::string constraint = ConstraintProblem(cov_ok, out);
  out.message = constraint;
  out.status = constraint.empty() ? FitStatus::kConverged : FitStatus::kUnconstrained;
  const double dof = out.n_points - out.n_params - out.n_nuisance;
  const double p_value = boost::math::gamma_q(0.5 * dof, 0.5 * out.chi2);
  if (p_value < 1e-6) {
    std::ostringstream poor;
    poor << std::setprecision(3) << "the model does not describe the data (chi2/dof "
         << out.reduced_chi2 << " over " << dof << " degrees of freedom, p = " << p_value
         << "): the width is not a measurement of the surface";
    out.message = poor.str();
    out.status = FitStatus::kPoorFit;
  }
}

// Whether the data constrain the width of a judged fit (its covariance was regular if it has a
// sigma).
bool WidthConstrained(const FitSummary& f) {
  return f.status != FitStatus::kFailed && ConstraintProblem(f.width.sigma > 0, f).empty();
}

}  // namespace

namespace {

// Each sample's mode at (width, k, eta); an error names the sample whose response is broken.
Result<std::vector<int>> DecideModes(std::span<const Sample> samples, const FitOptions& o,
                                     ResponseCache& cache, double width, double k, double eta) {
  std::vector<int> modes(samples.size(), 0);
  if (!o.use_response) return modes;
  for (std::size_t i = 0; i < samples.size(); ++i) {
    auto m = DecideMode(o.model, samples[i], i, cache, width, k, eta, o.response_tolerance,
                        o.max_response_rays);
    if (!m.ok()) return m.error();
    modes[i] = *m;
  }
  return modes;
}

// A held sample's next level is traced (TraceHeld) only up to this many times the budget: past
// it, tracing would cost far more than the fit (a 6 x 16 cone pair over 1 178 pixels is 11 M).
constexpr long kTraceRaysPerBudget = 64;

// Where the budget held a model, its corrected value's own error: the change from each streamed
// level to the next finer one, both streamed once at (width, k, eta). The correction made the
// model the streamed level's value, whose error that next change measures; the change from the
// held level, which sigma took during the rounds, is the error of a model left uncorrected (on
// antiglare under 3 x 10 mm up to 38 sigma, where the next change is at most 0.5). A step
// streamed at its finest level has no error left: an unbudgeted fit stops there too. A step whose
// next level is past kTraceRaysPerBudget times the budget keeps its change. Sets each held
// sample's quadrature; returns how many samples had every held step traced.
Result<int> TraceHeld(std::span<const Sample> samples, const FitOptions& o, ResponseCache& cache,
                      double width, double k, double eta) {
  const long limit = o.max_response_rays > std::numeric_limits<long>::max() / kTraceRaysPerBudget
                         ? std::numeric_limits<long>::max()
                         : kTraceRaysPerBudget * o.max_response_rays;
  int traced = 0;
  for (std::size_t i = 0; i < samples.size(); ++i) {
    ResponseCache::PerSample& c = cache.of[i];
    if (!c.IsHeld()) continue;
    const Sample& s = samples[i];
    bool whole = true;
    // The last decision's streamed value where it was taken at this width (the rounds settled
    // there), else streamed again.
    const bool here = std::log(width) == c.log_width;
    // The error of a step streamed at `at` (`value` there at k = 1 when `here`): its change to
    // `finer`, or `change` where untraced.
    auto error = [&](const std::optional<ResponseLevel>& at, double value,
                     const std::optional<ResponseLevel>& finer, double change) -> Result<double> {
      if (!finer) return 0.0;
      if (MaxRaysAtLevel(*s.response->setup, *finer) > limit) {
        whole = false;
        return change;
      }
      if (!here) {
        auto a = StreamedValue(o.model, s, i, *at, width, eta);
        if (!a.ok()) return a.error();
        value = *a;
      }
      auto b = StreamedValue(o.model, s, i, *finer, width, eta);
      if (!b.ok()) return b.error();
      return k * std::abs(*b - value);
    };
    double rect = 0, ap = 0;
    if (const Held& h = c.rectangle_held; h.streamed >= 0) {
      auto e = error(RectangleLevel(h.streamed), h.streamed_value, RectangleLevel(h.streamed + 1),
                     h.change);
      if (!e.ok()) return e.error();
      rect = *e;
    }
    if (const Held& h = c.apertures_held; h.streamed >= 0) {
      auto e = error(ApertureLevel(h.streamed, c.apertures_on), h.streamed_value,
                     ApertureLevel(h.streamed + 1, c.apertures_on), h.change);
      if (!e.ok()) return e.error();
      ap = *e;
    }
    c.quadrature = std::hypot(rect, ap);
    traced += whole;
  }
  return traced;
}

// What each sample's model was built from: its mode and its responses' levels. The decision has
// settled when a new one changes none of them (a level refined at the same mode counts: the
// model built at the start's width would otherwise stay on the coarser rays).
std::vector<std::array<int, 3>> Decided(const std::vector<int>& modes, const ResponseCache& cache) {
  std::vector<std::array<int, 3>> out;
  out.reserve(modes.size());
  for (std::size_t i = 0; i < modes.size(); ++i)
    out.push_back({modes[i], cache.of[i].rectangle_level, cache.of[i].aperture_level});
  return out;
}

// `samples` with each capped sample's quadrature error (ResponseCache) added to its sigma, into
// `out` (sized once, so that a Problem's span over it stays valid); its count and largest share.
std::pair<int, double> WithQuadrature(std::span<const Sample> samples, const ResponseCache& cache,
                                      std::vector<Sample>& out) {
  if (out.size() != samples.size()) out.assign(samples.begin(), samples.end());
  int capped = 0;
  double largest = 0;
  for (std::size_t i = 0; i < samples.size(); ++i) {
    const double q = cache.of[i].quadrature;
    out[i].sigma = std::hypot(samples[i].sigma, q);
    if (!cache.of[i].IsHeld()) continue;
    ++capped;
    largest = std::max(largest, q / samples[i].sigma);
  }
  return {capped, largest};
}

void Tell(const FitOptions& o, const std::string& what) {
  if (o.progress) o.progress(what);
}

std::string Rays(long n) {
  std::ostringstream s;
  if (n >= 1000000)
    s << std::setprecision(3) << n / 1e6 << " M";
  else
    s << n;
  return s.str() + " rays";
}

// What a set of decisions models: "R samples over their rectangle, A with the apertures, C held
// to the ray budget; N rays".
std::string DescribeModels(const std::vector<int>& modes, std::span<const SampleModel> models,
                           int capped) {
  int rect = 0, ap = 0;
  long rays = 0;
  for (std::size_t i = 0; i < modes.size(); ++i) {
    rect += modes[i] >= 1;
    ap += modes[i] == 2;
    rays += static_cast<long>(models[i].g.size());
  }
  std::ostringstream s;
  s << rect << " of " << modes.size() << " samples over their rectangle, " << ap
    << " with the apertures";
  if (capped > 0) s << ", " << capped << " held to the ray budget";
  s << "; " << Rays(rays) << " a pass";
  return s.str();
}

double Median(std::vector<double> v) {
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

// One fit with the floor on or off (o.floor is kOff or kFit).
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
  Tell(o, std::string("a solve of ") + std::to_string(samples.size()) + " samples, floor " +
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
  auto decided = Decided(*modes, cache);
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
  Tell(o, DescribeModels(*modes, p.models, capped.first));

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
      Tell(o, t.str());
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
    auto now = Decided(*next, cache);
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
    Tell(o,
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
    Tell(o, "tracing the next level of the " + std::to_string(capped.first) +
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
    Tell(o, t.str());
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
    Tell(o, t.str());
  }
  return out;
}

}  // namespace

namespace {

// Fit's work once the input is valid: with Floor::kAuto, the fits without and with a floor and
// BIC's choice between them.
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

// The samples with every response's setup changed by `change` (one copy per distinct setup).
template <typename Change>
std::vector<Sample> WithSetupChanged(std::span<const Sample> samples, Change change) {
  std::map<const ResponseSetup*, std::shared_ptr<const ResponseSetup>> moved;
  std::vector<Sample> out(samples.begin(), samples.end());
  for (Sample& s : out) {
    if (!s.response || !s.response->setup) continue;
    auto& m = moved[s.response->setup.get()];
    if (!m) {
      ResponseSetup c = *s.response->setup;
      change(c);
      m = std::make_shared<const ResponseSetup>(std::move(c));
    }
    s.response->setup = m;
  }
  return out;
}

// A local refit from `fit`'s solution, its floor choice kept (nullopt when it does not converge).
std::optional<FitSummary> Refit(std::span<const Sample> samples, SolveOptions o,
                                const FitSummary& fit) {
  o.floor = fit.floor_fitted ? Floor::kFit : Floor::kOff;
  o.initial_width = fit.width.value;
  o.automatic_starts = false;
  auto f = FitOnce(samples, o);
  if (!f.ok() || f->status == FitStatus::kFailed) return std::nullopt;
  return std::move(f).value();
}

// A least-squares refit of the moved samples from `fit`'s solution. Against one of the unmoved
// (from the same solution) it gives the estimator's derivative along the move: at the solution a
// robust loss weighs like least squares, and a robust refit of a setup moved by a whole pixel
// leaves residuals of many sigma, where Huber's reweighting converges linearly (hundreds of
// iterations in CI's demo) and measures the loss's response to outliers, not the derivative.
std::optional<FitSummary> MovedRefit(std::span<const Sample> moved, const SolveOptions& o,
                                     const FitSummary& fit) {
  SolveOptions ls = o;
  ls.loss = Loss::kNone;
  return Refit(moved, ls, fit);
}

// One run-wide setup quantity profiled (NuisanceUse in fitter.h): how a setup moves by d of it
// (nullopt from MovedBy where the setup refuses that, e.g. a plate of no thickness) and its
// stated sigma, in its unit.
struct Quantity {
  std::function<void(ResponseSetup&, double)> change;
  double prior = 0;
};

// The samples with every quantity k moved by d[k], or nullopt where a setup refuses the change.
std::optional<std::vector<Sample>> MovedBy(std::span<const Sample> used,
                                           const std::vector<Quantity>& q,
                                           const Eigen::VectorXd& d) {
  auto m = WithSetupChanged(used, [&q, &d](ResponseSetup& c) {
    for (std::size_t k = 0; k < q.size(); ++k)
      if (d[k] != 0) q[k].change(c, d[k]);
  });
  for (const Sample& s : m)
    if (s.response && s.response->setup && !s.response->setup->Validate().ok()) return std::nullopt;
  return m;
}

// What a joint profile gives: each quantity's use, why a quantity's data were not used, and the
// joint estimates (the posterior's most probable offsets with every quantity's data in, before
// any was dropped for lying beyond the probes; NaN for a quantity whose data did not enter).
struct JointUse {
  std::vector<NuisanceUse> use;
  std::vector<bool> left_out;  // no refit with it moved converged: its part is not in sigma
  std::vector<std::string> why_not;
  std::vector<bool> beyond;  // the data put it beyond the probes (its prior alone then)
  std::vector<bool> flat;    // chi-square not convex along it at these probes
  Eigen::VectorXd estimate;
};

// The quantities profiled together, about `at` with probes at +-`step` (both vectors in their
// units): least-squares refits from `fit`'s solution at `at`, at each one moved a step either
// way, and at each pair moved a step up together. With u = (offset - at) / step they give
// chi2(u) = C + b.u + u.Q.u and w(u) = w0 + w1.u + u.W.u (Q, W symmetric: the diagonal from the
// single probes, the cross terms from the pairs); the priors add sum_k ((at_k + u_k step_k) /
// prior_k)^2, so the offsets' posterior is N(at + step mu, step S step) with S^-1 = Q + diag(
// (step / prior)^2) and mu = -S (b + 2 at step / prior^2) / 2 (chi-square as -2 ln L, scaled by
// the reduced chi-square at its minimum where that exceeds 1, as the parameters' sigmas are). The
// width moves to w(mu), with variance g.S.g + 2 tr((W S)^2), g = w1 + 2 W mu (a Gaussian
// through a quadratic). Profiled one at a time, quantities that move the lobe alike (the
// thickness and the rectangle's x both shift a sweep) each took the whole shift, and the fit
// moved to both: on antiglare the thickness went 5 sigma and x 3 sigma off to absorb one
// sample-stage error, and the stage's offsets came out of the wrong sign. The data's quadratic
// is only trusted inside the probed range: a quantity whose mu lies beyond 1.5 steps, or along
// which chi-square is not convex, keeps its prior alone (its data terms dropped, which leaves it
// independent of the others; the note says why), as does a quantity probed one way only, which
// is then linear in it. nullopt when the refit at `at` does not converge.
std::optional<JointUse> JointProfileAt(std::span<const Sample> used, const std::vector<Quantity>& q,
                                       const SolveOptions& o, const FitSummary& fit,
                                       const FitSummary& base, const Eigen::VectorXd& at,
                                       const Eigen::VectorXd& step, bool cross,
                                       const std::vector<bool>& excluded) {
  const int n = static_cast<int>(q.size());
  auto refit = [&](const Eigen::VectorXd& d) -> std::optional<FitSummary> {
    auto m = MovedBy(used, q, d);
    if (!m) return std::nullopt;
    std::ostringstream t;
    t << "the geometry's profile: a refit with its setup moved by (" << d.transpose() << ")";
    Tell(o, t.str());
    return MovedRefit(*m, o, fit);
  };
  std::optional<FitSummary> centre = at.isZero() ? std::optional<FitSummary>(base) : refit(at);
  if (!centre) return std::nullopt;
  std::vector<std::optional<FitSummary>> up(n), down(n);
  for (int k = 0; k < n; ++k) {
    Eigen::VectorXd e = Eigen::VectorXd::Zero(n);
    e[k] = step[k];
    up[k] = refit(at + e);
    down[k] = refit(at - e);
  }
  JointUse out;
  out.use.assign(n, NuisanceUse{});
  out.why_not.assign(n, "");
  out.left_out.assign(n, false);
  out.beyond.assign(n, false);
  out.flat.assign(n, false);
  out.estimate = Eigen::VectorXd::Constant(n, std::numeric_limits<double>::quiet_NaN());
  Eigen::VectorXd b = Eigen::VectorXd::Zero(n), w1 = Eigen::VectorXd::Zero(n);
  Eigen::MatrixXd Q = Eigen::MatrixXd::Zero(n, n), W = Eigen::MatrixXd::Zero(n, n);
  std::vector<bool> data(n, false);  // the quantity's data terms enter
  for (int k = 0; k < n; ++k) {
    if (up[k] && down[k]) {
      out.use[k].probed = true;
      b[k] = (up[k]->chi2 - down[k]->chi2) / 2;
      Q(k, k) = (up[k]->chi2 + down[k]->chi2) / 2 - centre->chi2;
      w1[k] = (up[k]->width.value - down[k]->width.value) / 2;
      W(k, k) = (up[k]->width.value + down[k]->width.value) / 2 - centre->width.value;
      data[k] = Q(k, k) > 0 && !excluded[k];
      out.flat[k] = !(Q(k, k) > 0);
      if (out.flat[k]) out.why_not[k] = "chi-square not convex along it";
    } else if (up[k] || down[k]) {  // one way only: linear in it
      const std::optional<FitSummary>& one = up[k] ? up[k] : down[k];
      w1[k] = (one->width.value - centre->width.value) * (up[k] ? 1 : -1);
    } else {
      out.left_out[k] = true;
    }
  }
  for (int i = 0; i < n; ++i)
    for (int j = i + 1; j < n; ++j) {
      if (!cross || !data[i] || !data[j]) continue;
      Eigen::VectorXd e = Eigen::VectorXd::Zero(n);
      e[i] = step[i];
      e[j] = step[j];
      auto both = refit(at + e);
      if (!both) {  // no cross term: the pair is taken as independent
        continue;
      }
      Q(i, j) = Q(j, i) = (both->chi2 - centre->chi2 - b[i] - b[j] - Q(i, i) - Q(j, j)) / 2;
      W(i, j) = W(j, i) =
          (both->width.value - centre->width.value - w1[i] - w1[j] - W(i, i) - W(j, j)) / 2;
    }
  Eigen::VectorXd prior_u(n), at_u(n);  // the priors' sigma in steps, and `at` in steps
  for (int k = 0; k < n; ++k) {
    prior_u[k] = q[k].prior / step[k];
    at_u[k] = at[k] / step[k];
  }
  // Solve with the quantities whose data enter; drop one whose data put it beyond the probes (or
  // make the quadratic indefinite) and solve again.
  Eigen::VectorXd mu(n);
  Eigen::MatrixXd S(n, n);
  bool first_solve = true;
  for (;;) {
    Eigen::MatrixXd Qd = Q;
    Eigen::VectorXd bd = b;
    int m = 0;
    for (int k = 0; k < n; ++k) {
      if (data[k]) {
        ++m;
        continue;
      }
      Qd.row(k).setZero();
      Qd.col(k).setZero();
      bd[k] = 0;
    }
    // Chi-square's scale: the reduced chi-square at the data's minimum, with the quantities
    // counted as parameters (not the unmoved refit's: a quantity far from its stated value
    // inflates that by the very misfit it explains, which flattened the quadratic).
    double chi2_min = base.chi2;
    Eigen::LDLT<Eigen::MatrixXd> data_only(Qd);
    if (m > 0 && data_only.info() == Eigen::Success && data_only.isPositive()) {
      Eigen::MatrixXd Qm = Qd;
      for (int k = 0; k < n; ++k)
        if (!data[k]) Qm(k, k) = 1;  // a placeholder that leaves the others' minimum alone
      Eigen::LLT<Eigen::MatrixXd> llt(Qm);
      if (llt.info() == Eigen::Success) chi2_min = centre->chi2 - bd.dot(llt.solve(bd)) / 4;
    }
    const double dof = base.n_points - base.n_params - m;
    const double inflate = dof > 0 ? std::max(1.0, chi2_min / dof) : 1.0;
    Eigen::MatrixXd M = Qd / inflate;
    Eigen::VectorXd g = bd / inflate;
    for (int k = 0; k < n; ++k) {
      M(k, k) += 1 / (prior_u[k] * prior_u[k]);
      g[k] += 2 * at_u[k] / (prior_u[k] * prior_u[k]);
    }
    Eigen::LLT<Eigen::MatrixXd> llt(M);
    int drop = -1;
    if (llt.info() != Eigen::Success) {  // not a minimum: the largest data term goes
      for (int k = 0; k < n; ++k)
        if (data[k] && (drop < 0 || Q(k, k) > Q(drop, drop))) drop = k;
      out.why_not[drop] = "chi-square not convex along it";
    } else {
      S = llt.solve(Eigen::MatrixXd::Identity(n, n));
      mu = -S * g / 2;
      if (first_solve)  // the joint estimates, before any quantity's data are dropped
        for (int k = 0; k < n; ++k)
          if (data[k]) out.estimate[k] = at[k] + mu[k] * step[k];
      first_solve = false;
      for (int k = 0; k < n; ++k)
        if (data[k] && std::abs(mu[k]) > 1.5 && (drop < 0 || std::abs(mu[k]) > std::abs(mu[drop])))
          drop = k;
      if (drop >= 0) {
        std::ostringstream w;
        w << std::setprecision(2) << "the data put it " << at[drop] + mu[drop] * step[drop]
          << " off, beyond the probes: check the stated value";
        out.why_not[drop] = w.str();
        out.beyond[drop] = true;
      }
    }
    if (drop < 0) break;
    data[drop] = false;
  }
  // The width: its shift at mu, and its variance, split among the quantities by their shares
  // g_k (S g)_k + 2 ((W S)^2)_kk of the whole (negative shares, from anticorrelated quantities,
  // count 0; the split is rescaled to the whole).
  const Eigen::VectorXd g = w1 + 2 * W * mu;
  const Eigen::MatrixXd WS = W * S, WS2 = WS * WS;
  const double total = std::max(0.0, g.dot(S * g) + 2 * WS2.trace());
  const double shift = centre->width.value - base.width.value + w1.dot(mu) + mu.dot(W * mu);
  const Eigen::VectorXd Sg = S * g;
  Eigen::VectorXd share(n), part(n);
  for (int k = 0; k < n; ++k) {
    share[k] = std::max(0.0, g[k] * Sg[k] + 2 * WS2(k, k));
    part[k] = std::abs(w1[k] * mu[k] + W(k, k) * mu[k] * mu[k]);
  }
  const double share_sum = share.sum(), part_sum = part.sum();
  for (int k = 0; k < n; ++k) {
    NuisanceUse& u = out.use[k];
    u.fitted = data[k];
    u.offset = at[k] + mu[k] * step[k];
    u.offset_sigma = std::sqrt(S(k, k)) * step[k];
    u.width_sigma = share_sum > 0 ? std::sqrt(total * share[k] / share_sum) : 0.0;
    u.width_shift = part_sum > 0 ? shift * part[k] / part_sum : shift / n;
  }
  return out;
}

// Profiles about the stated values with probes at their sigmas, each quantity alone (no cross
// terms), then again, with the cross terms, about the offsets found, with probes at twice their
// sigmas where the data know a quantity to better than a quarter of the first step: the slope of
// chi-square through probes far outside the posterior carries their cubic terms (on the demo's
// joint fit one-pixel probes put the rectangle 0.007 px from where probes at 0.01 px do, more than
// its sigma of 0.005 px; on antiglare, 0.045 px against 0.0035), while its curvature does not
// change from 1 to 0.01 px; cross terms from a pair of such probes were worse still. The first
// profile only scouts where more than one quantity is stated: alone, each takes what the others
// explain (on antiglare x landed nine of the second probes' steps from the joint estimate, and a
// thickness 0.4 mm off looked 1.5 mm off beside a rectangle 0.5 px off). Where the second probes
// put an offset beyond themselves, they are taken again about the joint estimates (Newton's
// iteration on the data's quadratic), up to four times; a quantity whose estimate lies beyond 1.5
// of its prior's sigma keeps its prior (the note says to check the stated value). Should they not
// settle, the last profile stands, the quantities beyond its probes at their priors.
std::optional<JointUse> JointProfile(std::span<const Sample> used, const std::vector<Quantity>& q,
                                     const SolveOptions& o, const FitSummary& fit,
                                     const FitSummary& base) {
  const int n = static_cast<int>(q.size());
  Eigen::VectorXd prior(n);
  for (int k = 0; k < n; ++k) prior[k] = q[k].prior;
  std::vector<bool> excluded(n, false);
  auto first =
      JointProfileAt(used, q, o, fit, base, Eigen::VectorXd::Zero(n), prior, false, excluded);
  if (!first) return first;
  Eigen::VectorXd centre(n), step(n);
  bool finer = false;
  int with_data = 0;  // fitted, or beyond the first probes
  for (int k = 0; k < n; ++k) {
    const NuisanceUse& u = first->use[k];
    const bool sharp = u.fitted && u.offset_sigma < prior[k] / 4;
    finer = finer || sharp;
    with_data += u.fitted || first->beyond[k];
    centre[k] = u.fitted ? u.offset : 0;
    step[k] = sharp ? 2 * u.offset_sigma : prior[k];
  }
  if (with_data < 2) {  // one quantity: its own profile, refined where sharp
    for (int k = 0; k < n; ++k) excluded[k] = !first->use[k].fitted;
    if (!finer) return first;
  }
  std::optional<JointUse> last;
  std::vector<std::string> named(n);  // why an excluded quantity keeps its prior
  auto done = [&named, &excluded](JointUse& u) {
    for (std::size_t k = 0; k < named.size(); ++k)
      if (excluded[k] && !named[k].empty()) u.why_not[k] = named[k];
    return std::optional<JointUse>(std::move(u));
  };
  for (int round = 0; round < 5; ++round) {
    auto again = JointProfileAt(used, q, o, fit, base, centre, step, true, excluded);
    if (!again) break;
    bool moved = false;
    for (int k = 0; k < n; ++k) {
      if (!again->beyond[k]) continue;
      if (std::abs(again->estimate[k]) > 1.5 * prior[k]) {
        excluded[k] = true;  // far from the stated value: named, not followed, held there
        named[k] = again->why_not[k];
        centre[k] = 0;
      } else {
        moved = true;
      }
    }
    // A quantity the predictions depend on through its square (the rectangle across the plane of
    // incidence: chi-square quartic about 0) is convex at the first probes and flat at finer
    // ones: it goes back to the first probes' step.
    for (int k = 0; k < n; ++k)
      if (again->flat[k] && first->use[k].fitted && step[k] < prior[k]) {
        step[k] = prior[k];
        centre[k] = first->use[k].offset;
        moved = true;
      }
    bool newly_excluded = false;
    for (int k = 0; k < n; ++k)
      newly_excluded = newly_excluded || (again->beyond[k] && excluded[k]);
    last = std::move(again);
    if (!moved && !newly_excluded) return done(*last);
    if (!moved) continue;  // again without the far ones
    for (int k = 0; k < n; ++k)
      if (!excluded[k] && std::isfinite(last->estimate[k])) centre[k] = last->estimate[k];
  }
  return last ? done(*last) : first;
}

// "x +0.12 +- 0.31 px (from the data; prior 1)"
std::string DescribeNuisance(const NuisanceUse& n, const char* unit, double prior,
                             const std::string& why_not) {
  std::ostringstream d;
  d << std::setprecision(2);
  if (n.fitted)
    d << std::showpos << n.offset << std::noshowpos << " +- " << n.offset_sigma << " " << unit
      << " from the data (stated +-" << prior << "): width " << std::showpos << n.width_shift
      << std::noshowpos << " +- " << n.width_sigma;
  else
    d << "+-" << prior << " " << unit << " as stated"
      << (why_not.empty() ? std::string() : " (" + why_not + ")") << ": width +-" << n.width_sigma;
  return d.str();
}

// The nuisance parameters the data fixed, each counted as 1 - s^2 / sigma_prior^2 of a parameter
// (the share of its prior the data replaced; 0 where the prior stands), in the degrees of freedom
// of chi2/dof, the poor-fit test and the information criteria. Without it a fit whose geometry the
// data found looked better than it is: on 17 points with 3 parameters, up to 20 % below its
// chi2/dof. Where chi2/dof inflated the sigmas (least squares), they follow the new value.
void CountNuisance(const GeometryUse& g, const BenchOptics& b, const FitOptions& o,
                   FitSummary& fit) {
  auto share = [](const NuisanceUse& n, double prior) {
    if (!n.fitted || !(prior > 0)) return 0.0;
    return std::clamp(1 - (n.offset_sigma * n.offset_sigma) / (prior * prior), 0.0, 1.0);
  };
  const double nu = share(g.thickness, b.thickness_sigma_mm) +
                    share(g.rectangle_x, b.rectangle_sigma_px) +
                    share(g.rectangle_y, b.rectangle_sigma_px);
  // At least one degree of freedom stays (ValidateSamples asks for n_params + 1 samples).
  const double n_nuisance = std::min(nu, std::max(0.0, fit.n_points - fit.n_params - 1.0));
  if (n_nuisance <= 0) return;
  const double before = fit.reduced_chi2;
  fit.n_nuisance = n_nuisance;
  SetInformation(fit);
  if (o.inflate_by_reduced_chi2 && o.loss == Loss::kNone) {
    const double r = std::sqrt(std::max(1.0, fit.reduced_chi2) / std::max(1.0, before));
    for (Parameter* q : {&fit.width, &fit.scale, &fit.eta, &fit.floor}) q->sigma *= r;
  }
  if (fit.status != FitStatus::kFailed) JudgeFit(fit.width.sigma > 0, fit);
}

// GeometryUse (fitter.h): the geometry's stated uncertainties into the fit.
Result<FitSummary> WithGeometry(std::span<const Sample> samples, const FitOptions& o,
                                FitSummary fit) {
  const Sample* known = nullptr;
  for (const Sample& s : samples)
    if (s.response && s.response->setup) known = &s;
  if (fit.status == FitStatus::kFailed) return fit;
  if (known == nullptr || !o.use_response) {
    fit.geometry.note =
        "the samples carry no instrument response: the geometry's uncertainty "
        "(angles, thickness, rectangle) is not known and not in sigma";
    return fit;
  }
  const BenchOptics& b = known->response->setup->bench;
  Tell(o,
       "the geometry's uncertainty: refits with the angles, the thickness and the rectangle "
       "as stated and moved");
  GeometryUse g;
  g.stated = true;
  std::ostringstream note;
  // The angle read-back: the arm's per point, through each sample's sigma; the sample stage's per
  // group of points taken without moving it, as an offset of the solve (StageGroups).
  SolveOptions so(o);
  double angle_part = 0;
  std::vector<Sample> widened;
  if (b.angle_sigma_deg > 0) {
    const double a_sigma = b.angle_sigma_deg;
    auto stage = std::make_shared<StageGroups>();
    stage->prior_deg = a_sigma;
    stage->group.assign(samples.size(), -1);
    stage->slope.assign(samples.size(), 0.0);
    widened.assign(samples.begin(), samples.end());
    for (std::size_t i = 0; i < widened.size(); ++i) {
      Sample& s = widened[i];
      if (!s.response || !s.response->setup) continue;
      const auto [d_sample, d_arm] = StageSlopes(fit, s);
      g.angle_max_fraction =
          std::max(g.angle_max_fraction, a_sigma * std::hypot(d_sample, d_arm) / s.sigma);
      s.sigma = std::hypot(s.sigma, a_sigma * d_arm);
      const double at = s.response->at.sample_deg;
      if (i == 0 || stage->group[i - 1] < 0 || stage->groups.back().sample_deg != at)
        stage->groups.push_back({at, 0, 0, a_sigma});
      ++stage->groups.back().points;
      stage->group[i] = static_cast<int>(stage->groups.size()) - 1;
      stage->slope[i] = d_sample;
    }
    const double tol = o.response_tolerance;
    const double adds = std::hypot(1.0, g.angle_max_fraction) - 1;
    note << std::setprecision(2) << "angle read-back +-" << b.angle_sigma_deg << " deg: at most "
         << 100 * g.angle_max_fraction << " % of a sample's sigma (adding " << 100 * adds
         << " % in quadrature)";
    if (adds > tol * tol / 2) {
      SolveOptions with_stage(o);
      with_stage.stage = stage;
      auto again = FitWithFloor(widened, with_stage);
      if (!again.ok()) return again.error();
      if (again->status != FitStatus::kFailed) {
        const std::string floor_choice = fit.floor_choice;
        fit = std::move(again).value();
        if (fit.floor_choice.empty()) fit.floor_choice = floor_choice;
        g.angle_in_fit = true;
        so = with_stage;
        // Its share of the width's sigma: the sigma with and without it, both uninflated by
        // chi-square (the fit without it may have been inflated by the very scatter it explains).
        SolveOptions plain = so, plain_without(o);
        plain.inflate_by_reduced_chi2 = plain_without.inflate_by_reduced_chi2 = false;
        const auto with = Refit(widened, plain, fit), without = Refit(samples, plain_without, fit);
        if (with && without)
          angle_part = std::sqrt(std::max(0.0, with->width.sigma * with->width.sigma -
                                                   without->width.sigma * without->width.sigma));
        note << ", in the fit: the arm's in each sample's sigma, the sample stage's as one offset "
                "for each of "
             << stage->groups.size() << " groups of points taken without moving it";
      }
    } else {
      note << ", left out (the fit takes it in above " << 100 * tol * tol / 2 << " %)";
    }
  } else {
    note << "angle read-back: not stated";
  }
  // Common to the run: the thickness and the rectangle's position, profiled as nuisance
  // parameters by refits of the samples the fit used (with the angle term in their sigmas where
  // it went in). One that does not converge leaves its part out of sigma, and the note says so;
  // the fit itself stands.
  std::optional<FitSummary> base;
  if (!WidthConstrained(fit) && (b.thickness_sigma_mm > 0 || b.rectangle_sigma_px > 0)) {
    // Refits with the response each (most of such a fit's time) for a width the data do not
    // constrain: not worth it. A poor fit keeps them: a geometry that is off is one reason a
    // fit is poor.
    note << "; thickness and rectangle: not computed (the data do not constrain the width)";
    g.note = note.str();
    g.sample_stage = fit.geometry.sample_stage;
    fit.width.sigma_geometry = angle_part;
    fit.geometry = g;
    return fit;
  }
  const std::span<const Sample> used = g.angle_in_fit ? std::span<const Sample>(widened) : samples;
  if (b.thickness_sigma_mm > 0 || b.rectangle_sigma_px > 0) {
    SolveOptions ls = so;
    ls.loss = Loss::kNone;
    base = Refit(used, ls, fit);
  }
  const char* why = base ? " (a refit with it moved did not converge)"
                         : " (the unmoved least-squares refit did not converge)";
  // The quantities stated, profiled together (JointProfile): the thickness, and the rectangle's
  // x and y (d output pixels along an axis is the optical axis as far the other way).
  std::vector<Quantity> q;
  int k_thickness = -1, k_x = -1;
  if (b.thickness_sigma_mm > 0) {
    k_thickness = static_cast<int>(q.size());
    q.push_back({[](ResponseSetup& c, double d) { c.thickness_mm += d; }, b.thickness_sigma_mm});
  }
  if (b.rectangle_sigma_px > 0) {
    k_x = static_cast<int>(q.size());
    q.push_back({[](ResponseSetup& c, double d) { c.bench.axis_x_px -= d * c.rectangle.binning_h; },
                 b.rectangle_sigma_px});
    q.push_back({[](ResponseSetup& c, double d) { c.bench.axis_y_px -= d * c.rectangle.binning_v; },
                 b.rectangle_sigma_px});
  }
  std::optional<JointUse> joint;
  if (base && !q.empty()) joint = JointProfile(used, q, so, fit, *base);
  double shift = 0;
  if (k_thickness >= 0) {
    const double t = b.thickness_sigma_mm;
    if (joint && !joint->left_out[k_thickness]) {
      const NuisanceUse& n = joint->use[k_thickness];
      g.thickness = n;
      g.width_thickness = n.width_sigma;
      shift += n.width_shift;
      note << "; thickness " << DescribeNuisance(n, "mm", t, joint->why_not[k_thickness]);
    } else {
      g.left_out = true;
      note << "; thickness +-" << t << " mm: LEFT OUT of sigma" << why;
    }
  } else {
    note << "; thickness: not stated";
  }
  if (k_x >= 0) {
    const double p = b.rectangle_sigma_px;
    if (joint && !joint->left_out[k_x] && !joint->left_out[k_x + 1]) {
      g.rectangle_x = joint->use[k_x];
      g.rectangle_y = joint->use[k_x + 1];
      g.width_rectangle = std::hypot(g.rectangle_x.width_sigma, g.rectangle_y.width_sigma);
      shift += g.rectangle_x.width_shift + g.rectangle_y.width_shift;
      note << "; rectangle x " << DescribeNuisance(g.rectangle_x, "px", p, joint->why_not[k_x])
           << ", y " << DescribeNuisance(g.rectangle_y, "px", p, joint->why_not[k_x + 1]);
    } else {
      g.left_out = true;
      note << "; rectangle +-" << p << " px: LEFT OUT of sigma" << why;
    }
  } else {
    note << "; rectangle position: not stated";
  }
  // The fit at the most probable geometry, with the fit's own loss, from its solution: the
  // width, k, the floor, chi-square and the residuals are then all of the geometry the data
  // found (Predict models it too). Should that refit not converge, the width alone moves by the
  // profile's shift and the note says so.
  if (g.thickness.fitted || g.rectangle_x.fitted || g.rectangle_y.fitted) {
    auto best =
        Refit(WithSetupChanged(used, [&g](ResponseSetup& c) { MoveToFitted(g, c); }), so, fit);
    if (best) {
      const std::string floor_choice = fit.floor_choice;
      const double floor_shift = fit.floor_width_shift, floor_part = fit.width.sigma_floor;
      fit = std::move(best).value();
      if (fit.floor_choice.empty()) fit.floor_choice = floor_choice;
      // The refit keeps the floor's choice but not what the choice put in sigma.
      fit.floor_width_shift = floor_shift;
      fit.width.sigma_floor = floor_part;
      fit.width.sigma = std::hypot(fit.width.sigma, floor_part);
      note << "; refitted at that geometry";
    } else {
      fit.width.value += shift;
      note << "; the refit at that geometry did not converge: the width moved by " << std::showpos
           << shift << std::noshowpos << " alone";
    }
  }
  // The sample stage's offsets of the final fit (the one at the geometry found, where it moved).
  if (g.angle_in_fit) {
    double largest = 0;  // in the prior's sigma
    for (const StageOffset& so_g : fit.geometry.sample_stage)
      largest = std::max(largest, std::abs(so_g.offset_deg) / b.angle_sigma_deg);
    note << std::setprecision(2) << "; the sample stage's largest offset found: " << largest
         << " of its prior's sigma";
  }
  CountNuisance(g, b, o, fit);
  if (fit.n_nuisance > 0)
    note << std::setprecision(2) << "; chi2/dof counts " << fit.n_nuisance
         << " of them as fitted parameters";
  const double common = std::hypot(g.width_thickness, g.width_rectangle);
  fit.width.sigma = std::hypot(fit.width.sigma, common);
  fit.width.sigma_geometry = std::hypot(angle_part, common);
  g.note = note.str();
  g.sample_stage = fit.geometry.sample_stage;
  fit.geometry = g;
  return fit;
}

}  // namespace

Result<FitSummary> Fit(std::span<const Sample> samples, const FitOptions& o) {
  if (Status s = o.Validate(); !s) return s.error();
  if (Status s = ValidateSamples(samples, o.NumParams()); !s) return s.error();
  if (IsReflection(samples[0]) && !HasBrdf(o.model.family))
    return InvalidArgument(std::string(Name(o.model.family)) +
                           " is a transmission model (Sun 2008 gives no BRDF): it cannot fit "
                           "reflection samples; fit beckmann, ggx or phong");
  const auto t0 = std::chrono::steady_clock::now();
  auto fit = FitWithFloor(samples, SolveOptions(o));
  if (!fit.ok()) return fit;
  auto out = WithGeometry(samples, o, std::move(fit).value());
  if (out.ok())
    out->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return out;
}

// ---- Comparing models ----------------------------------------------------------------------

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

// ---- The paper's protocol -----------------------------------------------------------------------

std::vector<PredictionError> PredictIncidences(const FitSummary& fit,
                                               std::span<const Sample> samples) {
  std::vector<PredictionError> out;
  for (const auto& g : GroupByIncidence(samples)) {
    PredictionError e;
    e.theta_l_deg = g.theta_l_deg;
    e.n = static_cast<int>(g.samples.size());
    double peak_meas = 0, peak_pred = 0, sum_rel2 = 0;
    int n_rel = 0;
    for (const Sample& s : g.samples) peak_meas = std::max(peak_meas, s.value);
    for (const Sample& s : g.samples) {
      const double p = Predict(fit, s);
      peak_pred = std::max(peak_pred, p);
      e.reduced_chi2 += (p - s.value) * (p - s.value) / (s.sigma * s.sigma);
      if (s.value > 0.01 * peak_meas) {
        sum_rel2 += (p - s.value) * (p - s.value) / (s.value * s.value);
        ++n_rel;
      }
    }
    e.reduced_chi2 /= std::max(1, e.n);
    e.rms_relative = n_rel ? std::sqrt(sum_rel2 / n_rel) : 0;
    e.peak_ratio = peak_meas > 0 ? peak_pred / peak_meas : 0;
    out.push_back(e);
  }
  return out;
}

// ---- Empirical D --------------------------------------------------------------------------------

std::vector<EmpiricalDPoint> EmpiricalD(std::span<const Sample> samples, double scale, double eta,
                                        double min_relative, double min_snr) {
  std::vector<EmpiricalDPoint> out;
  double max_value = 0;
  for (const Sample& s : samples) max_value = std::max(max_value, s.value);
  for (const Sample& s : samples) {
    const Vec3<double>& l = s.light;
    const Vec3<double>& v = s.view;
    if (optics::AbsCosTheta(l) <= 0.5 || optics::AbsCosTheta(v) <= 0.5) continue;
    if (s.value < min_relative * max_value || s.value < min_snr * s.sigma) continue;
    // eq. 21 (or 20 for reflection) with G = 1, solved for D; S = k f |cos theta_l|.
    const FixedGeometry g = PrecomputeGeometry(l, v, eta);
    if (!(g.factor > 0)) continue;
    const double to_d = 1 / (scale * g.factor);
    EmpiricalDPoint p;
    p.theta_h_deg = std::acos(std::clamp(g.h.z, -1.0, 1.0)) / kDeg;
    p.d = s.value * to_d;
    p.d_sigma = s.sigma * to_d;
    out.push_back(p);
  }
  std::sort(out.begin(), out.end(), [](const EmpiricalDPoint& a, const EmpiricalDPoint& b) {
    return a.theta_h_deg < b.theta_h_deg;
  });
  return out;
}

double FittedD(const FitSummary& fit, double theta_h_deg) {
  using namespace optics;
  const Vec3<double> m = DirectionInPlane(theta_h_deg * kDeg);
  switch (fit.model.family) {
    case Family::kBeckmann:
      return BeckmannDistribution<double>(fit.width.value).D(m);
    case Family::kGgx:
      return GgxDistribution<double>(fit.width.value).D(m);
    case Family::kPhong:
      return PhongDistribution<double>(fit.width.value).D(m);
    case Family::kSun2008:
      return Sun2008OrientationD(m, fit.width.value);
  }
  return 0;
}

}  // namespace gonio::fitting
