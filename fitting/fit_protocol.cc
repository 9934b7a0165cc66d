#include "fitting/fit_protocol.h"

#include <cmath>
#include <string>

namespace gonio::fitting {

namespace {

// `what`: the samples' part, for progress ("normal incidence", "all incidences").
Result<std::vector<FitSummary>> FitEach(std::span<const Sample> samples,
                                        const FitProtocolOptions& o, const std::string& what) {
  std::vector<FitSummary> fits;
  for (const ModelSpec& m : o.models) {
    FitOptions fo = o.base;
    fo.model = m;
    if (o.stage) o.stage(Describe(m) + ", " + what);
    if (o.base.progress)
      fo.progress = [&o, label = Describe(m) + ", " + what + ": "](const std::string& s) {
        o.base.progress(label + s);
      };
    auto r = Fit(samples, fo);
    if (!r.ok()) return Error{r.error().code, Describe(m) + ": " + r.error().message};
    fits.push_back(*r);
  }
  return fits;
}

}  // namespace

Result<std::vector<ModelSpec>> ParseModels(std::span<const std::string> names, optics::SmithG1 g1) {
  std::vector<ModelSpec> specs;
  for (const std::string& name : names) {
    auto family = ParseFamily(name);
    if (!family)
      return InvalidArgument("unknown model '" + name + "' (known: beckmann, ggx, phong, sun2008)");
    specs.push_back({*family, g1});
  }
  if (specs.empty()) return InvalidArgument("no model to fit");
  return specs;
}

bool FitProtocolResult::AnyFitted() const {
  for (const FitSummary& f : joint_fits)
    if (f.status != FitStatus::kFailed) return true;
  return false;
}

Result<FitProtocolResult> RunFitProtocol(std::span<const Sample> samples,
                                         const FitProtocolOptions& options) {
  FitProtocolResult r;
  r.groups = GroupByIncidence(samples);
  const IncidenceGroup* normal = nullptr;
  for (const IncidenceGroup& g : r.groups)
    if (std::abs(g.theta_l_deg) < options.normal_incidence_deg) normal = &g;
  r.protocol = normal != nullptr && r.groups.size() > 1;
  if (r.protocol) {
    auto fits = FitEach(normal->samples, options, "normal incidence");
    if (!fits.ok()) return fits.error();
    r.normal_fits = std::move(fits).value();
    for (const FitSummary& f : r.normal_fits)
      r.predictions.push_back(PredictIncidences(f, samples));
  }
  auto joint = FitEach(samples, options, "all incidences");
  if (!joint.ok()) return joint.error();
  r.joint_fits = std::move(joint).value();
  r.choice = SelectModel(r.joint_fits);
  return r;
}

std::vector<PredictionError> PredictIncidences(const FitSummary& fit,
                                               std::span<const Sample> samples) {
  std::vector<PredictionError> out;
  for (const auto& g : GroupByIncidence(samples)) {
    PredictionError e;
    e.theta_l_deg = g.theta_l_deg;
    e.n = static_cast<int>(g.samples.size());
    double peak_meas = 0, peak_pred = 0, sum_rel2 = 0;
    int n_rel = 0;
    for (const Sample& s : g.samples) peak_meas = std::max(peak_meas, s.value);
    for (const Sample& s : g.samples) {
      const double p = Predict(fit, s);
      peak_pred = std::max(peak_pred, p);
      e.reduced_chi2 += (p - s.value) * (p - s.value) / (s.sigma * s.sigma);
      if (s.value > 0.01 * peak_meas) {
        sum_rel2 += (p - s.value) * (p - s.value) / (s.value * s.value);
        ++n_rel;
      }
    }
    e.reduced_chi2 /= std::max(1, e.n);
    e.rms_relative = n_rel ? std::sqrt(sum_rel2 / n_rel) : 0;
    e.peak_ratio = peak_meas > 0 ? peak_pred / peak_meas : 0;
    out.push_back(e);
  }
  return out;
}

}  // namespace gonio::fitting
