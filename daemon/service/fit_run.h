// Fitting a stored run (goniod: a schedule's "fit" after each run, POST /api/v1/runs/{id}/fit),
// by the protocol gonio-fit follows (fitting/fit_protocol.h). When the run has a normal-incidence
// sweep and others beside it, the fit stored for each model is the normal-incidence one (Walter
// 2007 section 6), with its predictions of the other incidences, the joint fit of all of them and
// the model choice beside it in the stored parameters; otherwise the fit of all samples. Each
// model's summary is stored in the run's fit_results and returned.
#pragma once

#include <chrono>
#include <functional>
#include <string>
#include <vector>

#include "acquisition/storage.h"
#include "daemon/service/events.h"
#include "fitting/fitter.h"

namespace gonio::daemon {

struct RunFit {
  std::string model;
  fitting::FitSummary summary;
  std::int64_t stored_id = 0;
  std::string samples;  // "normal incidence" or "all incidences"
};

// Models by name (beckmann, ggx, phong, sun2008; kInvalidArgument naming an unknown one), the
// specimen's eta fixed. kNotFound for an unknown run; kInvalidArgument when the run has too few
// samples to fit. `progress`, when given, is told what the fit is doing (fitting::FitOptions::
// progress, labelled with the model and the samples' part), from the calling thread.
Result<std::vector<RunFit>> FitRun(acquisition::Storage& db, std::int64_t run,
                                   const std::vector<std::string>& models,
                                   std::function<void(const std::string&)> progress = {});

// A FitRun progress that publishes "fit_progress" events ({run, message, seconds}: what the fit
// is doing and how long it has run) on `events`: the first message, then at most one each
// `every`, so that a long fit (a narrow lobe under a large rectangle: minutes) shows it is alive
// without flooding the ring.
std::function<void(const std::string&)> FitProgressEvents(
    EventLog& events, std::int64_t run,
    std::chrono::milliseconds every = std::chrono::milliseconds(1000));

struct PointPrediction {
  int index = 0;  // the run's point
  double theta_l_deg = 0, theta_v_deg = 0;
  double value = 0;  // the fitted model's
};

// The run's stored fit `fit_id` at each of the run's measured points: through the point's
// instrument response where the fit would use it, plus the fitted floor (fitting::Predict), so
// that it sits beside the data as the fit saw them. kNotFound for an unknown run or fit;
// kFailedPrecondition naming the run and fit when its stored model or parameters do not parse.
Result<std::vector<PointPrediction>> PredictRun(acquisition::Storage& db, std::int64_t run,
                                                std::int64_t fit_id);

}  // namespace gonio::daemon
