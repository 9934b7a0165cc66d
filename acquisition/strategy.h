// Strategies: where a run spends its bench time (docs/acquisition.md).
//
// A plan's [strategy] (plan.h, StrategyPolicy) says which of the grid's points a run measures:
// uniform (all), lobe (the expected lobe densely, the tails thinly) or adaptive. An adaptive run
// is sequential experimental design on the fitter's model:
//   1. a coarse scan of the grid;
//   2. a provisional fit (Beckmann, floor and scale free, eta the specimen's);
//   3. the next batch of points (`batch`, or a quarter of the points so far when more), each the
//      grid point that shrinks var(ln alpha) the most per bench
//      second: with F the Fisher information of the points so far in (ln alpha, ln k, b) and g a
//      candidate's gradient of S = k f |cos theta_l| + b, adding it lowers var(ln alpha) by
//        (e' F^-1 g)^2 / (sigma^2 + g' F^-1 g)              (rank-one update of F^-1)
//      and it costs its exposures and its move; sigma and the exposure come from a noise model
//      calibrated on the run's own points (NoiseModel);
//   4. again from 2 until the fit's sigma(alpha) / alpha reaches the target or the next batch
//      would overrun the budget. A batch ends at the first choice predicted to reach the target
//      (but holds at least `batch`): a run does not overshoot its target by a batch.
// The planner works on the point model (no rectangle or apertures): it ranks points, the fit
// that reports alpha uses the instrument response as every fit does.
#pragma once

#include <array>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "acquisition/exposure.h"
#include "acquisition/plan.h"
#include "common/result.h"
#include "fitting/fitter.h"

namespace gonio::acquisition {

// Marks the grid's points the plan's strategy leaves out as skipped, with its reason. Needs the
// specimen's expected width for "lobe" (LoadPlan refuses a lobe plan without one).
void SelectByStrategy(const Plan& plan, std::vector<PlannedPoint>* grid);
// The reason SelectByStrategy gives an adaptive plan's candidates (points it may choose later).
inline constexpr const char* kCandidateReason = "adaptive: a candidate, measured if chosen";
// How an adaptive plan's coarse scan is exposed: the plan's policy with the strategy's
// coarse_frames and at most coarse_max_s. Other plans: the plan's policy.
ExposurePolicy CoarseExposure(const Plan& plan);
// How the engine exposes a point of a plan: an adaptive plan's points without a planned exposure
// (its coarse scan) by CoarseExposure, the rest by the plan's policy.
ExposurePolicy ExposureFor(const Plan& plan, const PlannedPoint& p);

// One measured point, as the planner sees it.
struct Observation {
  PlannedPoint point;
  double value = 0, sigma = 0;  // stored value and its sigma
  double exposure_s = 0;        // the exposure of its averaged frames
  int frames = 0;               // how many were averaged
  double level = 0;             // the rectangle above dark, as a fraction of the linear range
  double cost_s = 0;            // bench seconds it took: every frame (ranging, darks) and its move
};

// What a point will cost and how well it will measure, calibrated on the points so far:
//   exposure  t(S) = clamp(fill / S, min_s, max_s) on the ladder, with `fill` the value x exposure
//             that brings the rectangle to the ranging's target (the median over the points of
//             S t target / level);
//   sigma^2   = shot S / t + dark / t + read / t^2 + lamp S^2, least squares on the points'
//             relative residuals, each term >= 0 (shot: photons; dark: the dark current and the
//             stray light; read: read noise; lamp: what every pixel shares);
//   cost      = frames t + overhead_s, the median over the points of what they cost beyond their
//             averaged frames (the move, ranging tries, readouts), plus a dark set at an exposure
//             whose set is missing or older than max_age_s (the dark library replayed).
struct NoiseModel {
  double fill = 0;
  double shot = 0, read = 0, lamp = 0, dark_current = 0;
  double overhead_s = 0;
  int dark_frames = 4;
  double dark_max_age_s = 600;
  std::map<double, double> dark_taken;  // exposure -> when its set was taken (clock_s)
  double clock_s = 0;                   // the run's bench seconds so far
  ExposurePolicy exposure;
  double Exposure(double value) const;
  double Sigma(double value) const;
  double Cost(double value) const;
  // Cost, and the point taken: the clock runs on and its dark set, if it needed one, is taken.
  double Take(double value);
  // The dark set taken at t (SameExposure), or none.
  std::map<double, double>::iterator DarkAt(double t);
  std::map<double, double>::const_iterator DarkAt(double t) const;
};
// Needs at least 3 points with a positive value; an error says what is missing.
Result<NoiseModel> CalibrateNoise(const std::vector<Observation>& seen,
                                  const ExposurePolicy& exposure, const DarkPolicy& darks);

// The bench's noise per frame (exposure.h, FrameNoise), fitted as CalibrateNoise fits its terms
// with each point's sigma scaled to one frame. Needs 3 points with signal, as CalibrateNoise.
Result<FrameNoise> CalibrateFrameNoise(const std::vector<Observation>& seen);

// The provisional model: S = k f(l, v; alpha, eta) |cos theta_l| + b (Beckmann).
struct Provisional {
  double alpha = 0, k = 0, b = 0, eta = 1.5;
  double Value(const PlannedPoint& p) const;
  // dS / d(ln alpha, ln k, b).
  std::array<double, 3> Gradient(const PlannedPoint& p) const;
};

// One decision of an adaptive run: the point chosen and why.
struct Choice {
  PlannedPoint point;
  double predicted_value = 0, predicted_sigma = 0;
  double exposure_s = 0, cost_s = 0;
  double rel_sigma_before = 0, rel_sigma_after = 0;  // predicted sigma(alpha) / alpha
  std::string Reason() const;                        // for the run's events
};

// The predicted sigma(ln alpha) of the points seen at the model (their own sigmas).
double PredictedRelSigmaAlpha(const Provisional& model, const std::vector<Observation>& seen);

// The next `count` points among `candidates` (skipped ones excluded; a point may be chosen
// again: its repeat averages down), greedily, each by the largest drop of var(ln alpha) per bench
// second given the points seen and the ones chosen before it.
std::vector<Choice> ChooseNext(const Provisional& model, const NoiseModel& noise,
                               const std::vector<Observation>& seen,
                               const std::vector<PlannedPoint>& candidates, int count);

// The provisional fit of the points seen (Beckmann, floor fitted, eta fixed at the specimen's).
Result<fitting::FitSummary> FitSeen(const std::vector<Observation>& seen, double eta);

// An adaptive run, on any way of measuring (NextAdaptiveStep until it stops): `measure` measures
// the given points and returns what they gave, each Observation's point the Choice's (it carries
// the prediction); `decided` hears each choice before it is measured. Starts from the
// points already seen (a coarse scan, or a resumed run's points). Stops when the provisional fit's
// sigma(alpha) / alpha reaches the target (a poor fit's too: its sigma is inflated by its
// chi2/dof, and the message says so), when the next batch would overrun the budget, or when no
// candidate adds anything; the outcome says which.
struct AdaptiveOutcome {
  enum class Stop { kTarget, kBudget, kExhausted } stop = Stop::kExhausted;
  std::string message;  // "reached sigma(alpha)/alpha 0.012 <= 0.015 after 1234 s", ...
  fitting::FitSummary fit;
  double spent_s = 0;
  int rounds = 0, chosen = 0;
};
// One decision of an adaptive run from what it has seen (the points it chose carry their
// predicted cost, PlannedPoint::predicted_s): either the run is over (`stop`) or `batch` is to be
// measured next (its points carry their planned exposure and predicted cost). Deterministic: a
// resumed run that has measured the same points decides the same.
struct AdaptiveStep {
  std::optional<AdaptiveOutcome> stop;
  std::vector<Choice> batch;
};
Result<AdaptiveStep> NextAdaptiveStep(const Plan& plan, const std::vector<PlannedPoint>& candidates,
                                      const std::vector<Observation>& seen);
using MeasureBatch =
    std::function<Result<std::vector<Observation>>(const std::vector<Choice>& batch)>;
Result<AdaptiveOutcome> RunAdaptive(const Plan& plan, const std::vector<PlannedPoint>& candidates,
                                    std::vector<Observation> seen, const MeasureBatch& measure,
                                    const std::function<void(const Choice&)>& decided = {});

}  // namespace gonio::acquisition
