#include "daemon/service/fit_run.h"

#include <cmath>

#include "fitting/sample.h"
#include "fitting/summary_json.h"

namespace gonio::daemon {

Result<std::vector<RunFit>> FitRun(acquisition::Storage& db, std::int64_t run,
                                   const std::vector<std::string>& models) {
  std::vector<fitting::ModelSpec> specs;
  for (const std::string& m : models) {
    auto family = fitting::ParseFamily(m);
    if (!family)
      return InvalidArgument("unknown model '" + m + "' (known: beckmann, ggx, phong, sun2008)");
    specs.push_back({*family, optics::SmithG1::kExact});
  }
  if (specs.empty()) return InvalidArgument("no model to fit");
  auto info = db.GetRun(run);
  if (!info.ok()) return Error{ErrorCode::kNotFound, info.error().message};
  auto rows = db.Measurements(run);
  if (!rows.ok()) return rows.error();
  std::vector<fitting::Sample> all, normal;
  bool other = false;
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
    all.push_back(s);
    if (std::abs(r.point.theta_l_deg) < 0.5)
      normal.push_back(s);
    else
      other = true;
  }
  const bool use_normal = !normal.empty() && other;
  const auto& samples = use_normal ? normal : all;
  fitting::FitOptions base;
  base.eta = info->specimen_eta;
  if (Status v = fitting::ValidateSamples(samples, base.NumParams(),
                                          "run " + std::to_string(run) + " point");
      !v.ok())
    return v.error();
  std::vector<RunFit> out;
  for (const auto& spec : specs) {
    fitting::FitOptions o = base;
    o.model = spec;
    auto f = fitting::Fit(samples, o);
    if (!f.ok()) return f.error();
    RunFit rf;
    rf.model = fitting::Describe(spec);
    rf.summary = *f;
    rf.samples = use_normal ? "normal incidence" : "all incidences";
    nlohmann::json params{{"width", f->width.value},
                          {"width_sigma", f->width.sigma},
                          {"scale", f->scale.value},
                          {"eta", f->eta.value},
                          {"samples", rf.samples}};
    auto id = db.StoreFitResult(run, rf.model, params.dump(), fitting::ToJson(*f).dump());
    if (!id.ok()) return id.error();
    rf.stored_id = *id;
    out.push_back(std::move(rf));
  }
  return out;
}

}  // namespace gonio::daemon
