// Fits microfacet models to measured BTDF*cos samples with Ceres (Walter 2007 section 6).
//
// Contract
//   * Input: a span of transmission Samples (sample.h), checked by ValidateSamples. The fitter
//     minimises sum_i rho(((S_model(l_i, v_i) - value_i) / sigma_i)^2) over the width, the scale k
//     and (optionally) eta, with rho the identity or a robust loss.
//   * Samples that carry an instrument response (response.h) are modelled as their rectangle's
//     mean (eq. R1 of docs/measurement.md) where that changes the prediction by more than
//     response_tolerance sigma, refined until finer rays change it by less; the others, and
//     samples without one, by the point model. FitSummary::response says how many and the cost.
//   * Samples that share a dark set's error (Sample::dark_set, sigma_dark) take one nuisance per
//     set where it matters, the rest of each sigma independent (DarkUse).
//   * Floor::kFit adds a constant b to the model (stray light); kAuto keeps it only when BIC
//     prefers it. Each parameter's sigma is split into the samples' statistical part and the rest.
//   * Parameters stay physical without bounds the solver can hit: the solver sees log(width),
//     log(k) and, for eta, a logistic map onto (1, 3).
//   * Derivatives are exact (automatic differentiation through the templated optics layer).
//     Derivatives::kNumeric exists only so the benchmarks can chart what exactness buys.
//   * Starts need no human: a 1-D scan of the width on a log grid (k at its closed-form optimum for
//     each width), the lobe's half-width at half maximum, and the caller's start if given. Local
//     fits run from the best few; the lowest cost wins.
//   * Uncertainties: the covariance of the solution (ceres::Covariance), mapped to the physical
//     parameters by the delta method and, by default, inflated by the reduced chi-square when it
//     exceeds 1 (the data scatter more than their sigmas say); with a robust loss, by the squared
//     robust scatter (1.4826 x median |residual|) instead, since the outliers dominate chi-square.
//   * A fit the data cannot support is reported, not hidden: FitStatus::kPoorFit when the model
//     does not describe the data (chi-square p-value < 1e-6), whatever else holds: its width is
//     then not a measurement; else FitStatus::kUnconstrained when fewer than 3 samples lie inside
//     the fitted lobe's half maximum, the width's relative uncertainty exceeds 50 %, or the
//     covariance is singular. One word for "this family is wrong", however its sigma came out.
#pragma once

#include <functional>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "common/result.h"
#include "fitting/model.h"
#include "fitting/sample.h"

namespace gonio::fitting {

enum class Loss { kNone, kHuber, kCauchy };
// A constant floor b added to the model, S = k f cos + b: the stray light no background
// measurement removed. kAuto fits with and without it and keeps it when BIC prefers it by more
// than 2 (positive evidence, Kass & Raftery 1995): "a floor the data need"; and also when leaving
// it out moves the width by more than FitOptions::floor_width_tolerance of the width's sigma with
// it, since BIC asks whether the data show the floor, not whether the width depends on it.
// Wherever BIC could not show the floor, that move joins the width's sigma in quadrature
// (FitSummary::floor_width_shift, Parameter::sigma_floor), whether the floor was then kept or
// left out: a floor kept for its move is chosen on the draw, when the floor-fitted width lies far
// from the other, and the floor-fitted sigma alone is short for those fits (docs/measurement.md).
// On samples whose background was each measured and subtracted (Sample::background_subtracted) it
// fits none.
enum class Floor { kOff, kFit, kAuto };
enum class Derivatives { kAutomatic, kNumeric };
// A sample held to the ray budget: its error traced one level finer, or the next level's change.
enum class HeldError { kTraced, kNextChange };

struct FitOptions {
  ModelSpec model;
  double eta = 1.51;  // fixed value, or the start when fit_eta (soda-lime, docs/reference.md)
  bool fit_eta = false;
  Loss loss = Loss::kNone;
  double loss_scale = 3.0;  // robust loss scale, in units of sigma
  // Start for the width in the family's own unit (alpha, exponent or s); nullopt: none.
  std::optional<double> initial_width;
  int max_local_fits = 3;  // local fits from the best distinct starts
  // false: a single local fit from initial_width (required), no scan and no half-width start.
  // For benchmarks and peers that compare one solve; a user rarely wants it.
  bool automatic_starts = true;
  int scan_points = 40;  // log grid of alpha-equivalent in [0.003, 2]
  int max_iterations = 200;
  Derivatives derivatives = Derivatives::kAutomatic;
  bool inflate_by_reduced_chi2 = true;
  Floor floor = Floor::kOff;
  // Floor::kAuto keeps the floor where leaving it out moves the width by more than this fraction
  // of its sigma (with the floor), whatever BIC says. Infinity: BIC alone decides.
  double floor_width_tolerance = 0.5;
  // Samples that carry an instrument response (response.h) are modelled by it (eq. R1) where it
  // changes the prediction by more than this fraction of the sample's sigma at the current
  // estimate; the decision is per sample and taken again at each solution until it settles.
  // The apertures are added the same way, on top of the rectangle. false: the point model for all.
  bool use_response = true;
  double response_tolerance = 0.1;
  // The most rays one sample's model may hold (memory, and the time of every evaluation). Where
  // the refinement asks for a finer level than that, the model stays at the finest level within
  // it, the next level is evaluated (streamed, its rays never held), the model is corrected to it
  // with the correction's slope in the width, and its error (held_error) joins the sample's sigma
  // in quadrature (ResponseUse::capped). A narrow lobe under a large rectangle with its
  // apertures (antiglare under 3 x 10 mm: 1 178 pixels times 144 cone pairs or more) is where it
  // binds; the demo's samples use a few thousand.
  long max_response_rays = 65536;
  // A held sample's error once the fit has settled: kTraced streams one level finer than the one
  // its model is corrected to, at the solution (a held step at its finest level has none left),
  // and solves again with that; kNextChange keeps the change from the held level to the next
  // (no more rays, but conservative: the change to the next level overstates the error where the
  // levels converge fast).
  // A next level past 64 times the budget is not traced (ResponseUse::traced counts those that
  // were).
  HeldError held_error = HeldError::kTraced;
  // Told what a long fit is doing (each solve, its responses, its result); may be empty.
  std::function<void(const std::string&)> progress;

  // Valid options, or an InvalidArgument naming the bad field.
  Status Validate() const;
  int NumParams() const { return (fit_eta ? 3 : 2) + (floor == Floor::kFit ? 1 : 0); }
};

enum class FitStatus {
  kConverged,      // the solver converged and the data constrain the width
  kUnconstrained,  // converged, but the data do not determine the width (see message)
  kPoorFit,        // converged, but the model does not describe the data: chi-square's p-value
                   // is below 1e-6 (e.g. multiple scattering on very rough glass, wrong family),
                   // whether or not the width is constrained
  kFailed,         // no start converged
};
const char* ToString(FitStatus s);

struct Parameter {
  double value = 0;
  double sigma = 0;  // 1-sigma; 0 for a fixed parameter
  // The part of sigma that the samples' statistical sigmas (Sample::sigma_stat: shot, read and
  // dark noise) account for; the rest, sqrt(sigma^2 - sigma_stat^2), is the instrument's (lamp,
  // monitor) and any inflation by chi-square. 0 when the samples carry no statistical part.
  double sigma_stat = 0;
  // The part of sigma that the geometry's stated uncertainties account for (GeometryUse): the
  // angle read-back through each sample's sigma, the thickness and the rectangle's position by
  // refitting with them moved by their sigma. 0 when none is stated.
  double sigma_geometry = 0;
  // The part of sigma that the floor's choice accounts for (the width's only; FitWithFloor in
  // fitter.cc): where BIC could not show the floor, how far the width with a floor fitted lies
  // from the width without one, whichever of the two is reported. 0 otherwise.
  double sigma_floor = 0;
};

// A setup quantity common to a run (the plate's thickness, the rectangle's position along one
// sensor axis) taken as a nuisance parameter: its stated sigma is a Gaussian prior about the
// stated value, and the data's own chi-square along it (least-squares refits with it moved a
// step either way) the likelihood. The width follows it as a parabola through the three refits.
struct NuisanceUse {
  bool probed = false;      // refits both ways converged (else one way, or none: see GeometryUse)
  bool fitted = false;      // the data's parabola entered (else the prior alone)
  double offset = 0;        // the posterior's most probable offset from the stated value
  double offset_sigma = 0;  // its sigma (the prior's when not fitted)
  double width_shift = 0;   // the width at that offset minus the width at the stated value
  double width_sigma = 0;   // the width's sigma from the offset's
};

// The sample stage's error over one group of points taken without moving it (an incidence's
// sweep moves the arm alone): its read-back angle, and the offset from it the fit found.
struct StageOffset {
  double sample_deg = 0;  // the read-back angle the group shares
  int points = 0;         // how many samples
  double offset_deg = 0;  // the posterior's most probable offset (0 a priori)
  // Its sigma (the prior's, angle_sigma_deg, where the data say nothing), conditional on the
  // thickness and the rectangle found: the offsets are solved inside the final refit, with the
  // geometry held where JointProfile put it. Both shift the lobe, so with few incidences the
  // offsets and the thickness trade against each other and the true offset can lie well beyond
  // this sigma (on antiglare runs the offsets found missed the simulator's by about
  // the prior). The width's sigma is not affected: it carries the geometry's part separately.
  double sigma_deg = 0;
};

// How the geometry's uncertainties (BenchOptics: angle_sigma_deg, thickness_sigma_mm,
// rectangle_sigma_px, stated with the samples' instrument response) entered a fit. The angle
// read-back has two parts. The arm's is independent from point to point (each point moves it):
// it enters each sample's sigma as angle_sigma * |dS/d(arm)|. The sample stage's is common to
// the points taken between two of its moves (a consecutive run of samples with one read-back
// sample angle): one offset per such group, a nuisance parameter of the solve itself with the
// prior N(0, angle_sigma^2), entering each of the group's samples as dS/d(sample) times it
// (linear: on the bench angle_sigma is a few ten-thousandths of a degree). Its prior's term is in
// chi2, so it takes no degree of freedom (the minimised chi2 is then the generalised one of the
// group's correlated errors, chi-square with n - p degrees of freedom). Both slopes are the fitted
// model's at the point as the fit takes it (through its response), and the fit is redone with them
// when the angle term would change some sample's sigma by more than response_tolerance^2 / 2 (a
// tenth of sigma in quadrature at the default). The thickness and the rectangle's position are
// common to a run: an error in them moves every point together, so they are nuisance parameters
// (NuisanceUse), profiled together by least-squares refits with each moved a step either way and
// each pair together (first the thickness by its sigma and the rectangle by a pixel along x and
// along y, then at twice the sigmas the data leave), one quadratic with its cross terms: each
// quantity's offset and sigma are the marginal posterior's. Where the data know a quantity better
// than its stated sigma, the fit is redone at the most probable geometry (its width, k, floor,
// chi-square and residuals are that refit's) and the width's geometry sigma shrinks to what is
// left; where they do not, the prior's sigma stands. A refit that does not converge leaves its part
// out, named in the note. They are not computed for an unconstrained fit (no width to budget; the
// refits are most of a response fit's time).
struct GeometryUse {
  bool stated = false;                    // the samples carry a response: the geometry is known
  double angle_max_fraction = 0;          // the largest angle term over a sample's sigma
  bool angle_in_fit = false;              // the fit was redone with the angle terms in it
  std::vector<StageOffset> sample_stage;  // the sample stage's offsets, when angle_in_fit
  double width_thickness = 0;             // the width's sigma from the thickness
  double width_rectangle = 0;             // the width's sigma from the rectangle (x and y together)
  NuisanceUse thickness;                  // mm
  NuisanceUse rectangle_x, rectangle_y;   // sensor pixels
  bool left_out = false;  // a refit did not converge: its part is not in sigma (note)
  std::string note;       // what was used and what was left out, in words
};

// How the dark sets' shared errors entered a fit (Sample::dark_set, sigma_dark). The samples of a
// set were subtracted with the same dark frames, so the set's error is one error in all of them:
// one nuisance z per set, a parameter of the solve with the prior N(0, 1), entering each of its
// samples as sigma_dark z, and the rest of each sample's sigma, sqrt(sigma^2 - sigma_dark^2),
// independent (generalised least squares with the sets' correlations; the prior's term is in
// chi2, so it takes no degree of freedom). A set enters when it has 2 or more samples and its
// shared part matters: the sum over them of (sigma_dark / sigma)^2 is 0.01 or more (below, the
// correlation moves no parameter's variance by more than about 1 %). Its share of the parameters'
// sigmas is statistical (dark frames' shot and read noise). Residuals are then over the
// independent part of sigma, with the sets' offsets in the model.
struct DarkUse {
  int sets = 0;          // sets modelled
  int samples = 0;       // samples in them
  double largest_z = 0;  // the largest |z| found, in units of its prior
};

// How the instrument response entered a fit (FitOptions::use_response).
struct ResponseUse {
  int samples_with_response = 0;  // samples that carry one
  int rectangle = 0;              // modelled by the rectangle's rays (eq. R1)
  int apertures = 0;              // of which also over the source and lens cones
  long rays = 0;                  // model evaluations per pass over the samples
  int rounds = 0;                 // solves until the per-sample decision settled
  // Samples whose model FitOptions::max_response_rays held below the level the tolerance asked
  // for, and the largest of their quadrature errors as a fraction of the sample's own sigma
  // (added to it in quadrature for the fit).
  int capped = 0;
  double capped_largest = 0;
  // FitOptions::held_error = kTraced: the held samples whose error was traced one level finer,
  // and the largest change to the next level, as a fraction of sigma, that it replaced.
  int traced = 0;
  double capped_untraced_largest = 0;
};

struct FitSummary {
  ModelSpec model;
  FitStatus status = FitStatus::kFailed;
  std::string message;  // why, when not kConverged; empty otherwise

  Parameter width;  // in the family's unit (WidthName)
  Parameter scale;  // k
  Parameter eta;    // sigma 0 unless fitted
  Parameter floor;  // the constant floor b (value units); 0 +- 0 unless fitted
  bool floor_fitted = false;
  std::string floor_choice;  // with Floor::kAuto: why it was kept or left out
  // With Floor::kAuto: the width with a floor fitted minus the width without one (0 unless both
  // fits converged, the floor's with no higher chi-square). Where BIC could not show the floor,
  // its magnitude is in width.sigma (in quadrature, width.sigma_floor): what a floor the data
  // could not show might have moved it, or what choosing it on this draw did.
  double floor_width_shift = 0;
  ResponseUse response;
  GeometryUse geometry;
  DarkUse dark;
  double seconds = 0;  // wall time of the fit
  double alpha_equivalent = 0;

  int n_points = 0;
  int n_params = 0;
  // The geometry's nuisance parameters the data fixed (GeometryUse), each counted as
  // 1 - s^2 / sigma_prior^2 of a parameter: the share of its prior the data replaced.
  double n_nuisance = 0;
  // The sum of squared normalised residuals (without the robust loss), plus the sample stage's
  // prior terms (offset / angle_sigma)^2 where GeometryUse::sample_stage is fitted.
  double chi2 = 0;
  double reduced_chi2 = 0;        // chi2 / (n_points - n_params - n_nuisance)
  double aic = 0;                 // chi2 + 2 p, p = n_params + n_nuisance
  double bic = 0;                 // chi2 + p ln n
  std::vector<double> residuals;  // (model - value) / sigma, in the order of the samples

  int iterations = 0;  // of the winning local fit
  int local_fits = 0;  // how many local fits ran
  int points_in_lobe = 0;

  bool ok() const { return status == FitStatus::kConverged; }
};

// Fits one model. Errors: InvalidArgument for bad options or samples (the message names the
// sample); the solver's own failures are a FitSummary with status kFailed, not an error.
Result<FitSummary> Fit(std::span<const Sample> samples, const FitOptions& options);

// The fitted model's prediction of a sample's value: through the sample's response where the fit
// would use it (FitOptions' default tolerance), at the geometry the fit found (GeometryUse's
// fitted offsets, and the sample stage's offset of the first group read back at the sample's
// angle), plus the floor.
double Predict(const FitSummary& fit, const Sample& s);

// Half-width at half maximum of the lobe, turned into an alpha-equivalent start (or nullopt when
// the data have no clear peak). Exposed for tests.
std::optional<double> EstimateAlphaFromHalfWidth(std::span<const Sample> samples, double eta);

}  // namespace gonio::fitting
