// The fit protocol of Walter 2007 section 6, written once for gonio-fit and goniod: with a
// normal-incidence sweep among other incidences, fit each model at normal incidence, predict the
// other incidences from that fit (Figures 10-11), fit all incidences jointly, and choose the
// model the data support (SelectModel over the joint fits). Without that pair of sweeps, only
// the joint fit is made.
#pragma once

#include <functional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "common/result.h"
#include "fitting/fitter.h"
#include "fitting/model.h"
#include "fitting/model_choice.h"
#include "fitting/sample.h"

namespace gonio::fitting {

// "beckmann,ggx" into model specs with the given G1 (kExact unless Walter's rational eq. 27 is
// asked for). Unknown names are kInvalidArgument naming the name and the known ones; an empty
// list too.
Result<std::vector<ModelSpec>> ParseModels(std::span<const std::string> names,
                                           optics::SmithG1 g1 = optics::SmithG1::kExact);

// How well a fit predicts each incidence (Walter section 6: fit at normal incidence, then
// predict 30, 60, 80 degrees).
struct PredictionError {
  double theta_l_deg = 0;
  int n = 0;
  double reduced_chi2 = 0;  // sum ((pred - value)/sigma)^2 / n
  double rms_relative = 0;  // over samples above 1 % of the group's peak
  double peak_ratio = 0;    // predicted peak / measured peak
};
std::vector<PredictionError> PredictIncidences(const FitSummary& fit,
                                               std::span<const Sample> samples);

struct FitProtocolOptions {
  std::vector<ModelSpec> models;  // fitted in this order
  FitOptions base;                // each fit's options, its model replaced
  // |theta_l| below this counts as normal incidence (a read-back angle is never exactly 0).
  double normal_incidence_deg = 0.5;
  // Told as each fit begins, with the model and the samples' part ("beckmann, normal
  // incidence"); may be empty. base.progress, if set, is told each fit's steps with that prefix.
  std::function<void(const std::string&)> stage;
};

struct FitProtocolResult {
  std::vector<IncidenceGroup> groups;   // the samples by incidence, as GroupByIncidence orders them
  bool protocol = false;                // a normal-incidence sweep and at least one other incidence
  std::vector<FitSummary> normal_fits;  // per model; empty unless protocol
  std::vector<std::vector<PredictionError>> predictions;  // per normal fit, per group
  std::vector<FitSummary> joint_fits;                     // per model, all samples
  ModelChoice choice;                                     // over joint_fits
  // The fits that describe the lobe's shape: the normal-incidence ones under the protocol
  // (the paper's), the joint ones otherwise. Plots draw these.
  const std::vector<FitSummary>& curve_fits() const { return protocol ? normal_fits : joint_fits; }
  // Whether any joint fit did not fail.
  bool AnyFitted() const;
};

// Runs the protocol. Errors are Fit's (bad options or samples), naming the model; a solver's
// failure is a fit with status kFailed, not an error.
Result<FitProtocolResult> RunFitProtocol(std::span<const Sample> samples,
                                         const FitProtocolOptions& options);

}  // namespace gonio::fitting
