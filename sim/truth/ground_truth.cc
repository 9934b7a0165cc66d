#include "sim/truth/ground_truth.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <sstream>

#include "optics/microfacet.h"

namespace gonio::sim {

double TabulatedTruth::BtdfCos(const optics::Vec3<double>& l, const optics::Vec3<double>& v) const {
  const double ti = t_.theta_i_deg * optics::kPi / 180;
  const double cos_to_own = l.z * std::cos(ti) + l.x * std::sin(ti);
  if (cos_to_own < std::cos(kTableLightToleranceDeg * optics::kPi / 180)) {
    std::fprintf(stderr, "gonio: bug: TabulatedTruth '%s' holds theta_i %g only (asked %g)\n",
                 name_.c_str(), t_.theta_i_deg,
                 std::acos(std::clamp(l.z, -1.0, 1.0)) * 180 / optics::kPi);
    std::abort();
  }
  const int k = t_.BinOf(v);
  return k < 0 ? 0.0 : t_.f[k] * std::abs(l.z);
}

GroundTruthChoice ChooseGroundTruth(double s, double n_above, double n_below, double theta_i_deg,
                                    double noise_l1) {
  MonteCarloOptions probe;
  probe.rays = 50'000;
  const BtdfTable st = StatisticalMonteCarlo(s, n_above, n_below, theta_i_deg, probe);
  const TableDifference d =
      Compare(st, TabulateModel(st, WalterBeckmannModel(s, n_above, n_below)));
  GroundTruthChoice c;
  c.analytic_error_l1 = ExcessL1(d);
  std::ostringstream os;
  if (c.analytic_error_l1 <= noise_l1) {
    c.kind = TruthKind::kAnalytic;
    os << "analytic single scattering (Walter 2007, Beckmann alpha = 2/s): its error "
       << c.analytic_error_l1 << " is within the measurement noise " << noise_l1;
  } else if (s >= 2) {
    c.kind = TruthKind::kStatisticalMonteCarlo;
    os << "statistical Monte Carlo: single scattering is off by " << c.analytic_error_l1
       << " (> noise " << noise_l1 << "), and for s >= 2 Smith's statistics match explicit "
       << "surfaces within a measurement's noise";
  } else {
    c.kind = TruthKind::kExplicitSurfaces;
    os << "explicit surfaces: single scattering is off by " << c.analytic_error_l1
       << ", and below s = 2 Smith's uncorrelated statistics differ from real surfaces too";
  }
  c.reason = os.str();
  return c;
}

std::shared_ptr<GroundTruth> MicrofacetTruth(const std::string& family, double alpha, double eta) {
  char label[96];
  std::snprintf(label, sizeof label, "%s alpha=%.4g eta=%.4g", family.c_str(), alpha, eta);
  if (family == "beckmann") {
    const optics::RoughDielectricBsdf<optics::BeckmannDistribution<double>> bsdf(
        optics::BeckmannDistribution<double>(alpha), eta);
    return std::make_shared<AnalyticTruth>(
        label,
        [bsdf](const optics::Vec3<double>& l, const optics::Vec3<double>& v) {
          return bsdf.Btdf(l, v);
        },
        [bsdf](const optics::Vec3<double>& l, const optics::Vec3<double>& v) {
          return bsdf.Brdf(l, v);
        });
  }
  if (family == "ggx") {
    const optics::RoughDielectricBsdf<optics::GgxDistribution<double>> bsdf(
        optics::GgxDistribution<double>(alpha), eta);
    return std::make_shared<AnalyticTruth>(
        label,
        [bsdf](const optics::Vec3<double>& l, const optics::Vec3<double>& v) {
          return bsdf.Btdf(l, v);
        },
        [bsdf](const optics::Vec3<double>& l, const optics::Vec3<double>& v) {
          return bsdf.Brdf(l, v);
        });
  }
  std::fprintf(stderr, "MicrofacetTruth: unknown family '%s'\n", family.c_str());
  std::abort();
}

}  // namespace gonio::sim
