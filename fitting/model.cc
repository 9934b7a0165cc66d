#include "fitting/model.h"

#include <cmath>

namespace gonio::fitting {

const char* Name(Family f) {
  switch (f) {
    case Family::kBeckmann:
      return "beckmann";
    case Family::kGgx:
      return "ggx";
    case Family::kPhong:
      return "phong";
    case Family::kSun2008:
      return "sun2008";
  }
  return "?";
}

std::optional<Family> ParseFamily(std::string_view name) {
  for (Family f : kAllFamilies)
    if (name == Name(f)) return f;
  return std::nullopt;
}

const char* WidthName(Family f) {
  switch (f) {
    case Family::kPhong:
      return "exponent";
    case Family::kSun2008:
      return "s";
    default:
      return "alpha";
  }
}

double AlphaEquivalent(Family f, double width) {
  switch (f) {
    case Family::kPhong:
      return std::sqrt(2.0 / (width + 2.0));
    case Family::kSun2008:
      return optics::Sun2008EquivalentAlpha(width);
    default:
      return width;
  }
}

std::optional<double> WidthFromAlphaEquivalent(Family f, double alpha) {
  if (!(alpha > 0)) return std::nullopt;
  switch (f) {
    case Family::kPhong: {
      const double e = optics::BeckmannToPhongExponent(alpha);
      if (!(e > 0)) return std::nullopt;
      return e;
    }
    case Family::kSun2008:
      return 2.0 / alpha;
    default:
      return alpha;
  }
}

FixedGeometry PrecomputeGeometry(const optics::Vec3<double>& l, const optics::Vec3<double>& v,
                                 double eta) {
  using namespace optics;
  FixedGeometry g;
  g.l = l;
  g.v = v;
  if (CosTheta(l) > 0 && CosTheta(v) > 0) {  // reflection, eq. 20
    const auto h = HalfVectorReflection(l, v);
    if (!h) return g;
    g.h = *h;
    const double ldoth = Dot(l, *h), vdoth = Dot(v, *h);
    if (!(ldoth > 0) || !(vdoth > 0)) return g;  // G1's chi+ (eq. 26, 34)
    g.factor =
        FresnelDielectric(ldoth, eta) / (4 * AbsCosTheta(l) * AbsCosTheta(v)) * AbsCosTheta(l);
    return g;
  }
  if (!(CosTheta(l) * CosTheta(v) < 0) || eta == 1) return g;
  const double eta_i = CosTheta(l) > 0 ? 1 : eta, eta_o = CosTheta(v) > 0 ? 1 : eta;
  const auto h = HalfVectorTransmission(l, eta_i, v, eta_o);
  if (!h) return g;
  g.h = *h;
  // The sidedness of Walter's G1 (eq. 26, 34) and of Sun's refraction delta: the facet must face
  // both directions from their own sides.
  const double ldoth = Dot(l, *h), vdoth = Dot(v, *h);
  if (!(ldoth * CosTheta(l) > 0) || !(vdoth * CosTheta(v) > 0)) return g;
  const double denom = eta_i * ldoth + eta_o * vdoth;
  const double F = FresnelDielectric(ldoth, eta_o / eta_i);
  g.factor = std::abs(ldoth) * std::abs(vdoth) * eta_o * eta_o * (1 - F) /
             (AbsCosTheta(l) * AbsCosTheta(v) * denom * denom) * AbsCosTheta(l);
  return g;
}

bool HasBrdf(Family f) { return f != Family::kSun2008; }

std::string Describe(const ModelSpec& m) {
  std::string s = Name(m.family);
  if (m.family == Family::kBeckmann && m.g1 == optics::SmithG1::kRational) s += " (rational G1)";
  return s;
}

}  // namespace gonio::fitting
