#include "fitting/sample.h"

#include <algorithm>
#include <cmath>
#include <sstream>

namespace gonio::fitting {
namespace {}

Sample SampleFromBenchAngles(double theta_l_deg, double phi_l_deg, double theta_v_deg,
                             double phi_v_deg, double value, double sigma) {
  const double tl = theta_l_deg * optics::kDeg, pl = phi_l_deg * optics::kDeg;
  const double tv = theta_v_deg * optics::kDeg, pv = phi_v_deg * optics::kDeg;
  Sample s;
  s.light = {std::sin(tl) * std::cos(pl), std::sin(tl) * std::sin(pl), std::cos(tl)};
  s.view = {std::sin(tv) * std::cos(pv), std::sin(tv) * std::sin(pv), -std::cos(tv)};
  s.value = value;
  s.sigma = sigma;
  return s;
}

Sample SampleFromReflectionAngles(double theta_l_deg, double phi_l_deg, double theta_v_deg,
                                  double phi_v_deg, double value, double sigma) {
  // The view through the hemisphere at theta_v, turned to the air side: the mirror of l is
  // (-l.x, -l.y, l.z), reached at theta_v = theta_l.
  Sample s = SampleFromBenchAngles(theta_l_deg, phi_l_deg, theta_v_deg, phi_v_deg, value, sigma);
  s.view = -s.view;
  return s;
}

double ThetaLightDeg(const Sample& s) {
  const double t = std::acos(std::clamp(s.light.z, -1.0, 1.0)) / optics::kDeg;
  return s.light.x < 0 ? -t : t;
}

double ThetaViewDeg(const Sample& s) {
  if (IsReflection(s)) {
    const double t = std::acos(std::clamp(s.view.z, -1.0, 1.0)) / optics::kDeg;
    return s.view.x > 0 ? -t : t;
  }
  const double t = std::acos(std::clamp(-s.view.z, -1.0, 1.0)) / optics::kDeg;
  return s.view.x < 0 ? -t : t;
}

std::vector<Sample> WithSystematic(std::span<const Sample> samples, double relative) {
  std::vector<Sample> out(samples.begin(), samples.end());
  for (Sample& s : out) s.sigma = std::hypot(s.sigma, relative * s.value);
  return out;
}

std::string Where(const Sample& s, std::size_t index, const std::string& source) {
  std::ostringstream os;
  if (s.line > 0 && !source.empty())
    os << source << ":" << s.line;
  else if (s.line > 0)
    os << "line " << s.line;
  else
    os << "sample " << index;
  return os.str();
}

Status ValidateSamples(std::span<const Sample> samples, int n_params, const std::string& source) {
  if (samples.size() <= static_cast<std::size_t>(n_params)) {
    std::ostringstream os;
    os << samples.size() << " samples for " << n_params
       << " free parameters: a fit needs more samples than parameters";
    return InvalidArgument((source.empty() ? "" : source + ": ") + os.str());
  }
  bool any_signal = false;
  for (std::size_t k = 0; k < samples.size(); ++k) {
    const Sample& s = samples[k];
    auto bad = [&](const std::string& what) {
      return InvalidArgument(Where(s, k, source) + ": " + what);
    };
    if (!std::isfinite(s.value)) return bad("value is not a finite number");
    if (!std::isfinite(s.sigma)) return bad("sigma is not a finite number");
    if (!(s.sigma > 0)) return bad("sigma must be > 0 (it weights the sample)");
    if (!(s.sigma_dark >= 0 && s.sigma_dark < s.sigma))
      return bad("sigma_dark (the dark set's shared part of sigma) must lie in [0, sigma)");
    // Dark-subtracted values scatter below zero where the signal is below the noise; that is a
    // measurement of ~0 and dropping or clipping it would bias the fit. More than 5 sigma below
    // zero is not noise: the dark frame does not match the exposure.
    if (s.value < -5 * s.sigma) {
      std::ostringstream os;
      os << "value " << s.value << " is " << -s.value / s.sigma
         << " sigma below zero: a negative BTDF beyond the noise means the dark subtraction is "
            "wrong (dark frame at another exposure or temperature?); fix it upstream";
      return bad(os.str());
    }
    for (const auto* w : {&s.light, &s.view}) {
      if (!std::isfinite(w->x) || !std::isfinite(w->y) || !std::isfinite(w->z))
        return bad("direction is not finite");
      if (std::abs(optics::LengthSquared(*w) - 1) > 1e-6)
        return bad("direction is not unit length");
    }
    if (!(s.light.z > 0)) return bad("light direction must be on the air side (z > 0)");
    if (!(s.view.z != 0))
      return bad(
          "view direction lies in the surface plane (z = 0): neither transmission nor "
          "reflection");
    if (IsReflection(s) != IsReflection(samples[0]))
      return bad(std::string("a ") + (IsReflection(s) ? "reflection" : "transmission") +
                 " sample among " + (IsReflection(samples[0]) ? "reflection" : "transmission") +
                 " ones: fit each side on its own (their scales k differ by the lens's exit)");
    any_signal = any_signal || s.value > s.sigma;
  }
  if (!any_signal)
    return InvalidArgument((source.empty() ? "" : source + ": ") +
                           "every value is zero within its sigma: there is no signal to fit");
  return OkStatus();
}

std::vector<IncidenceGroup> GroupByIncidence(std::span<const Sample> samples) {
  std::vector<IncidenceGroup> groups;
  std::vector<optics::Vec3<double>> keys;
  for (const Sample& s : samples) {
    std::size_t g = 0;
    while (g < keys.size() && optics::LengthSquared(keys[g] - s.light) > 1e-12) ++g;
    if (g == keys.size()) {
      keys.push_back(s.light);
      groups.push_back({ThetaLightDeg(s), {}});
    }
    groups[g].samples.push_back(s);
  }
  return groups;
}

}  // namespace gonio::fitting
