// How a run starts, written once for goniod's controller and gonio-acquire: what every new run
// stores beside its points (the instrument config as written, the responses' setup), how its cost
// is estimated before its first point (EstimateRun with the instrument's limits and its
// configured [throughput]), and the events that say how it began. The daemon makes a RunStart
// from the instrument's config (daemon/instrument: RunStartFor).
#pragma once

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "acquisition/engine.h"
#include "acquisition/exposure.h"
#include "acquisition/plan.h"
#include "acquisition/storage.h"
#include "common/result.h"

namespace gonio::acquisition {

struct RunStart {
  EngineOptions engine;     // the engine's limits and the stages' speeds, which the estimate uses
  std::string config_text;  // the instrument config as written, stored with each run
  // A plan's instrument responses, as the JSON that rebuilds them (fitting::ResponseSetup),
  // stored with its run; unset or "": the run is fitted with the point model.
  std::function<std::string(const Plan&)> response_for;
  // The instrument config's [throughput]: prices a run when the database has no finished run of
  // its own to price it on.
  std::optional<Throughput> throughput;
};

// Creates the run of `plan` with its expanded `points`: the config and the responses stored with
// it, and the rectangle's reason, when the plan chose its rectangle, as a "rectangle" event.
// Errors: Storage's.
Result<std::int64_t> CreateRun(Storage& store, const RunStart& start, const Plan& plan,
                               const std::vector<PlannedPoint>& points);

// What a run of `plan` is expected to cost (EstimateRun at the start's limits and throughput).
Result<RunEstimate> EstimateNewRun(Storage& store, const RunStart& start, const Plan& plan,
                                   const std::vector<PlannedPoint>& points);

// Keeps an estimate with its run where it was priced; where it was not (no run and no
// [throughput] to price it on), no estimate is kept (none is shown) and an "estimate" event says
// why. Errors: Storage's.
Status RecordEstimate(Storage& store, std::int64_t run, const RunEstimate& estimate);

// The "cooled" event of a run measured after the CCD held its setpoint: "sensor held at -10 C".
Status RecordCooled(Storage& store, std::int64_t run, double setpoint_c);

}  // namespace gonio::acquisition
