#include "acquisition/strategy.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <utility>

#include "acquisition/exposure.h"
#include "fitting/model.h"
#include "fitting/sample.h"

namespace gonio::acquisition {
namespace {

using Mat3 = std::array<std::array<double, 3>, 3>;
using Vec3 = std::array<double, 3>;

// The inverse of a symmetric 3x3 matrix by cofactors; nullopt when singular.
std::optional<Mat3> Inverse(const Mat3& a) {
  Mat3 c;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) {
      const int i1 = (i + 1) % 3, i2 = (i + 2) % 3, j1 = (j + 1) % 3, j2 = (j + 2) % 3;
      c[j][i] = a[i1][j1] * a[i2][j2] - a[i1][j2] * a[i2][j1];  // transposed: the adjugate
    }
  const double det = a[0][0] * c[0][0] + a[0][1] * c[1][0] + a[0][2] * c[2][0];
  if (!(std::abs(det) > 0) || !std::isfinite(det)) return std::nullopt;
  for (auto& row : c)
    for (double& x : row) x /= det;
  return c;
}

Vec3 Times(const Mat3& a, const Vec3& g) {
  Vec3 u{};
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) u[i] += a[i][j] * g[j];
  return u;
}

double Dot(const Vec3& a, const Vec3& b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

// The Fisher information of the points seen in (ln alpha, ln k, b), with a weak prior so that a
// parameter the points cannot see yet (the floor, before any tail point) leaves it invertible:
// ln alpha and ln k within a factor e^10, b within the largest value seen.
Mat3 Information(const Provisional& model, const std::vector<Observation>& seen) {
  Mat3 f{};
  double peak = 0;
  for (const Observation& o : seen) {
    if (o.point.reflection || !(o.sigma > 0)) continue;
    peak = std::max(peak, std::abs(o.value));
    const Vec3 g = model.Gradient(o.point);
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) f[i][j] += g[i] * g[j] / (o.sigma * o.sigma);
  }
  f[0][0] += 1e-2;
  f[1][1] += 1e-2;
  f[2][2] += 1 / std::pow(std::max(peak, 1e-12), 2);
  return f;
}

double Median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

// sigma^2 (x frames when per_frame) = shot S/t + dark/t + read/t^2 + lamp S^2, each >= 0: least
// squares in relative terms (every row divided by its sigma^2) over each subset of the terms; the
// best subset whose coefficients are all >= 0 wins (a non-negative least squares on four
// unknowns).
Result<FrameNoise> FitNoiseTerms(const std::vector<const Observation*>& use, bool per_frame) {
  if (use.size() < 3)
    return Error{ErrorCode::kFailedPrecondition,
                 "the noise model needs 3 measured points with signal, and there are " +
                     std::to_string(use.size())};
  auto variance = [&](const Observation& o) {
    return o.sigma * o.sigma * (per_frame ? std::max(1, o.frames) : 1);
  };
  constexpr int kTerms = 4;  // shot, read, lamp, dark
  using Row = std::array<double, kTerms>;
  auto terms = [](const Observation& o) {
    const double t = o.exposure_s;
    return Row{o.value / t, 1 / (t * t), o.value * o.value, 1 / t};
  };
  FrameNoise best_terms;
  double best = std::numeric_limits<double>::infinity();
  for (int mask = 1; mask < (1 << kTerms); ++mask) {
    std::array<Row, kTerms> a{};
    Row b{};
    for (const Observation* o : use) {
      const double v = variance(*o);
      Row row = terms(*o);
      for (int i = 0; i < kTerms; ++i) row[i] = mask & (1 << i) ? row[i] / v : 0;
      for (int i = 0; i < kTerms; ++i) {
        b[i] += row[i];
        for (int j = 0; j < kTerms; ++j) a[i][j] += row[i] * row[j];
      }
    }
    for (int i = 0; i < kTerms; ++i)
      if (!(mask & (1 << i))) a[i][i] = 1;  // unused terms: fixed at 0
    // Gaussian elimination with partial pivoting; a singular subset is skipped.
    Row c = b;
    bool singular = false;
    for (int k = 0; k < kTerms && !singular; ++k) {
      int pivot = k;
      for (int i = k + 1; i < kTerms; ++i)
        if (std::abs(a[i][k]) > std::abs(a[pivot][k])) pivot = i;
      if (!(std::abs(a[pivot][k]) > 1e-300)) {
        singular = true;
        break;
      }
      std::swap(a[k], a[pivot]);
      std::swap(c[k], c[pivot]);
      for (int i = k + 1; i < kTerms; ++i) {
        const double f = a[i][k] / a[k][k];
        for (int j = k; j < kTerms; ++j) a[i][j] -= f * a[k][j];
        c[i] -= f * c[k];
      }
    }
    if (singular) continue;
    for (int k = kTerms - 1; k >= 0; --k) {
      for (int j = k + 1; j < kTerms; ++j) c[k] -= a[k][j] * c[j];
      c[k] /= a[k][k];
    }
    if (std::any_of(c.begin(), c.end(), [](double x) { return !(x >= 0); })) continue;
    double r2 = 0;
    for (const Observation* o : use) {
      const Row row = terms(*o);
      double model = 0;
      for (int i = 0; i < kTerms; ++i) model += c[i] * row[i];
      r2 += std::pow(model / variance(*o) - 1, 2);
    }
    if (r2 < best) best = r2, best_terms = FrameNoise{c[0], c[1], c[2], c[3]};
  }
  if (!std::isfinite(best))
    return Error{ErrorCode::kFailedPrecondition, "the noise model found no fit to the sigmas"};
  return best_terms;
}

std::vector<const Observation*> WithSignal(const std::vector<Observation>& seen) {
  std::vector<const Observation*> use;
  for (const Observation& o : seen)
    if (o.value > 0 && o.sigma > 0 && o.exposure_s > 0) use.push_back(&o);
  return use;
}

}  // namespace

void SelectByStrategy(const Plan& plan, std::vector<PlannedPoint>* grid) {
  const StrategyPolicy& s = plan.strategy;
  if (s.kind == StrategyKind::kUniform) return;
  // Groups: one view sweep per incidence and azimuth, in the grid's order.
  std::map<std::pair<double, double>, std::vector<PlannedPoint*>> sweeps;
  for (PlannedPoint& p : *grid)
    if (!p.skipped) sweeps[{p.phi_deg, p.theta_l_deg}].push_back(&p);
  for (auto& [key, points] : sweeps) {
    if (s.kind == StrategyKind::kAdaptive) {
      // By view angle, so that the coarse scan is the same on either sweep direction.
      std::vector<PlannedPoint*> by_view = points;
      std::sort(by_view.begin(), by_view.end(), [](const PlannedPoint* a, const PlannedPoint* b) {
        return a->theta_v_deg < b->theta_v_deg;
      });
      for (std::size_t k = 0; k < by_view.size(); ++k)
        if (k % s.coarse_every != 0)
          by_view[k]->skipped = true, by_view[k]->reason = kCandidateReason;
      continue;
    }
    // lobe
    const Provisional expected{*plan.specimen.expected_alpha, 1, 0, plan.specimen.eta};
    double peak = 0;
    for (const PlannedPoint* p : points) peak = std::max(peak, expected.Value(*p));
    int outside = 0;
    char reason[96];
    std::snprintf(reason, sizeof reason, "lobe: outside the expected lobe (below %g of its peak)",
                  s.lobe_fraction);
    for (PlannedPoint* p : points) {
      if (expected.Value(*p) >= s.lobe_fraction * peak) continue;
      if (outside++ % s.tail_every != 0) p->skipped = true, p->reason = reason;
    }
  }
}

ExposurePolicy CoarseExposure(const Plan& plan) {
  ExposurePolicy x = plan.exposure;
  if (plan.strategy.kind != StrategyKind::kAdaptive) return x;
  x.frames = plan.strategy.coarse_frames;
  x.max_s = std::min(x.max_s, plan.strategy.coarse_max_s);
  x.min_s = std::min(x.min_s, x.max_s);
  x.initial_s = std::clamp(x.initial_s, x.min_s, x.max_s);
  return x;
}

ExposurePolicy ExposureFor(const Plan& plan, const PlannedPoint& p) {
  return p.planned_exposure_s ? plan.exposure : CoarseExposure(plan);
}

double NoiseModel::Exposure(double value) const {
  if (!(value > 0) || !(fill > 0)) return exposure.max_s;
  return std::clamp(OnLadder(fill / value), exposure.min_s, exposure.max_s);
}

double NoiseModel::Sigma(double value) const {
  const double t = Exposure(value), s = std::max(value, 0.0);
  return std::sqrt(shot * s / t + dark_current / t + read / (t * t) + lamp * s * s);
}

double NoiseModel::Take(double value) {
  const double cost = Cost(value), t = Exposure(value);
  if (auto dark = DarkAt(t); dark == dark_taken.end())
    dark_taken[t] = clock_s;
  else if (clock_s - dark->second > dark_max_age_s)
    dark->second = clock_s;
  clock_s += cost;
  return cost;
}

namespace {
template <typename Map>
auto FindExposure(Map& darks, double t) {
  return std::find_if(darks.begin(), darks.end(),
                      [&](const auto& d) { return SameExposure(d.first, t); });
}
}  // namespace

std::map<double, double>::iterator NoiseModel::DarkAt(double t) {
  return FindExposure(dark_taken, t);
}

std::map<double, double>::const_iterator NoiseModel::DarkAt(double t) const {
  return FindExposure(dark_taken, t);
}

double NoiseModel::Cost(double value) const {
  const double t = Exposure(value);
  const auto it = DarkAt(t);
  const bool dark = it != dark_taken.end() && clock_s - it->second <= dark_max_age_s;
  return exposure.frames * t + overhead_s + (dark ? 0 : dark_frames * t);
}

Result<NoiseModel> CalibrateNoise(const std::vector<Observation>& seen,
                                  const ExposurePolicy& exposure, const DarkPolicy& darks) {
  NoiseModel m;
  m.exposure = exposure;
  m.dark_frames = darks.frames;
  // The dark library as the engine keeps it, replayed on the points' costs (summed, the run's
  // clock): a set is taken at the first point of its exposure and again once it is older than
  // max_age_s.
  m.dark_max_age_s = darks.max_age_s;
  for (const Observation& o : seen) {
    if (auto it = m.DarkAt(o.exposure_s); it == m.dark_taken.end())
      m.dark_taken[o.exposure_s] = m.clock_s;
    else if (m.clock_s - it->second > darks.max_age_s)
      it->second = m.clock_s;
    m.clock_s += o.cost_s;
  }
  const std::vector<const Observation*> use = WithSignal(seen);
  auto terms = FitNoiseTerms(use, /*per_frame=*/false);  // first: it says what is missing
  if (!terms.ok()) return terms.error();
  std::vector<double> fills, overheads;
  for (const Observation& o : seen)
    overheads.push_back(std::max(0.0, o.cost_s - o.frames * o.exposure_s));
  m.overhead_s = Median(overheads);
  // Each point's level says how much value x exposure fills the range to the target.
  for (const Observation* o : use)
    if (o->level > 0) fills.push_back(o->value * o->exposure_s * exposure.target / o->level);
  if (fills.empty())
    return Error{ErrorCode::kFailedPrecondition,
                 "the noise model needs the points' levels (their fraction of the linear range)"};
  m.fill = Median(fills);
  m.shot = terms->shot, m.read = terms->read, m.lamp = terms->lamp, m.dark_current = terms->dark;
  return m;
}

Result<FrameNoise> CalibrateFrameNoise(const std::vector<Observation>& seen) {
  return FitNoiseTerms(WithSignal(seen), /*per_frame=*/true);
}

double Provisional::Value(const PlannedPoint& p) const {
  if (p.reflection) return 0;
  const fitting::Sample s =
      fitting::SampleFromBenchAngles(p.theta_l_deg, p.phi_deg, p.theta_v_deg, p.phi_deg, 0, 1);
  return k * fitting::ModelBtdf(fitting::ModelSpec{}, s.light, s.view, alpha, eta) *
             std::abs(s.light.z) +
         b;
}

std::array<double, 3> Provisional::Gradient(const PlannedPoint& p) const {
  if (p.reflection) return {0, 0, 0};
  const double h = 1e-4;  // central difference in ln alpha: relative error ~h^2
  Provisional up = *this, down = *this;
  up.alpha *= std::exp(h), down.alpha *= std::exp(-h);
  up.b = down.b = 0;
  Provisional lobe = *this;
  lobe.b = 0;
  return {(up.Value(p) - down.Value(p)) / (2 * h), lobe.Value(p), 1.0};
}

std::string Choice::Reason() const {
  char s[256];
  std::snprintf(
      s, sizeof s,
      "theta_l %.4g theta_v %.4g phi %.4g: predicted %.4g +- %.2g at %.4g s, cost %.4g s; "
      "sigma(alpha)/alpha %.4g -> %.4g",
      point.theta_l_deg, point.theta_v_deg, point.phi_deg, predicted_value, predicted_sigma,
      exposure_s, cost_s, rel_sigma_before, rel_sigma_after);
  return s;
}

double PredictedRelSigmaAlpha(const Provisional& model, const std::vector<Observation>& seen) {
  const auto inv = Inverse(Information(model, seen));
  return inv ? std::sqrt(std::max(0.0, (*inv)[0][0])) : std::numeric_limits<double>::infinity();
}

std::vector<Choice> ChooseNext(const Provisional& model, const NoiseModel& calibrated,
                               const std::vector<Observation>& seen,
                               const std::vector<PlannedPoint>& candidates, int count) {
  std::vector<Choice> out;
  NoiseModel noise = calibrated;  // learns the darks the batch's own choices will take
  auto inv = Inverse(Information(model, seen));
  if (!inv) return out;
  Mat3 c = *inv;
  for (int n = 0; n < count; ++n) {
    const PlannedPoint* best = nullptr;
    double best_score = 0, best_gain = 0, best_sigma = 0;
    Vec3 best_u{};
    double best_denominator = 0;
    for (const PlannedPoint& p : candidates) {
      if (p.reflection || (p.skipped && p.reason != kCandidateReason)) continue;
      const double value = model.Value(p);
      if (!(value > 0)) continue;
      const double sigma = noise.Sigma(value);
      const Vec3 g = model.Gradient(p);
      const Vec3 u = Times(c, g);
      const double denominator = sigma * sigma + Dot(g, u);
      const double gain = u[0] * u[0] / denominator;  // the drop of var(ln alpha)
      const double score = gain / noise.Cost(value);
      if (score > best_score) {
        best = &p, best_score = score, best_gain = gain, best_sigma = sigma;
        best_u = u, best_denominator = denominator;
      }
    }
    if (best == nullptr) break;
    Choice ch;
    ch.point = *best;
    ch.predicted_value = model.Value(*best);
    ch.predicted_sigma = best_sigma;
    ch.exposure_s = noise.Exposure(ch.predicted_value);
    ch.cost_s = noise.Cost(ch.predicted_value);
    ch.point.skipped = false;
    ch.point.reason.clear();
    ch.point.planned_exposure_s = ch.exposure_s;
    ch.point.predicted_s = ch.cost_s;
    ch.rel_sigma_before = std::sqrt(std::max(0.0, c[0][0]));
    // Sherman-Morrison: (F + g g'/s^2)^-1 = F^-1 - u u' / (s^2 + g'u).
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) c[i][j] -= best_u[i] * best_u[j] / best_denominator;
    ch.rel_sigma_after = std::sqrt(std::max(0.0, c[0][0]));
    noise.Take(ch.predicted_value);  // the batch's clock runs on, its darks are taken
    (void)best_gain;
    out.push_back(ch);
  }
  return out;
}

Result<fitting::FitSummary> FitSeen(const std::vector<Observation>& seen, double eta) {
  std::vector<fitting::Sample> samples;
  for (const Observation& o : seen) {
    if (o.point.reflection) continue;
    samples.push_back(fitting::SampleFromBenchAngles(o.point.theta_l_deg, o.point.phi_deg,
                                                     o.point.theta_v_deg, o.point.phi_deg, o.value,
                                                     o.sigma));
  }
  fitting::FitOptions options;
  options.eta = eta;
  options.floor = fitting::Floor::kFit;
  options.max_local_fits = 2;
  return fitting::Fit(samples, options);
}

Result<AdaptiveStep> NextAdaptiveStep(const Plan& plan, const std::vector<PlannedPoint>& candidates,
                                      const std::vector<Observation>& seen) {
  const StrategyPolicy& s = plan.strategy;
  AdaptiveStep step;
  AdaptiveOutcome out;
  double predicted_s = 0, actual_s = 0;  // of the points chosen so far
  for (const Observation& o : seen) {
    out.spent_s += o.cost_s;
    if (o.point.predicted_s > 0)
      predicted_s += o.point.predicted_s, actual_s += o.cost_s, ++out.chosen;
  }
  char text[256];
  auto fit = FitSeen(seen, plan.specimen.eta);
  if (!fit.ok()) return fit.error();
  out.fit = *fit;
  const double rel = fit->width.sigma / fit->width.value;
  // A poor fit counts too: its sigma is inflated by sqrt(chi2/dof), so it is no smaller than what
  // the run's own fit will give. The provisional fit is the point model on the stored sigmas; on a
  // real bench it becomes poor as the points get precise (the rectangle and the apertures move a
  // ground-glass lobe by 1-3 %, docs/measurement.md), and a run that waited for it to converge
  // went on 40 times past its target (bench/forecast_spread.cc).
  const bool poor = fit->status == fitting::FitStatus::kPoorFit;
  if (s.target_rel_sigma_alpha > 0 && (fit->status == fitting::FitStatus::kConverged || poor) &&
      rel <= s.target_rel_sigma_alpha) {
    out.stop = AdaptiveOutcome::Stop::kTarget;
    std::snprintf(text, sizeof text, "reached sigma(alpha)/alpha %.3g <= %.3g after %.0f s", rel,
                  s.target_rel_sigma_alpha, out.spent_s);
    out.message = text;
    if (poor) {
      std::snprintf(text, sizeof text,
                    " (the provisional point-model fit is poor, chi2/dof %.3g: its sigma is "
                    "inflated by sqrt(chi2/dof); the run's own fit models the bench's response)",
                    fit->reduced_chi2);
      out.message += text;
    }
    step.stop = out;
    return step;
  }
  if (fit->status == fitting::FitStatus::kFailed)
    return Error{ErrorCode::kFailedPrecondition, "the provisional fit failed after " +
                                                     std::to_string(seen.size()) +
                                                     " points: " + fit->message};
  auto noise = CalibrateNoise(seen, plan.exposure, plan.darks);
  if (!noise.ok()) return noise.error();
  const Provisional model{fit->width.value, fit->scale.value, fit->floor.value, plan.specimen.eta};
  // Batches grow with the run (at least a quarter of the points so far): the choices within a
  // batch already account for each other, and a fit per few points of a long run would cost
  // more computer time than they save bench time. The first is `batch`: it measures how far
  // the predicted costs are off before much is spent on them.
  const int count =
      out.chosen == 0 ? s.batch : std::max(s.batch, static_cast<int>(seen.size() / 4));
  std::vector<Choice> batch = ChooseNext(model, *noise, seen, candidates, count);
  // No more than the target needs, as predicted: the batch ends at the first choice that brings
  // the predicted sigma(alpha)/alpha to the target (at least `batch` choices, so that a
  // prediction a little optimistic costs a few more rounds, not one point per round). Without
  // it a run overshoots its target by up to a batch, a quarter of its points.
  if (s.target_rel_sigma_alpha > 0) {
    const auto enough = std::find_if(batch.begin(), batch.end(), [&](const Choice& c) {
      return c.rel_sigma_after <= s.target_rel_sigma_alpha;
    });
    if (enough != batch.end()) {
      const auto keep = std::max<std::ptrdiff_t>(enough - batch.begin() + 1, s.batch);
      if (keep < static_cast<std::ptrdiff_t>(batch.size())) batch.resize(keep);
    }
  }
  // What the choices cost so far against what they were predicted to cost (ranging tries, longer
  // moves): the budget is checked on predictions scaled by it.
  const double ratio = predicted_s > 0 ? std::clamp(actual_s / predicted_s, 0.5, 10.0) : 1.0;
  // Measured in the grid's order (a serpentine), not the order of choice: the stages move least.
  // The costs are priced again in that order (which darks age out depends on it); while the batch
  // overruns what is left of the budget, its last choice goes.
  std::vector<std::pair<Choice, std::size_t>> ranked;  // with the order of choice
  for (std::size_t k = 0; k < batch.size(); ++k) ranked.emplace_back(batch[k], k);
  std::stable_sort(ranked.begin(), ranked.end(), [](const auto& a, const auto& b) {
    return a.first.point.index < b.first.point.index;
  });
  auto price = [&] {
    NoiseModel n = *noise;
    double total = 0;
    for (auto& [c, k] : ranked) {
      c.cost_s = c.point.predicted_s = n.Take(c.predicted_value);
      total += ratio * c.cost_s;
    }
    return total;
  };
  // Before any choice was measured the predictions are untested: the first batch may spend at
  // most half of what is left.
  const double left = (s.budget_s - out.spent_s) * (out.chosen == 0 ? 0.5 : 1.0);
  const double first_cost = batch.empty() ? 0 : ratio * batch[0].cost_s;
  while (!ranked.empty() && price() > left && s.budget_s > 0)
    ranked.erase(std::max_element(ranked.begin(), ranked.end(), [](const auto& a, const auto& b) {
      return a.second < b.second;
    }));
  if (s.budget_s > 0 && ranked.empty() && !batch.empty()) {
    out.stop = AdaptiveOutcome::Stop::kBudget;
    std::snprintf(text, sizeof text,
                  "stopped at the budget: %.0f of %.0f s spent, the next point costs %.0f s; "
                  "sigma(alpha)/alpha is %.3g%s",
                  out.spent_s, s.budget_s, first_cost, rel,
                  s.target_rel_sigma_alpha > 0 ? " (the target was not reached)" : "");
    out.message = text;
    step.stop = out;
    return step;
  }
  // A bound that no sensible budget reaches: every candidate chosen 50 times.
  if (ranked.empty() || seen.size() >= 50 * (candidates.size() + 1)) {
    out.stop = AdaptiveOutcome::Stop::kExhausted;
    out.message = "no candidate point adds to what is known of alpha";
    step.stop = out;
    return step;
  }
  batch.clear();
  for (auto& [c, k] : ranked) batch.push_back(c);
  step.batch = std::move(batch);
  return step;
}

Result<AdaptiveOutcome> RunAdaptive(const Plan& plan, const std::vector<PlannedPoint>& candidates,
                                    std::vector<Observation> seen, const MeasureBatch& measure,
                                    const std::function<void(const Choice&)>& decided) {
  for (int rounds = 0;; ++rounds) {
    auto step = NextAdaptiveStep(plan, candidates, seen);
    if (!step.ok()) return step.error();
    if (step->stop) {
      step->stop->rounds = rounds;
      return *step->stop;
    }
    if (decided)
      for (const Choice& c : step->batch) decided(c);
    auto measured = measure(step->batch);
    if (!measured.ok()) return measured.error();
    seen.insert(seen.end(), measured->begin(), measured->end());
  }
}

}  // namespace gonio::acquisition
