// The instrument at the level of its stored points, for studies of strategies:
// bench/acquire_strategies charts bench time against alpha error over hundreds of simulated runs,
// which the image-level simulator (sim/, a few seconds per point) cannot afford. Model no more
// than the question needs: where a run spends its time and what each point's value and sigma are.
//
// What it keeps of the bench (sim/ defaults: sim/camera/sensor.h, sim/scene/scene.h):
//   - the signal: electrons_per_s_per_value x (k f |cos theta_l|) per pixel (Beckmann), plus the
//     stray light, in every one of the rectangle's `pixels`;
//   - the engine's ranging (JudgeExposure on the rectangle's mean, from the previous point's
//     exposure), its frames, and a dark set at each exposure not taken before;
//   - the noise: shot, read and dark noise per pixel averaged over the rectangle and the frames,
//     the lamp's flicker common to the rectangle, and the dark's own noise, one draw per dark set
//     shared by every point subtracted with it (the coarse scan's tails share one, and whether
//     the floor looks worth measuring turns on it);
//   - moves at the stages' speed (the largest axis move) plus settling, and each frame's readout
//     but the last (read out during the next move).
// What it leaves out: images, the rectangle's spread of directions and the apertures (the point
// model: the strategies compare where time goes, not the measurement equation), saturation
// beyond the ranging (it ranges below full well), dark drift, faults. The sigma it reports is
// the true one: the engine's budget was shown honest on the image-level simulator (#16).
#pragma once

#include <cstdint>
#include <random>

#include "acquisition/exposure.h"
#include "acquisition/plan.h"
#include "acquisition/strategy.h"

namespace gonio::acquisition {

struct PointSimulatorOptions {
  double alpha = 0.344, eta = 1.51, k = 1.0;  // the specimen's truth (Beckmann)
  double electrons_per_s_per_value = 1000;    // per pixel, per unit of stored value
  double stray_e_per_s = 2.0;                 // per pixel
  double gain_e_per_adu = 1.5, read_noise_e = 8, dark_e_per_s = 0.5;
  double full_well_e = 60000;
  int pixels = 114;  // the demo's 6 x 19 rectangle
  double flicker_rms = 0.002;
  int dark_frames = 4;
  double dark_max_age_s = 600;  // a dark set older than this (bench seconds) is taken again
  double degrees_per_s = 10, settle_s = 0.1;
  // When given, moves are priced as the instrument prices them (MoveSeconds at these axes'
  // speeds and accelerations) instead of by degrees_per_s and settle_s.
  std::vector<devices::AxisSettings> axes;
  // A frame's readout (512 x 512 at 1 MHz): each ranging try and averaged frame waits for it,
  // except the point's last, which reads out while the stages move on (the engine's overlap).
  double readout_s = 0.262;
  std::uint64_t seed = 1;
};

class PointSimulator {
 public:
  explicit PointSimulator(PointSimulatorOptions o) : o_(o), rng_(o.seed) {}

  // Measures one point as the engine would under `exposure`: its value, sigma, final exposure and
  // the bench seconds it took (ranging tries, frames, a dark set at a new exposure, the move).
  // Ranging starts at `planned_s` when given (> 0), else at the previous point's exposure.
  Observation Measure(const PlannedPoint& p, const ExposurePolicy& exposure, double planned_s = 0);
  // The expected stored value (no noise): k f |cos theta_l| + stray / electrons_per_s_per_value.
  double Truth(const PlannedPoint& p) const;
  double spent_s() const { return spent_s_; }
  double moved_s() const { return moved_s_; }  // of which moves and settling

 private:
  PointSimulatorOptions o_;
  std::mt19937_64 rng_;
  double last_exposure_s_ = 0;
  StageTargets at_;
  // A dark set: its exposure, the bench second it was taken at, and its error (electrons, in
  // the rectangle's mean), which every point subtracted with it shares.
  struct DarkSet {
    double exposure_s = 0, taken_s = 0, offset_e = 0;
  };
  std::vector<DarkSet> darks_;
  double spent_s_ = 0, moved_s_ = 0;
};

// One run of `plan` on a point simulator: the grid's points its strategy selects
// (SelectByStrategy), measured in order, then for an adaptive plan its choices (RunAdaptive), and
// the fit of it all (FitSeen). The plan's darks policy replaces the options'.
struct SimulatedRun {
  fitting::FitSummary fit;
  double spent_s = 0;
  double moved_s = 0;  // of which moves
  double first_s = 0;  // of which the points the strategy selected first (adaptive: coarse scan)
  int points = 0;
  std::string stop;                // an adaptive run's outcome; empty otherwise
  bool reached_target = false;     // an adaptive run that stopped at its target
  bool stopped_at_budget = false;  // ... or at its budget (neither: it ran out of candidates)
};
Result<SimulatedRun> SimulateRun(const Plan& plan, const std::vector<PlannedPoint>& grid,
                                 PointSimulatorOptions options);

}  // namespace gonio::acquisition

namespace gonio::acquisition {

// A point simulator that stands for a measured bench (the estimate before a run): the
// specimen's expected lobe at the bench's throughput (`lobe`: its k, floor, counts per value, dark
// level and linear range) and the bench's noise per frame (`noise`, CalibrateFrameNoise on that
// run's points). The rectangle is one "pixel" whose electrons per second per value is 1 / shot,
// so that shot noise, read noise (read) and the lamp (lamp) come out as calibrated; moves as the
// instrument prices them at `axes`; no readout (the stored bench time has none).
PointSimulatorOptions BenchLike(const LobeForecast& lobe, const FrameNoise& noise,
                                const std::vector<devices::AxisSettings>& axes);

// What an adaptive plan is expected to cost before it is run: `runs` simulated runs on `like`
// (seeds 1..runs: the same inputs give the same forecast), each to its target or its budget.
struct AdaptiveForecast {
  int runs = 0, reached = 0, failed = 0;       // failed: the simulated run's fit failed
  int at_budget = 0, exhausted = 0;            // the runs that stopped short of the target, by why
  double median_s = 0, low_s = 0, high_s = 0;  // bench seconds: median, 10th and 90th percentile
  double exposure_median_s = 0;                // of the time without moves
  double target = 0;                           // the plan's sigma(alpha)/alpha (0: none)
  double short_median_rel = 0;  // sigma(alpha)/alpha where the short runs stopped (median)
  // "adaptive: 20 simulated runs: 2410 s (10-90 %: 2100-2900 s), the target reached in 18 of 20;
  // 2 stopped at the budget at sigma(alpha)/alpha 2.4e-05 (the target 2e-05): a larger budget_s"
  std::string Describe() const;
};
// `points`: the plan's grid, or its points as ExpandPoints marked them (the candidates are
// restored to the grid). An error if every run failed.
Result<AdaptiveForecast> ForecastAdaptive(const Plan& plan, std::vector<PlannedPoint> points,
                                          const PointSimulatorOptions& like, int runs = 20);

}  // namespace gonio::acquisition
