// The instrument response's room: which samples the fit models through their response (eq. R1 of
// docs/measurement.md), at which refinement level, and what a model held to the ray budget
// (FitOptions::max_response_rays) carries in its sigma. Per sample and at the current estimate:
// the point model while the response changes the prediction by at most response_tolerance
// sigma, the rectangle's rays otherwise, the apertures' cones on top where they matter too; each
// refined until finer rays change it by at most half that. Also the fitted model through a
// sample's response at the geometry a fit found (Predict, the stage slopes). Internal to fitting/.
#pragma once

#include <array>
#include <cstddef>
#include <optional>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "common/result.h"
#include "fitting/fitter.h"
#include "fitting/internal/solve.h"
#include "fitting/response.h"
#include "fitting/sample.h"

namespace gonio::fitting::internal {

// A level held below the one asked for (the budget): the next level's value over its own, and
// their difference in value units (0 and ratio 1 where not held).
struct HeldLevel {
  double ratio = 1, change = 0;
  int streamed = -1;          // the index of the level streamed (-1: not held)
  double slope = 0;           // d ln(ratio) / d ln(width)
  double streamed_value = 0;  // at k = 1 and the decision's width
};

// Each sample's responses by refinement level (response.h), computed once per fit when first
// needed, and the levels last chosen (a sample is never coarsened again within a fit).
struct ResponseCache {
  struct PerSample {
    std::vector<std::optional<Response>> rectangle, apertures;
    // The rectangle's coarsest rays spread over the apertures' coarsest cones: whether the
    // apertures matter anywhere in the rectangle (DecideMode).
    std::optional<Response> aperture_probe;
    int rectangle_level = 0, aperture_level = 0;
    // Where FitOptions::max_response_rays held the model below the level asked for, at the last
    // decision: the next level's value over the held one's, which the model is scaled by (its
    // correction), and their difference (value units), the quadrature's error that sigma takes
    // in; 1 and 0 otherwise.
    double correction = 1;
    double quadrature = 0;
    // Each step as the last decision held it (streamed = -1 where not), and the rectangle level
    // the apertures' step stood on: TraceHeld traces one level finer than each streamed one
    // (FitOptions::held_error), reusing its streamed value at the decision's width.
    HeldLevel rectangle_held, apertures_held;
    int apertures_on = 0;
    // d ln(correction) / d ln(width) at the decision's width (SampleModel::slope).
    double slope = 0, log_width = 0;
    bool IsHeld() const { return rectangle_held.streamed >= 0 || apertures_held.streamed >= 0; }
  };
  std::vector<PerSample> of;
  explicit ResponseCache(std::size_t n) : of(n) {}
};

// The mode a sample needs at (width, k, eta): the point model while the response changes its
// prediction by at most tolerance * sigma, the rectangle's rays otherwise, and the apertures on
// top where they change the nominal value by more than that too; each refined until finer rays
// change it by at most half that.
Result<int> DecideMode(const ModelSpec& m, const Sample& s, std::size_t i, ResponseCache& cache,
                       double width, double k, double eta, double tolerance, long max_rays);

// The model of sample i for a mode (0, 1, 2) from the cache's levels, its geometry at eta.
SampleModel BuildModel(const Sample& s, std::size_t i, const ResponseCache& cache, int mode,
                       double eta);

// Each sample's mode at (width, k, eta); an error names the sample whose response is broken.
Result<std::vector<int>> DecideModes(std::span<const Sample> samples, const FitOptions& o,
                                     ResponseCache& cache, double width, double k, double eta);

// Where the budget held a model, its corrected value's own error: the change from each streamed
// level to the next finer one, both streamed once at (width, k, eta). The correction made the
// model the streamed level's value, whose error that next change measures; the change from the
// held level, which sigma took during the rounds, is the error of a model left uncorrected (on
// antiglare under 3 x 10 mm up to 38 sigma, where the next change is at most 0.5). A step
// streamed at its finest level has no error left: an unbudgeted fit stops there too. A step whose
// next level is past kTraceRaysPerBudget times the budget keeps its change. Sets each held
// sample's quadrature; returns how many samples had every held step traced.
Result<int> TraceHeld(std::span<const Sample> samples, const FitOptions& o, ResponseCache& cache,
                      double width, double k, double eta);

// What each sample's model was built from: its mode and its responses' levels. The decision has
// settled when a new one changes none of them (a level refined at the same mode counts: the
// model built at the start's width would otherwise stay on the coarser rays).
std::vector<std::array<int, 3>> DecidedLevels(const std::vector<int>& modes,
                                              const ResponseCache& cache);

// `samples` with each capped sample's quadrature error (ResponseCache) added to its sigma, into
// `out` (sized once, so that a Problem's span over it stays valid); its count and largest share.
std::pair<int, double> WithQuadrature(std::span<const Sample> samples, const ResponseCache& cache,
                                      std::vector<Sample>& out);

// What a set of decisions models: "R samples over their rectangle, A with the apertures, C held
// to the ray budget; N rays".
std::string DescribeModels(const std::vector<int>& modes, std::span<const SampleModel> models,
                           int capped);

// A setup moved to the geometry a fit found (GeometryUse's fitted offsets; 0 where not fitted).
// The rectangle d pixels along an axis is the optical axis as far the other way.
void MoveToFitted(const GeometryUse& g, ResponseSetup& c);

// The fitted model's value for a sample as the fit models it (through its response where that
// matters, Predict's choice), with the sample's stage position moved to `at`; without the floor
// and the sample stage's offset.
double ModelAt(const FitSummary& f, const Sample& sample, const StagePosition& at);

// The fitted model's slopes dS/d(sample stage) and dS/d(arm) at a sample's read-back position
// (value units per degree), by central differences of the model as the fit takes it (ModelAt):
// on a narrow lobe the rectangle and the apertures widen the flanks, and the point model's slopes
// put the sample stage's offsets where the data do not (on antiglare the offsets found missed
// those the simulator drew by 2-3 of their sigmas, and the thickness and the rectangle took the
// rest). 0, 0 for a sample without a response. Each slope is two response builds.
double StageSlope(const FitSummary& f, const Sample& s, double StagePosition::*axis);

// Both: {dS/d(sample stage), dS/d(arm)}.
std::pair<double, double> StageSlopes(const FitSummary& f, const Sample& s);

}  // namespace gonio::fitting::internal
