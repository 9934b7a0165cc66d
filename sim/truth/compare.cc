#include "sim/truth/compare.h"

#include <cmath>

#include "optics/microfacet.h"
#include "optics/sun2008.h"
#include "sim/truth/monte_carlo.h"

namespace gonio::sim {

std::vector<double> TabulateModel(const BtdfTable& t, const BtdfFunction& f_t) {
  // 4-point Gauss-Legendre on [-1, 1].
  static const double x[4] = {-0.8611363115940526, -0.3399810435848563, 0.3399810435848563,
                              0.8611363115940526};
  static const double w[4] = {0.3478548451374538, 0.6521451548625461, 0.6521451548625461,
                              0.3478548451374538};
  const double d = optics::kPi / 180, ti = t.theta_i_deg * d;
  const optics::Vec3<double> l{std::sin(ti), 0, std::cos(ti)};
  std::vector<double> out(t.n_theta * t.n_phi, 0.0);
  for (int a = 0; a < t.n_theta; ++a)
    for (int b = 0; b < t.n_phi; ++b) {
      const double t0 = t.ThetaLo(a) * d, t1 = t.ThetaHi(a) * d;
      const double p0 = t.PhiLo(b) * d, p1 = t.PhiHi(b) * d;
      double sum = 0;
      for (int q = 0; q < 4; ++q)
        for (int r = 0; r < 4; ++r) {
          const double th = 0.5 * (t0 + t1) + 0.5 * (t1 - t0) * x[q];
          const double ph = 0.5 * (p0 + p1) + 0.5 * (p1 - p0) * x[r];
          const optics::Vec3<double> v{std::sin(th) * std::cos(ph), std::sin(th) * std::sin(ph),
                                       -std::cos(th)};
          // weight: |cos theta| sin theta dtheta dphi
          sum += w[q] * w[r] * f_t(l, v) * std::cos(th) * std::sin(th);
        }
      out[t.Index(a, b)] = sum * 0.25 * (t1 - t0) * (p1 - p0) / t.CosSolidAngle(a);
    }
  return out;
}

TableDifference Compare(const BtdfTable& mc, const std::vector<double>& model) {
  TableDifference r;
  double diff = 0, noise = 0;
  for (int a = 0; a < mc.n_theta; ++a)
    for (int b = 0; b < mc.n_phi; ++b) {
      const int k = mc.Index(a, b);
      const double c = mc.CosSolidAngle(a);
      diff += std::abs(mc.f[k] - model[k]) * c;
      noise += std::sqrt(2 / optics::kPi) * mc.f_se[k] * c;
      r.transmitted_mc += mc.f[k] * c;
      r.transmitted_model += model[k] * c;
    }
  r.l1_relative = r.transmitted_mc > 0 ? diff / r.transmitted_mc : 0;
  r.l1_noise = r.transmitted_mc > 0 ? noise / r.transmitted_mc : 0;
  return r;
}

TableDifference CompareTables(const BtdfTable& a, const BtdfTable& b) {
  TableDifference r = Compare(a, b.f);
  double noise = 0;
  for (int i = 0; i < a.n_theta; ++i)
    for (int j = 0; j < a.n_phi; ++j) {
      const int k = a.Index(i, j);
      noise += std::sqrt(2 / optics::kPi) * std::hypot(a.f_se[k], b.f_se[k]) * a.CosSolidAngle(i);
    }
  r.l1_noise = r.transmitted_mc > 0 ? noise / r.transmitted_mc : 0;
  return r;
}

BtdfFunction WalterBeckmannModel(double s, double n_above, double n_below) {
  const optics::RoughDielectricBsdf<optics::BeckmannDistribution<double>> bsdf(
      optics::BeckmannDistribution<double>(PredictedAlpha(s)), n_below / n_above);
  return [bsdf](const optics::Vec3<double>& l, const optics::Vec3<double>& v) {
    return bsdf.Btdf(l, v);
  };
}

BtdfFunction Sun2008Model(double s, double n_above, double n_below) {
  const double eta = n_below / n_above;
  return [s, eta](const optics::Vec3<double>& l, const optics::Vec3<double>& v) {
    return optics::Sun2008Btdf(l, v, s, eta);
  };
}

}  // namespace gonio::sim
