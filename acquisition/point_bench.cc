#include "acquisition/point_bench.h"

#include <algorithm>
#include <cmath>

#include "acquisition/exposure.h"

namespace gonio::acquisition {

double PointBench::Truth(const PlannedPoint& p) const {
  const Provisional truth{o_.alpha, o_.k, o_.stray_e_per_s / o_.electrons_per_s_per_value, o_.eta};
  return truth.Value(p);
}

Observation PointBench::Measure(const PlannedPoint& p, const ExposurePolicy& x, double planned_s) {
  Observation out;
  out.point = p;
  const double rate_e = Truth(p) * o_.electrons_per_s_per_value;  // per pixel
  const double range_adu = o_.full_well_e / o_.gain_e_per_adu;
  double cost =
      std::max(std::abs(p.stage.sample_deg - sample_deg_), std::abs(p.stage.arm_deg - arm_deg_)) /
          o_.degrees_per_s +
      o_.settle_s;
  sample_deg_ = p.stage.sample_deg, arm_deg_ = p.stage.arm_deg;
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
  auto dark =
      std::find_if(darks_.begin(), darks_.end(), [&](const auto& d) { return d.first == t; });
  if (dark == darks_.end() || spent_s_ + cost - dark->second > o_.dark_max_age_s) {
    if (dark == darks_.end()) dark = darks_.insert(darks_.end(), {t, 0});
    cost += o_.dark_frames * (t + o_.readout_s);
    dark->second = spent_s_ + cost;
  }
  // Variance of the rectangle's mean in electrons^2, per frame: each pixel's shot, dark and read
  // noise over the pixels, and the lamp's flicker, which all pixels share.
  const double signal_e = rate_e * t, dark_e = o_.dark_e_per_s * t;
  const double read2 = o_.read_noise_e * o_.read_noise_e;
  const double frame_var =
      (signal_e + dark_e + read2) / o_.pixels + std::pow(o_.flicker_rms * signal_e, 2);
  const double dark_var = (dark_e + read2) / (o_.pixels * o_.dark_frames);
  const double var_e = frame_var / x.frames + dark_var;
  const double scale = 1 / (t * o_.electrons_per_s_per_value);  // electrons -> stored value
  std::normal_distribution<double> normal(0, 1);
  out.sigma = std::sqrt(var_e) * scale;
  out.value = signal_e * scale + out.sigma * normal(rng_);
  out.exposure_s = t;
  out.frames = x.frames;
  out.level = signal_e / o_.full_well_e;
  out.cost_s = cost;
  spent_s_ += cost;
  return out;
}

Result<SimulatedRun> SimulateRun(const Plan& plan, const std::vector<PlannedPoint>& grid,
                                 PointBenchOptions options) {
  options.dark_frames = plan.darks.frames;
  options.dark_max_age_s = plan.darks.max_age_s;
  PointBench bench(options);
  std::vector<PlannedPoint> points = grid;
  SelectByStrategy(plan, &points);
  std::vector<Observation> seen;
  const ExposurePolicy first = CoarseExposure(plan);
  for (const PlannedPoint& p : points)
    if (!p.skipped) seen.push_back(bench.Measure(p, first));
  SimulatedRun run;
  run.first_s = bench.spent_s();
  if (plan.strategy.kind == "adaptive") {
    auto outcome =
        RunAdaptive(plan, points, seen,
                    [&](const std::vector<Choice>& batch) -> Result<std::vector<Observation>> {
                      std::vector<Observation> out;
                      for (const Choice& c : batch)
                        out.push_back(bench.Measure(c.point, plan.exposure));
                      return out;
                    });
    if (!outcome.ok()) return outcome.error();
    run.fit = outcome->fit;
    run.stop = outcome->message;
    run.points = static_cast<int>(seen.size()) + outcome->chosen;
  } else {
    auto fit = FitSeen(seen, plan.specimen.eta);
    if (!fit.ok()) return fit.error();
    run.fit = *fit;
    run.points = static_cast<int>(seen.size());
  }
  run.spent_s = bench.spent_s();
  return run;
}

}  // namespace gonio::acquisition
