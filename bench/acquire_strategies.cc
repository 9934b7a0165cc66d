// Bench time against alpha error for the acquisition strategies (issue #17; docs/acquisition.md):
// uniform grids, the lobe strategy on the same grids, and adaptive runs at budgets that are
// fractions of the finest uniform grid's bench time, on ground, etched and antiglare glass, each
// over `repeats` simulated runs (acquisition/point_simulator.h: the instrument at the level of its
// points). Prints a Markdown table and writes JSON for bench/plot_acquire.py.
//
// Usage: acquire_strategies [REPEATS=20] [OUT.json]
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "acquisition/exposure.h"
#include "acquisition/plan.h"
#include "acquisition/point_simulator.h"
#include "acquisition/strategy.h"

namespace {

using namespace gonio::acquisition;

struct Case {
  const char* name;
  double alpha;
  double half_range_deg;          // views about the refracted direction
  std::vector<double> steps_deg;  // coarsest first; the last is the reference grid
};

double Quantile(std::vector<double> v, double q) {
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<std::size_t>(q * static_cast<double>(v.size())))];
}

struct Row {
  std::string specimen, strategy, setting;
  double time_median_s = 0, error_median = 0, error_p90 = 0, coverage = 0, points = 0;
  double rel_sigma_median = 0;
  double worst_overrun = 0;  // adaptive: the largest bench time over budget, as a fraction
  int failed = 0, runs = 0;
};

Plan PlanFor(const Case& c, double step, StrategyKind kind) {
  Plan p;
  p.specimen.name = c.name;
  p.specimen.eta = 1.51;
  p.specimen.expected_alpha = c.alpha;
  p.incidence_deg = {0, 30, 60, 80};
  p.azimuth_deg = {0};
  p.view_about = ViewAbout::kRefracted;
  p.view_from_deg = -c.half_range_deg;
  p.view_to_deg = c.half_range_deg;
  p.view_step_deg = step;
  p.exposure.frames = 4;
  p.exposure.initial_s = 0.05;
  p.exposure.max_s = 20;
  p.exposure.floor = 0.005;
  p.strategy.kind = kind;
  return p;
}

Row Measure(const Case& c, const Plan& plan, const std::string& setting, int repeats) {
  const PlanContext context;
  const std::vector<PlannedPoint> grid = ExpandGrid(plan, context);
  Row row{c.name, ToString(plan.strategy.kind), setting};
  std::vector<double> times, errors, points, rel;
  int covered = 0;
  for (int r = 0; r < repeats; ++r) {
    PointSimulatorOptions o;
    o.alpha = c.alpha;
    o.seed = 1000 + static_cast<std::uint64_t>(r);
    auto run = SimulateRun(plan, grid, o);
    ++row.runs;
    if (!run.ok() || run->fit.status == gonio::fitting::FitStatus::kFailed) {
      if (row.failed == 0)  // the first failure of the row, so that a pattern is seen
        std::fprintf(stderr, "%s %s %s: %s\n", c.name, ToString(plan.strategy.kind),
                     setting.c_str(),
                     run.ok() ? run->fit.message.c_str() : run.error().message.c_str());
      ++row.failed;
      continue;
    }
    if (r == 0 && !run->stop.empty())
      std::fprintf(stderr, "%s %s: coarse scan %.0f s; %s\n", c.name, setting.c_str(), run->first_s,
                   run->stop.c_str());
    const double a = run->fit.width.value, s = run->fit.width.sigma;
    times.push_back(run->spent_s);
    if (plan.strategy.budget_s > 0)
      row.worst_overrun = std::max(row.worst_overrun, run->spent_s / plan.strategy.budget_s - 1);
    errors.push_back(std::abs(a / c.alpha - 1));
    rel.push_back(s / a);
    points.push_back(run->points);
    if (std::abs(a - c.alpha) <= 2 * s) ++covered;
  }
  if (times.empty()) return row;
  row.time_median_s = Quantile(times, 0.5);
  row.error_median = Quantile(errors, 0.5);
  row.error_p90 = Quantile(errors, 0.9);
  row.rel_sigma_median = Quantile(rel, 0.5);
  row.points = Quantile(points, 0.5);
  row.coverage = static_cast<double>(covered) / static_cast<double>(times.size());
  return row;
}

// The estimate before a specimen's first adaptive run against its runs (docs/acquisition.md, "The
// time to a target"): the bench calibrated on a uniform 2 deg run of `other` (its fit's k and
// floor, its points' sigmas), `c`'s catalogue lobe, the plan simulated to `target`
// (ForecastAdaptive); then `repeats` runs of it on the true bench. No readout on either side:
// the instrument's stored bench time has none.
struct ForecastRow {
  std::string specimen, calibrated_on;
  double target = 0, forecast_s = 0, low_s = 0, high_s = 0, actual_s = 0, actual_low_s = 0,
         actual_high_s = 0;
  int reached = 0, runs = 0;
};

ForecastRow Forecast(const Case& c, const Case& other, double target, int repeats) {
  ForecastRow row{c.name, other.name, target};
  PointSimulatorOptions truth;
  truth.readout_s = 0;
  truth.alpha = other.alpha;
  truth.seed = 77;
  const Plan first = PlanFor(other, 2, StrategyKind::kUniform);
  PointSimulator bench(truth);
  std::vector<Observation> seen;
  for (const PlannedPoint& p : ExpandGrid(first, PlanContext{}))
    if (!p.skipped) seen.push_back(bench.Measure(p, first.exposure));
  auto fit = FitSeen(seen, 1.51);
  auto noise = CalibrateFrameNoise(seen);
  if (!fit.ok() || !noise.ok()) {
    std::fprintf(stderr, "forecast %s: the calibration failed: %s\n", c.name,
                 !fit.ok() ? fit.error().message.c_str() : noise.error().message.c_str());
    return row;
  }
  Throughput t;
  t.scale = fit->scale.value;
  t.floor = fit->floor.value;
  t.adu_per_value = truth.electrons_per_s_per_value / truth.gain_e_per_adu;
  t.noise = *noise;
  const LobeForecast lobe{t, c.alpha, 1.51, truth.full_well_e / truth.gain_e_per_adu, 12};
  Plan plan = PlanFor(c, c.steps_deg.back(), StrategyKind::kAdaptive);
  plan.strategy.budget_s = 1e6;
  plan.strategy.target_rel_sigma_alpha = target;
  const std::vector<PlannedPoint> grid = ExpandGrid(plan, PlanContext{});
  auto f = ForecastAdaptive(plan, grid, BenchLike(lobe, *noise, {}), 20);
  if (!f.ok()) {
    std::fprintf(stderr, "forecast %s: %s\n", c.name, f.error().message.c_str());
    return row;
  }
  row.forecast_s = f->median_s, row.low_s = f->low_s, row.high_s = f->high_s;
  truth.alpha = c.alpha;
  std::vector<double> times;
  for (int r = 0; r < repeats; ++r) {
    truth.seed = 5000 + static_cast<std::uint64_t>(r);
    auto run = SimulateRun(plan, grid, truth);
    ++row.runs;
    if (!run.ok()) continue;
    times.push_back(run->spent_s);
    row.reached += run->reached_target;
  }
  if (times.empty()) return row;
  row.actual_s = Quantile(times, 0.5);
  row.actual_low_s = Quantile(times, 0.1);
  row.actual_high_s = Quantile(times, 0.9);
  return row;
}

}  // namespace

int main(int argc, char** argv) {
  const int repeats = argc > 1 ? std::max(1, std::atoi(argv[1])) : 20;
  const std::string out_path = argc > 2 ? argv[2] : "";
  // Ground and etched on the 1 deg reference grid; antiglare's lobe is about 1 deg wide,
  // so its reference grid is 0.1 deg (on a 1 deg grid one point or two fall inside it).
  const std::vector<Case> cases = {{"ground (alpha 0.344)", 0.344, 40, {4, 2, 1}},
                                   {"etched (alpha 0.493)", 0.493, 50, {4, 2, 1}},
                                   {"antiglare (alpha 0.023)", 0.023, 4, {0.4, 0.2, 0.1}}};
  std::vector<Row> rows;
  for (const Case& c : cases) {
    double reference_s = 0;
    for (double step : c.steps_deg) {
      char setting[32];
      std::snprintf(setting, sizeof setting, "%g deg grid", step);
      rows.push_back(Measure(c, PlanFor(c, step, StrategyKind::kUniform), setting, repeats));
      reference_s = rows.back().time_median_s;
      std::fprintf(stderr, "%s %s uniform: %.0f s\n", c.name, setting, reference_s);
      rows.push_back(Measure(c, PlanFor(c, step, StrategyKind::kLobe), setting, repeats));
    }
    for (double fraction : {1.0 / 32, 1.0 / 16, 1.0 / 8, 1.0 / 4}) {
      Plan p = PlanFor(c, c.steps_deg.back(), StrategyKind::kAdaptive);
      p.strategy.budget_s = fraction * reference_s;
      char setting[64];
      std::snprintf(setting, sizeof setting, "budget 1/%.0f of the reference", 1 / fraction);
      rows.push_back(Measure(c, p, setting, repeats));
      std::fprintf(stderr, "%s adaptive %s: the largest overrun of the budget %+.1f %%\n", c.name,
                   setting, 100 * rows.back().worst_overrun);
    }
  }
  std::printf(
      "Bench time against alpha error, %d simulated runs per row "
      "(acquisition/point_simulator.h)\n\n",
      repeats);
  std::printf(
      "| specimen | strategy | setting | points | bench time (median) | |alpha error| median | "
      "90th pct | median sigma/alpha | 2 sigma covers truth | failed |\n"
      "|---|---|---|---|---|---|---|---|---|---|\n");
  nlohmann::json json = nlohmann::json::array();
  for (const Row& r : rows) {
    std::printf(
        "| %s | %s | %s | %.0f | %.2f h | %.3g %% | %.3g %% | %.3g %% | %.0f %% | %d/%d |\n",
        r.specimen.c_str(), r.strategy.c_str(), r.setting.c_str(), r.points, r.time_median_s / 3600,
        100 * r.error_median, 100 * r.error_p90, 100 * r.rel_sigma_median, 100 * r.coverage,
        r.failed, r.runs);
    json.push_back({{"specimen", r.specimen},
                    {"strategy", r.strategy},
                    {"setting", r.setting},
                    {"points", r.points},
                    {"time_s", r.time_median_s},
                    {"error_median", r.error_median},
                    {"error_p90", r.error_p90},
                    {"coverage", r.coverage},
                    {"failed", r.failed}});
  }
  std::printf(
      "\nThe estimate before the first adaptive run (a target, no budget in reach) against %d "
      "runs\n\n| specimen | calibrated on | target sigma(alpha)/alpha | estimate (10-90 %%) | "
      "actual median (10-90 %%) | estimate / actual | reached |\n"
      "|---|---|---|---|---|---|---|\n",
      repeats);
  const double targets[] = {2e-5, 2e-5, 5e-6};
  for (std::size_t k = 0; k < cases.size(); ++k) {
    const Case& other = cases[k == 1 ? 0 : 1];  // etched calibrates ground and antiglare
    const ForecastRow f = Forecast(cases[k], other, targets[k], repeats);
    std::printf("| %s | %s | %.0e | %.0f s (%.0f-%.0f) | %.0f s (%.0f-%.0f) | %.2f | %d/%d |\n",
                f.specimen.c_str(), f.calibrated_on.c_str(), f.target, f.forecast_s, f.low_s,
                f.high_s, f.actual_s, f.actual_low_s, f.actual_high_s,
                f.actual_s > 0 ? f.forecast_s / f.actual_s : 0.0, f.reached, f.runs);
    json.push_back({{"specimen", f.specimen},
                    {"strategy", "forecast"},
                    {"target", f.target},
                    {"forecast_s", f.forecast_s},
                    {"actual_s", f.actual_s}});
  }
  if (!out_path.empty()) std::ofstream(out_path) << json.dump(1) << "\n";
  return 0;
}
