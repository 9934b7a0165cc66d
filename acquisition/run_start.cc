#include "acquisition/run_start.h"

#include <sstream>

namespace gonio::acquisition {

Result<std::int64_t> CreateRun(Storage& store, const RunStart& start, const Plan& plan,
                               const std::vector<PlannedPoint>& points) {
  auto run = store.NewRun(plan, start.config_text, points,
                          start.response_for ? start.response_for(plan) : std::string());
  if (!run.ok()) return run;
  if (!plan.rectangle_reason.empty())
    if (Status s = store.AddEvent(*run, "rectangle", plan.rectangle_reason); !s.ok())
      return s.error();
  return run;
}

Result<RunEstimate> EstimateNewRun(Storage& store, const RunStart& start, const Plan& plan,
                                   const std::vector<PlannedPoint>& points) {
  return EstimateRun(store, plan, points, start.engine.axes, start.engine.linear_limit_adu,
                     start.engine.max_ranging_tries, start.throughput);
}

Status RecordEstimate(Storage& store, std::int64_t run, const RunEstimate& estimate) {
  if (estimate.priced) return store.SetRunEstimate(run, estimate);
  return store.AddEvent(run, "estimate", estimate.basis);
}

Status RecordCooled(Storage& store, std::int64_t run, double setpoint_c) {
  std::ostringstream held;
  held << "sensor held at " << setpoint_c << " C";
  return store.AddEvent(run, "cooled", held.str());
}

}  // namespace gonio::acquisition
