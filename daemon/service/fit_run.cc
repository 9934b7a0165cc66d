#include "daemon/service/fit_run.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <optional>

#include "fitting/fit_protocol.h"
#include "fitting/sample.h"
#include "fitting/summary_json.h"

namespace gonio::daemon {

namespace {

// The run's measurements as the fitter's samples, each with its instrument response when the
// run's bench geometry was stored; a reflection run's (the camera on the light side) are fitted
// with the BRDF. A stored setup that does not parse is an error naming the run (nothing is stored
// or changed).
Result<std::vector<fitting::Sample>> RunSamples(acquisition::Storage& db, std::int64_t run) {
  auto info = db.GetRun(run);
  if (!info.ok()) return Error{ErrorCode::kNotFound, info.error().message};
  auto rows = db.Measurements(run);
  if (!rows.ok()) return rows.error();
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
    const auto from_angles =
        r.point.reflection ? fitting::SampleFromReflectionAngles : fitting::SampleFromBenchAngles;
    auto s = from_angles(r.point.theta_l_deg, r.point.phi_deg, r.point.theta_v_deg, r.point.phi_deg,
                         r.m.value, r.m.sigma);
    s.line = r.point.index;
    s.sigma_stat = r.m.sigma_stat;
    s.background_subtracted = r.m.background.has_value();
    // The dark set's shared part, as the export gives it (the fitter takes one error per set).
    if (r.m.dark_id > 0 && r.m.sigma_dark > 0 && r.m.sigma_dark < r.m.sigma) {
      s.dark_set = static_cast<int>(r.m.dark_id);
      s.sigma_dark = r.m.sigma_dark;
    }
    if (setup)
      s.response = fitting::PointResponse{
          setup, {r.m.sample_read_deg, r.m.arm_read_deg, r.m.azimuth_read_deg}};
    samples.push_back(s);
  }
  return samples;
}

}  // namespace

std::function<void(const std::string&)> FitProgressEvents(EventLog& events, std::int64_t run,
                                                          std::chrono::milliseconds every) {
  using Clock = std::chrono::steady_clock;
  const Clock::time_point start = Clock::now();
  auto last = std::make_shared<std::optional<Clock::time_point>>();
  return [&events, run, every, start, last](const std::string& message) {
    const Clock::time_point now = Clock::now();
    if (*last && now - **last < every) return;
    *last = now;
    events.Publish("fit_progress",
                   {{"run", run},
                    {"message", message},
                    {"seconds", std::chrono::duration<double>(now - start).count()}});
  };
}

Result<std::vector<RunFit>> FitRun(acquisition::Storage& db, std::int64_t run,
                                   const std::vector<std::string>& models,
                                   std::function<void(const std::string&)> progress) {
  auto specs = fitting::ParseModels(models);
  if (!specs.ok()) return specs.error();
  auto info = db.GetRun(run);
  if (!info.ok()) return Error{ErrorCode::kNotFound, info.error().message};
  auto all = RunSamples(db, run);
  if (!all.ok()) return all.error();
  const std::vector<fitting::Sample>& samples = *all;
  fitting::FitProtocolOptions po;
  po.models = *specs;
  po.base.eta = info->specimen_eta;
  // A floor only if the data need it; none where each point's background was measured.
  po.base.floor = fitting::Floor::kAuto;
  po.base.progress = std::move(progress);
  if (Status v = fitting::ValidateSamples(samples, po.base.NumParams(),
                                          "run " + std::to_string(run) + " point");
      !v.ok())
    return v.error();
  auto protocol = fitting::RunFitProtocol(samples, po);
  if (!protocol.ok()) return protocol.error();
  const fitting::FitProtocolResult& p = *protocol;
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

Result<std::vector<PointPrediction>> PredictRun(acquisition::Storage& db, std::int64_t run,
                                                std::int64_t fit_id) {
  auto fits = db.FitResults(run);
  if (!fits.ok()) return fits.error();
  const auto it = std::find_if(fits->begin(), fits->end(),
                               [&](const acquisition::FitRecord& f) { return f.id == fit_id; });
  if (it == fits->end())
    return Error{ErrorCode::kNotFound,
                 "run " + std::to_string(run) + " has no stored fit " + std::to_string(fit_id)};
  const std::string where = "run " + std::to_string(run) + ", fit " + std::to_string(fit_id);
  // The model as Describe named it ("beckmann", "beckmann (rational G1)"), its parameters as
  // FitRun stored them.
  const auto family = fitting::ParseFamily(it->model.substr(0, it->model.find(' ')));
  const nlohmann::json p = nlohmann::json::parse(it->parameters, nullptr, false);
  fitting::FitSummary f;
  for (const char* key : {"width", "scale", "eta", "floor"})
    if (!p.is_object() || !p.contains(key) || !p[key].is_number())
      return Error{ErrorCode::kFailedPrecondition,
                   where + ": its stored parameters have no number \"" + key + "\""};
  if (!family)
    return Error{ErrorCode::kFailedPrecondition, where + ": unknown model '" + it->model + "'"};
  f.model.family = *family;
  if (it->model.find("rational G1") != std::string::npos) f.model.g1 = optics::SmithG1::kRational;
  f.width.value = p["width"].get<double>();
  f.scale.value = p["scale"].get<double>();
  f.eta.value = p["eta"].get<double>();
  f.floor.value = p["floor"].get<double>();
  auto samples = RunSamples(db, run);
  if (!samples.ok()) return samples.error();
  std::vector<PointPrediction> out;
  out.reserve(samples->size());
  for (const fitting::Sample& s : *samples)
    out.push_back(
        {s.line, fitting::ThetaLightDeg(s), fitting::ThetaViewDeg(s), fitting::Predict(f, s)});
  return out;
}

}  // namespace gonio::daemon
