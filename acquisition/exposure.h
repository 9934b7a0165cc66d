// Auto-ranging and what a point's exposure will be before it is measured.
//
// The engine ranges each point's exposure on its frames: JudgeExposure says whether a try is
// kept or which exposure comes next. Before a run, the same rule is played on a forecast of each
// point's brightness: the specimen's expected lobe (Beckmann at the catalogue's width) times
// the bench's throughput, measured on an earlier run of any specimen. So the estimate of a plan
// never measured on this specimen prices its points at the exposures the engine will choose,
// not at the plan's first try.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "acquisition/plan.h"
#include "config/instrument_config.h"

namespace gonio::acquisition {

// Exposures on a ladder of 8 steps per decade (rounded down): neighbouring points share their
// exposures, so the dark library serves them without a dark per point.
double OnLadder(double t);

// An exposure asked for, as a key (whole microseconds): the engine's dark library and lamp pools.
std::int64_t ExposureKey(double t);
// Whether two exposures are one: a stored point's is the one its camera applied (read back), in the
// camera's steps (whole microseconds for the simulated one, a sensor line for some), not the
// ladder's step the planner asks for; within 0.1 % they are one (the ladder's steps are 33 %
// apart). An exact comparison split them, and priced a dark set for every adaptive choice.
bool SameExposure(double a, double b);

struct ExposureJudgement {
  bool too_bright = false;  // a rectangle pixel at or past `saturation` of the range
  bool too_dim = false;     // below max(floor, target / 4) of the range, and not yet at max_s
  double next_s = 0;        // the next try's exposure, when either (clamped, on the ladder)
};
// One try at `t` whose brightest rectangle pixel is `peak_adu` above the dark, of `range_adu`
// (linear limit - dark).
ExposureJudgement JudgeExposure(const ExposurePolicy& x, double t, double peak_adu,
                                double range_adu);

// The bench's noise per frame, in stored value units: sigma^2 x frames = shot S/t + dark/t +
// read/t^2 + lamp S^2 at value S and exposure t (CalibrateFrameNoise, strategy.h). It describes
// the bench, not a specimen: a run of one specimen calibrates the forecast of a run of another.
// `dark` is the dark current's shot noise (and the stray light's, which every point has alike):
// without it the long exposures' dark noise was fitted as read noise, which grows as 1/t^2, and
// the forecast put a 1 s tail's sigma at 4 times the bench's.
struct FrameNoise {
  double shot = 0, read = 0, lamp = 0, dark = 0;
};

// What the bench delivers, measured on a finished run that has a fit (Storage::LatestThroughput).
struct Throughput {
  std::int64_t run = 0;      // the run it comes from
  double scale = 0;          // the fit's k: a stored value per unit of f |cos theta_l|
  double floor = 0;          // the fit's constant floor b (stray light), stored value units
  double adu_per_value = 0;  // rectangle-mean ADU per second per unit of stored value (median)
  double dark_adu = 0;       // the dark's rectangle mean (median over the run's darks)
  std::optional<FrameNoise> noise;  // the run's points' sigmas, where they calibrate one
};

// The bench's throughput as the instrument's config states it ([throughput]): run 0, which
// DescribeEstimateBasis names as the config.
Throughput ThroughputOf(const config::ThroughputConfig& c);

// A specimen's expected lobe at the bench's throughput.
struct LobeForecast {
  Throughput bench;
  double alpha = 0;  // the specimen's expected Beckmann width
  double eta = 1.5;
  double linear_limit_adu = 65535;
  int max_ranging_tries = 12;
  // Expected rectangle ADU per second above dark at a transmission point, k f |cos theta_l| + b
  // (the mean stands for the brightest pixel: for a rectangle small against the lobe they differ
  // by its noise); 0 for reflection points, which it does not forecast.
  double Rate(const PlannedPoint& p) const;
};

// The forecast for a specimen: nullopt without a throughput or without the specimen's expected
// width (the catalogue's expected_alpha).
std::optional<LobeForecast> ForecastFor(const Specimen& specimen,
                                        const std::optional<Throughput>& bench,
                                        double linear_limit_adu, int max_ranging_tries);

// What an estimate was priced at, for the operator: "run N's exposures" or "the expected lobe
// (Beckmann alpha A) at run M's throughput" (or "at the configured throughput").
std::string DescribeEstimateBasis(const ExposureHistory* history, const LobeForecast* forecast);

// What a run was expected to cost when it was created (EstimateSeconds), in bench seconds.
struct RunEstimate {
  double total_s = 0;     // motion and exposure (motion only when not `priced`)
  double exposure_s = 0;  // of which exposure: frames, ranging tries, darks
  std::string basis;      // DescribeEstimateBasis, or why the exposures could not be priced
  // False when nothing says what the exposures will be (no earlier run of the specimen, no
  // throughput or no expected width): the plan's first exposure is no estimate (a run ranges
  // its points up from it, 90 times longer on the demo), so none is given.
  bool priced = true;
};

// The estimate of a new run of `plan` on what is known, in this order: `seen`, the specimen's
// newest finished run's exposures (null: none); else its expected lobe at `bench`, the bench's
// throughput (ForecastFor); else the exposures are not priced (`priced` false, the motion only,
// the basis says what is missing). linear_limit_adu and
// max_ranging_tries are the engine's (EngineOptions). An adaptive plan, when `bench` has a noise
// calibration and the specimen an expected width: its runs simulated to the target or the budget
// (point_simulator.h, ForecastAdaptive), the median as the estimate and the 10-90 % range in the
// basis; else its coarse scan and at most its budget. The one choice of basis behind a run's
// stored estimate (Storage's EstimateRun) and a schedule's dry run.
RunEstimate EstimateOn(const Plan& plan, const std::vector<PlannedPoint>& points,
                       const std::vector<devices::AxisSettings>& axes, const ExposureHistory* seen,
                       const std::optional<Throughput>& bench, double linear_limit_adu,
                       int max_ranging_tries);

}  // namespace gonio::acquisition
