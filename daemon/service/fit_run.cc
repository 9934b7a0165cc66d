#include "daemon/service/fit_run.h"

#include <cmath>
#include <memory>

#include "fitting/protocol.h"
#include "fitting/sample.h"
#include "fitting/summary_json.h"

namespace gonio::daemon {

Result<std::vector<RunFit>> FitRun(acquisition::Storage& db, std::int64_t run,
                                   const std::vector<std::string>& models) {
  auto specs = fitting::ParseModels(models);
  if (!specs.ok()) return specs.error();
  auto info = db.GetRun(run);
  if (!info.ok()) return Error{ErrorCode::kNotFound, info.error().message};
  auto rows = db.Measurements(run);
  if (!rows.ok()) return rows.error();
  // The run's instrument response, when its bench's geometry was configured: a stored setup that
  // does not parse is an error naming the run (the fit is not made; nothing is stored or changed).
  std::shared_ptr<const fitting::ResponseSetup> setup;
  if (info->response) {
    auto parsed = fitting::ResponseSetup::FromJson(*info->response);
    if (!parsed.ok())
      return Error{ErrorCode::kFailedPrecondition,
                   "run " + std::to_string(run) + ": its stored instrument response is corrupt (" +
                       parsed.error().message + "); the run is left as it is"};
    setup = std::make_shared<const fitting::ResponseSetup>(std::move(parsed).value());
  }
  std::vector<fitting::Sample> samples;
  for (const auto& r : *rows) {
    if (r.point.reflection)  // a plan has one side: the whole run is reflection
      return Error{ErrorCode::kFailedPrecondition,
                   "run " + std::to_string(run) +
                       " measured reflection (the camera on the light side); the fitter fits "
                       "transmission (BTDF) samples only"};
    auto s =
        fitting::SampleFromBenchAngles(r.point.theta_l_deg, r.point.phi_deg, r.point.theta_v_deg,
                                       r.point.phi_deg, r.m.value, r.m.sigma);
    s.line = r.point.index;
    s.sigma_stat = r.m.sigma_stat;
    if (setup)
      s.response = fitting::PointResponse{
          setup, {r.m.sample_read_deg, r.m.arm_read_deg, r.m.azimuth_read_deg}};
    samples.push_back(s);
  }
  fitting::ProtocolOptions po;
  po.models = *specs;
  po.base.eta = info->specimen_eta;
  po.base.floor = fitting::Floor::kAuto;  // no background is measured: a floor only if needed
  if (Status v = fitting::ValidateSamples(samples, po.base.NumParams(),
                                          "run " + std::to_string(run) + " point");
      !v.ok())
    return v.error();
  auto protocol = fitting::RunProtocol(samples, po);
  if (!protocol.ok()) return protocol.error();
  const fitting::ProtocolResult& p = *protocol;
  std::vector<RunFit> out;
  for (std::size_t k = 0; k < p.joint_fits.size(); ++k) {
    const fitting::FitSummary& f = p.curve_fits()[k];
    RunFit rf;
    rf.model = fitting::Describe(f.model);
    rf.summary = f;
    rf.samples = p.protocol ? "normal incidence" : "all incidences";
    nlohmann::json params{{"width", f.width.value},         {"width_sigma", f.width.sigma},
                          {"scale", f.scale.value},         {"eta", f.eta.value},
                          {"floor", f.floor.value},         {"samples", rf.samples},
                          {"chosen", p.choice.chosen == k}, {"choice", p.choice.reason}};
    if (p.protocol) {
      params["joint"] = fitting::ToJson(p.joint_fits[k]);
      nlohmann::json predictions = nlohmann::json::array();
      for (const fitting::PredictionError& e : p.predictions[k])
        predictions.push_back({{"theta_l_deg", e.theta_l_deg},
                               {"n", e.n},
                               {"rms_relative", e.rms_relative},
                               {"reduced_chi2", e.reduced_chi2}});
      params["predictions"] = predictions;
    }
    auto id = db.StoreFitResult(run, rf.model, params.dump(), fitting::ToJson(f).dump());
    if (!id.ok()) return id.error();
    rf.stored_id = *id;
    out.push_back(std::move(rf));
  }
  return out;
}

}  // namespace gonio::daemon
