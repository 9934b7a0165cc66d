#include "fitting/empirical_d.h"

#include <algorithm>
#include <cmath>

#include "optics/distribution.h"
#include "optics/sun2008.h"

namespace gonio::fitting {
namespace {
using optics::Vec3;
}  // namespace

std::vector<EmpiricalDPoint> EmpiricalD(std::span<const Sample> samples, double scale, double eta,
                                        double min_relative, double min_snr) {
  std::vector<EmpiricalDPoint> out;
  double max_value = 0;
  for (const Sample& s : samples) max_value = std::max(max_value, s.value);
  for (const Sample& s : samples) {
    const Vec3<double>& l = s.light;
    const Vec3<double>& v = s.view;
    if (optics::AbsCosTheta(l) <= 0.5 || optics::AbsCosTheta(v) <= 0.5) continue;
    if (s.value < min_relative * max_value || s.value < min_snr * s.sigma) continue;
    // eq. 21 (or 20 for reflection) with G = 1, solved for D; S = k f |cos theta_l|.
    const FixedGeometry g = PrecomputeGeometry(l, v, eta);
    if (!(g.factor > 0)) continue;
    const double to_d = 1 / (scale * g.factor);
    EmpiricalDPoint p;
    p.theta_h_deg = std::acos(std::clamp(g.h.z, -1.0, 1.0)) / optics::kDeg;
    p.d = s.value * to_d;
    p.d_sigma = s.sigma * to_d;
    out.push_back(p);
  }
  std::sort(out.begin(), out.end(), [](const EmpiricalDPoint& a, const EmpiricalDPoint& b) {
    return a.theta_h_deg < b.theta_h_deg;
  });
  return out;
}

double FittedD(const FitSummary& fit, double theta_h_deg) {
  using namespace optics;
  const Vec3<double> m = DirectionInPlane(theta_h_deg * optics::kDeg);
  switch (fit.model.family) {
    case Family::kBeckmann:
      return BeckmannDistribution<double>(fit.width.value).D(m);
    case Family::kGgx:
      return GgxDistribution<double>(fit.width.value).D(m);
    case Family::kPhong:
      return PhongDistribution<double>(fit.width.value).D(m);
    case Family::kSun2008:
      return Sun2008OrientationD(m, fit.width.value);
  }
  return 0;
}

}  // namespace gonio::fitting
