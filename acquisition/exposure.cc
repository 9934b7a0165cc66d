#include "acquisition/exposure.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "acquisition/point_simulator.h"
#include "acquisition/strategy.h"
#include "fitting/model.h"
#include "fitting/sample.h"

namespace gonio::acquisition {

double OnLadder(double t) { return std::pow(10.0, std::floor(8 * std::log10(t) + 1e-9) / 8); }

std::int64_t ExposureKey(double t) { return std::llround(t * 1e6); }

bool SameExposure(double a, double b) { return std::abs(a - b) <= 1e-3 * std::max(a, b); }

ExposureJudgement JudgeExposure(const ExposurePolicy& x, double t, double peak_adu,
                                double range_adu) {
  ExposureJudgement j;
  j.too_bright = peak_adu >= x.saturation * range_adu;
  // Dim: below a quarter of the target (counts are cheap while exposures are short), or below
  // the floor; at max_s there is nothing more to gain.
  j.too_dim =
      !j.too_bright && peak_adu < std::max(x.floor, 0.25 * x.target) * range_adu && t < x.max_s;
  const double goal = x.target * range_adu / std::max(peak_adu, 1.0);
  // Saturated pixels hide how bright the peak is: cut hard. Otherwise scale to the target, at
  // most x100 per step.
  const double next = j.too_bright ? t * std::min(0.25, goal) : t * std::min(goal, 100.0);
  j.next_s = std::clamp(OnLadder(next), x.min_s, x.max_s);
  return j;
}

double LobeForecast::Rate(const PlannedPoint& p) const {
  if (p.reflection) return 0;
  const fitting::Sample s =
      fitting::SampleFromBenchAngles(p.theta_l_deg, p.phi_deg, p.theta_v_deg, p.phi_deg, 0, 1);
  const double f =
      fitting::ModelBtdf(fitting::ModelSpec{}, s.light, s.view, alpha, eta) * std::abs(s.light.z);
  return std::max(0.0, bench.adu_per_value * (bench.scale * f + bench.floor));
}

Throughput ThroughputOf(const config::ThroughputConfig& c) {
  Throughput t;
  t.run = 0;
  t.scale = c.scale;
  t.floor = c.floor;
  t.adu_per_value = c.adu_per_value;
  t.dark_adu = c.dark_adu;
  if (c.noise_shot > 0 || c.noise_read > 0 || c.noise_lamp > 0 || c.noise_dark > 0)
    t.noise = FrameNoise{c.noise_shot, c.noise_read, c.noise_lamp, c.noise_dark};
  return t;
}

std::optional<LobeForecast> ForecastFor(const Specimen& specimen,
                                        const std::optional<Throughput>& bench,
                                        double linear_limit_adu, int max_ranging_tries) {
  if (!bench || !specimen.expected_alpha) return std::nullopt;
  return LobeForecast{*bench, *specimen.expected_alpha, specimen.eta, linear_limit_adu,
                      max_ranging_tries};
}

std::string DescribeEstimateBasis(const ExposureHistory* history, const LobeForecast* forecast) {
  if (history != nullptr) return "run " + std::to_string(history->run) + "'s exposures";
  if (forecast != nullptr) {
    char alpha[32];
    std::snprintf(alpha, sizeof alpha, "%.3g", forecast->alpha);
    const std::string at = forecast->bench.run > 0
                               ? "run " + std::to_string(forecast->bench.run) + "'s throughput"
                               : "the configured throughput";
    return std::string("the expected lobe (Beckmann alpha ") + alpha + ") at " + at;
  }
  return "the plan's initial exposure";
}

namespace {

// Why a plan's exposures cannot be priced: what is missing, and what would supply it.
std::string NotPricedBecause(const Plan& plan, const std::optional<Throughput>& bench) {
  if (!bench)
    return "exposures not priced: this database has no finished run with a fit to measure the "
           "bench's throughput on, and the instrument config has no [throughput] "
           "(docs/operator.md); motion only";
  return "exposures not priced: no earlier run of specimen '" + plan.specimen.name +
         "', and the catalogue gives it no expected_alpha to forecast its lobe from; motion only";
}

}  // namespace

RunEstimate EstimateOn(const Plan& plan, const std::vector<PlannedPoint>& points,
                       const std::vector<devices::AxisSettings>& axes, const ExposureHistory* seen,
                       const std::optional<Throughput>& bench, double linear_limit_adu,
                       int max_ranging_tries) {
  const bool adaptive = plan.strategy.kind == StrategyKind::kAdaptive;
  const std::optional<LobeForecast> forecast =
      ForecastFor(plan.specimen, bench, linear_limit_adu, max_ranging_tries);
  RunEstimate e;
  // An adaptive plan on a bench whose noise is known: its runs simulated on a point simulator like
  // it, to the target or the budget; the median, with the range in the basis.
  if (adaptive && forecast && forecast->bench.noise) {
    auto runs = ForecastAdaptive(plan, points, BenchLike(*forecast, *forecast->bench.noise, axes));
    if (runs.ok()) {
      e.total_s = runs->median_s;
      e.exposure_s = runs->exposure_median_s;
      e.basis = DescribeEstimateBasis(nullptr, &*forecast) + "; " + runs->Describe();
      return e;
    }
  }
  const LobeForecast* f = seen == nullptr && forecast ? &*forecast : nullptr;
  EstimateParts parts;
  // An adaptive plan's points are its coarse scan, exposed short; what it chooses after is
  // bounded by its budget (which counts the coarse scan too).
  Plan priced = plan;
  priced.exposure = CoarseExposure(plan);
  e.total_s = EstimateSeconds(priced, points, axes, priced.exposure.initial_s, seen, f, &parts);
  e.exposure_s = parts.exposure_s;
  e.basis = DescribeEstimateBasis(seen, f);
  if (seen == nullptr && f == nullptr && !adaptive) {
    // The plan's first exposure is where ranging starts, not what the points take.
    e.priced = false;
    e.total_s = parts.motion_s;
    e.exposure_s = 0;
    e.basis = NotPricedBecause(plan, bench);
    return e;
  }
  if (adaptive && plan.strategy.budget_s > e.total_s) {
    char text[96];
    std::snprintf(text, sizeof text, "; adaptive: a %.0f s coarse scan, then at most its budget",
                  e.total_s);
    e.basis += text;
    e.exposure_s += plan.strategy.budget_s - e.total_s;
    e.total_s = plan.strategy.budget_s;
  }
  return e;
}

}  // namespace gonio::acquisition
