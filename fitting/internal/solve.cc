#include "fitting/internal/solve.h"

#include <algorithm>
#include <map>
#include <utility>

#include "fitting/internal/residuals.h"

namespace gonio::fitting {

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
  const double theta_h = std::min(half_angle / deflection, 80 * optics::kDeg);
  return std::tan(theta_h) / std::sqrt(std::log(2.0));
}

}  // namespace gonio::fitting

namespace gonio::fitting::internal {

LocalFit::~LocalFit() = default;

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

}  // namespace gonio::fitting::internal
