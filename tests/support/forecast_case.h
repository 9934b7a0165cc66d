// The estimate-before-the-first-run case (issue #17) on the simulated instrument, shared by its
// test (tests/acquisition/engine_sim_test.cc) and the forecast's spread against real runs
// (bench/forecast_spread.cc): a catalogue of the etched and the ground glass, the demo's geometry
// made coarser (0 and 45 degrees, the lobe and its tails), a run measured the way goniod does it
// (its estimate stored when it is created), and the etched glass's run fitted into the bench's
// throughput (Storage::LatestThroughput).
#pragma once

#include <atomic>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <utility>
#include <vector>

#include "acquisition/engine.h"
#include "acquisition/exposure.h"
#include "acquisition/plan.h"
#include "acquisition/storage.h"
#include "fitting/fitter.h"
#include "tests/support/run_resuming.h"
#include "tests/support/sim_instrument.h"

namespace gonio::testing {

inline std::vector<acquisition::Specimen> ForecastCatalogue() {
  return {{"etched-glass-E1", "glass", 6, 1.51, 0.493},
          {"ground-glass-G1", "glass", 6, 1.51, 0.344}};
}

// The plan for `specimen` with `strategy` (a [strategy] table, or "") appended; the plan file is
// written beside `scratch` and removed. Fails (kInvalidArgument) as LoadPlan does.
inline Result<std::pair<acquisition::Plan, std::vector<acquisition::PlannedPoint>>> ForecastPlan(
    const std::string& scratch, const std::string& specimen,
    const std::vector<devices::AxisSettings>& axes, const std::string& strategy = "") {
  const std::string path = scratch + ".plan.toml";
  std::ofstream(path) << "sample = \"" << specimen << "\"\n[geometry]\nincidence_deg = [0, 45]\n"
                      << "view_about = \"refracted\"\nview_from_deg = -50\nview_to_deg = 50\n"
                      << "view_step_deg = 5\n[exposure]\nframes = 3\ninitial_s = 0.05\n"
                      << "max_s = 20\n[rectangle]\nx = 253\ny = 246\nwidth = 6\nheight = 19\n"
                      // The engine ages darks by the wall clock, which the simulated bench's
                      // runs 300 times slower than its own: no dark expires in a run.
                      << "[darks]\nmax_age_s = 100000\n"
                      << strategy;
  acquisition::PlanContext ctx;
  ctx.specimens = ForecastCatalogue();
  ctx.axes = axes;
  ctx.image_width = ctx.image_height = 512;
  auto plan = acquisition::LoadPlan(path, ctx);
  std::filesystem::remove(path);
  if (!plan.ok()) return plan.error();
  auto points = acquisition::ExpandPoints(*plan, ctx);
  return std::make_pair(std::move(*plan), std::move(points));
}

struct MeasuredRun {
  std::int64_t run = 0;
  double exposure_s = 0;  // the engine's count: frames, ranging tries, darks
  acquisition::EngineStats stats;
};

// Measures `points` as goniod does: the estimate is made and stored when the run is created, and
// a device fault pauses the run, which is resumed (RunResuming).
inline Result<MeasuredRun> MeasureAsGoniod(acquisition::Storage& store, SimInstrument& inst,
                                           const acquisition::Plan& plan,
                                           const std::vector<acquisition::PlannedPoint>& points,
                                           const acquisition::EngineOptions& options) {
  auto estimate = acquisition::EstimateRun(store, plan, points, inst.axes, options.linear_limit_adu,
                                           options.max_ranging_tries);
  if (!estimate.ok()) return estimate.error();
  auto sp = store.EnsureSpecimen(plan.specimen);
  if (!sp.ok()) return sp.error();
  auto cfg = store.StoreConfig("test");
  if (!cfg.ok()) return cfg.error();
  auto run = store.CreateRun(*sp, *cfg, plan.text, points);
  if (!run.ok()) return run.error();
  if (Status st = store.SetRunEstimate(*run, *estimate); !st.ok()) return st.error();
  acquisition::Engine engine(*inst.stages, *inst.camera, inst.meter, store, options);
  std::atomic<bool> stop{false};
  if (Status st = RunResuming(engine, *run, plan, stop); !st.ok()) return st.error();
  return MeasuredRun{*run, engine.stats().exposure_s, engine.stats()};
}

// The etched glass measured on `inst` (which must show it, alpha 0.493) with the uniform plan and
// fitted with a floor, as goniod fits it: the finished run with a chosen fit that gives the
// bench's throughput and its noise calibration.
inline Result<MeasuredRun> MeasureThroughputRun(acquisition::Storage& store, SimInstrument& inst,
                                                const std::string& scratch,
                                                const acquisition::EngineOptions& options) {
  auto planned = ForecastPlan(scratch, "etched-glass-E1", inst.axes);
  if (!planned.ok()) return planned.error();
  auto measured = MeasureAsGoniod(store, inst, planned->first, planned->second, options);
  if (!measured.ok()) return measured.error();
  auto rows = store.Measurements(measured->run);
  if (!rows.ok()) return rows.error();
  std::vector<fitting::Sample> samples;
  for (const acquisition::MeasurementRow& r : *rows)
    samples.push_back(fitting::SampleFromBenchAngles(r.point.theta_l_deg, 0, r.point.theta_v_deg, 0,
                                                     r.m.value, r.m.sigma));
  fitting::FitOptions fo;
  fo.eta = 1.51;
  fo.floor = fitting::Floor::kAuto;  // the lens's stray light, as goniod fits it
  auto fit = fitting::Fit(fitting::WithSystematic(samples, 0.02), fo);
  if (!fit.ok()) return fit.error();
  const std::string params = "{\"scale\": " + std::to_string(fit->scale.value) +
                             ", \"width\": " + std::to_string(fit->width.value) +
                             ", \"floor\": " + std::to_string(fit->floor.value) +
                             ", \"chosen\": true}";
  if (auto id = store.StoreFitResult(measured->run, "beckmann", params, "{}"); !id.ok())
    return id.error();
  return measured;
}

// The adaptive strategy's table for the ground glass: a target the run reaches well inside its
// budget.
inline constexpr const char* kForecastAdaptive =
    "[strategy]\nkind = \"adaptive\"\nbudget_s = 20000\ntarget_rel_sigma_alpha = 5e-5\n";

}  // namespace gonio::testing
