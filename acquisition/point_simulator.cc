#include "acquisition/point_simulator.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "acquisition/exposure.h"

namespace gonio::acquisition {

double PointSimulator::Truth(const PlannedPoint& p) const {
  const Provisional truth{o_.alpha, o_.k, o_.stray_e_per_s / o_.electrons_per_s_per_value, o_.eta};
  return truth.Value(p);
}

Observation PointSimulator::Measure(const PlannedPoint& p, const ExposurePolicy& x,
                                    double planned_s) {
  Observation out;
  out.point = p;
  const double rate_e = Truth(p) * o_.electrons_per_s_per_value;  // per pixel
  const double range_adu = o_.full_well_e / o_.gain_e_per_adu;
  double cost = !o_.axes.empty() ? MoveSeconds(o_.axes, at_, p.stage)
                                 : std::max(std::abs(p.stage.sample_deg - at_.sample_deg),
                                            std::abs(p.stage.arm_deg - at_.arm_deg)) /
                                           o_.degrees_per_s +
                                       o_.settle_s;
  at_ = p.stage;
  moved_s_ += cost;
  // The engine's ranging: each try is a frame; the last one kept is the first averaged frame.
  double t = planned_s > 0 ? planned_s : last_exposure_s_ > 0 ? last_exposure_s_ : x.initial_s;
  for (int tries = 0; tries < 12; ++tries) {
    const ExposureJudgement j = JudgeExposure(x, t, rate_e * t / o_.gain_e_per_adu, range_adu);
    if (!j.too_bright && !j.too_dim) break;
    cost += t + o_.readout_s;
    if (j.next_s == t) break;
    t = j.next_s;
  }
  last_exposure_s_ = t;
  cost += x.frames * t + (x.frames - 1) * o_.readout_s;
  // Variance of the rectangle's mean in electrons^2, per frame: each pixel's shot, dark and read
  // noise over the pixels, and the lamp's flicker, which all pixels share.
  const double signal_e = rate_e * t, dark_e = o_.dark_e_per_s * t;
  const double read2 = o_.read_noise_e * o_.read_noise_e;
  const double frame_var =
      (signal_e + dark_e + read2) / o_.pixels + std::pow(o_.flicker_rms * signal_e, 2);
  const double dark_var = (dark_e + read2) / (o_.pixels * o_.dark_frames);
  std::normal_distribution<double> normal(0, 1);
  auto dark = std::find_if(darks_.begin(), darks_.end(),
                           [&](const DarkSet& d) { return SameExposure(d.exposure_s, t); });
  if (dark == darks_.end() || spent_s_ + cost - dark->taken_s > o_.dark_max_age_s) {
    if (dark == darks_.end()) dark = darks_.insert(darks_.end(), DarkSet{.exposure_s = t});
    cost += o_.dark_frames * (t + o_.readout_s);
    dark->taken_s = spent_s_ + cost;
    dark->offset_e = std::sqrt(dark_var) * normal(rng_);
  }
  const double var_e = frame_var / x.frames + dark_var;
  const double scale = 1 / (t * o_.electrons_per_s_per_value);  // electrons -> stored value
  out.sigma = std::sqrt(var_e) * scale;
  out.value = (signal_e + std::sqrt(frame_var / x.frames) * normal(rng_) - dark->offset_e) * scale;
  out.exposure_s = t;
  out.frames = x.frames;
  out.level = signal_e / o_.full_well_e;
  out.cost_s = cost;
  spent_s_ += cost;
  return out;
}

Result<SimulatedRun> SimulateRun(const Plan& plan, const std::vector<PlannedPoint>& grid,
                                 PointSimulatorOptions options) {
  options.dark_frames = plan.darks.frames;
  options.dark_max_age_s = plan.darks.max_age_s;
  PointSimulator bench(options);
  std::vector<PlannedPoint> points = grid;
  SelectByStrategy(plan, &points);
  std::vector<Observation> seen;
  const ExposurePolicy first = CoarseExposure(plan);
  for (const PlannedPoint& p : points)
    if (!p.skipped) seen.push_back(bench.Measure(p, first));
  SimulatedRun run;
  run.first_s = bench.spent_s();
  if (plan.strategy.kind == StrategyKind::kAdaptive) {
    auto outcome =
        RunAdaptive(plan, points, seen,
                    [&](const std::vector<Choice>& batch) -> Result<std::vector<Observation>> {
                      std::vector<Observation> out;
                      // Ranging starts at the planned exposure, as the engine's does: from the
                      // previous point's, a chosen peak landed at 0.24 s where 0.42 s was planned,
                      // its dark library then lacked the planned exposure's set, and the planner,
                      // pricing that set into every peak point, turned elsewhere.
                      for (const Choice& c : batch)
                        out.push_back(bench.Measure(c.point, plan.exposure, c.exposure_s));
                      return out;
                    });
    if (!outcome.ok()) return outcome.error();
    run.fit = outcome->fit;
    run.stop = outcome->message;
    run.reached_target = outcome->stop == AdaptiveOutcome::Stop::kTarget;
    run.stopped_at_budget = outcome->stop == AdaptiveOutcome::Stop::kBudget;
    run.points = static_cast<int>(seen.size()) + outcome->chosen;
  } else {
    auto fit = FitSeen(seen, plan.specimen.eta);
    if (!fit.ok()) return fit.error();
    run.fit = *fit;
    run.points = static_cast<int>(seen.size());
  }
  run.spent_s = bench.spent_s();
  run.moved_s = bench.moved_s();
  return run;
}

PointSimulatorOptions BenchLike(const LobeForecast& lobe, const FrameNoise& noise,
                                const std::vector<devices::AxisSettings>& axes) {
  PointSimulatorOptions o;
  o.alpha = lobe.alpha;
  o.eta = lobe.eta;
  o.k = lobe.bench.scale;
  // Electrons per second per unit of value: 1 / shot, so that shot noise is the calibrated one.
  // A bench whose sigmas show no shot noise at all: photons as good as free.
  o.electrons_per_s_per_value = noise.shot > 0 ? 1 / noise.shot : 1e12;
  const double e = o.electrons_per_s_per_value;
  o.pixels = 1;
  o.read_noise_e = std::sqrt(noise.read) * e;
  o.dark_e_per_s = noise.dark * e * e;  // dark/t in value^2 is dark_e_per_s t / (e t)^2
  o.flicker_rms = std::sqrt(noise.lamp);
  o.stray_e_per_s = lobe.bench.floor * e;
  o.gain_e_per_adu = lobe.bench.adu_per_value > 0 ? e / lobe.bench.adu_per_value : 1;
  o.full_well_e = std::max(1.0, lobe.linear_limit_adu - lobe.bench.dark_adu) * o.gain_e_per_adu;
  o.readout_s = 0;
  o.axes = axes;
  return o;
}

std::string AdaptiveForecast::Describe() const {
  char text[160];
  std::snprintf(text, sizeof text,
                "adaptive: %d simulated runs: %.0f s (10-90 %%: %.0f-%.0f s), the target reached "
                "in %d of %d",
                runs, median_s, low_s, high_s, reached, runs);
  std::string out = text;
  if (failed > 0) out += ", " + std::to_string(failed) + " failed";
  // Said before the run, not found out after it: the runs that fall short, why, how far, and
  // what would help (a planner that runs out of candidates needs a finer grid, not more time).
  if (at_budget + exhausted > 0) {
    std::string why;
    if (at_budget > 0) why += std::to_string(at_budget) + " stopped at the budget";
    if (exhausted > 0) {
      if (!why.empty()) why += " and ";
      why += std::to_string(exhausted) + " ran out of candidates";
    }
    std::snprintf(text, sizeof text,
                  " at sigma(alpha)/alpha %.2g (the target %.2g): ", short_median_rel, target);
    why += text;
    if (at_budget > 0) why += "a larger budget_s";
    if (at_budget > 0 && exhausted > 0) why += "; ";
    if (exhausted > 0) why += "a finer view_step_deg or more incidences to choose from";
    out += "; " + why;
  }
  return out;
}

Result<AdaptiveForecast> ForecastAdaptive(const Plan& plan, std::vector<PlannedPoint> points,
                                          const PointSimulatorOptions& like, int runs) {
  for (PlannedPoint& p : points)
    if (p.skipped && p.reason == kCandidateReason) p.skipped = false, p.reason.clear();
  AdaptiveForecast f;
  std::vector<double> times, exposures, short_rel;
  std::string first_error;
  for (int r = 1; r <= runs; ++r) {
    PointSimulatorOptions o = like;
    o.seed = static_cast<std::uint64_t>(r);
    auto run = SimulateRun(plan, points, o);
    ++f.runs;
    if (!run.ok() || run->fit.status == fitting::FitStatus::kFailed) {
      ++f.failed;
      if (first_error.empty()) first_error = run.ok() ? run->fit.message : run.error().message;
      continue;
    }
    times.push_back(run->spent_s);
    exposures.push_back(run->spent_s - run->moved_s);
    if (run->reached_target) {
      ++f.reached;
    } else if (plan.strategy.kind == StrategyKind::kAdaptive) {
      ++(run->stopped_at_budget ? f.at_budget : f.exhausted);
      short_rel.push_back(run->fit.width.sigma / run->fit.width.value);
    }
  }
  if (times.empty())
    return Error{ErrorCode::kFailedPrecondition,
                 "every simulated run failed; the first: " + first_error};
  // Quantiles interpolated between order statistics.
  auto at = [](std::vector<double> v, double q) {
    std::sort(v.begin(), v.end());
    const double x = q * static_cast<double>(v.size() - 1);
    const auto i = static_cast<std::size_t>(x);
    const double w = x - static_cast<double>(i);
    return i + 1 < v.size() ? v[i] * (1 - w) + v[i + 1] * w : v[i];
  };
  f.median_s = at(times, 0.5), f.low_s = at(times, 0.1), f.high_s = at(times, 0.9);
  f.exposure_median_s = at(exposures, 0.5);
  f.target = plan.strategy.target_rel_sigma_alpha;
  if (!short_rel.empty()) f.short_median_rel = at(short_rel, 0.5);
  return f;
}

}  // namespace gonio::acquisition
