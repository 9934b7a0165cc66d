// The measurement model the fitter fits: S(l, v) = k f(l, v) |cos theta_l| (docs/reference.md
// section 1), for the model families of Walter 2007 (Beckmann, GGX, Phong) and Sun 2008.
//
// Each family has one width parameter, in its own unit:
//   Beckmann, GGX: alpha (slope-like, > 0)      Phong: exponent alpha_p (> 0)
//   Sun 2008: smoothness s = tau / sigma (> 0)
// AlphaEquivalent() maps a width to the Beckmann alpha it resembles (Phong: alpha_p = 2 alpha^-2 -
// 2, Walter section 5.2; Sun: alpha = 2 / s, docs/optics.md), so that widths can be compared and
// searched on one scale.
#pragma once

#include <optional>
#include <string>
#include <string_view>
#include <type_traits>

#include "optics/microfacet.h"
#include "optics/sun2008.h"

namespace gonio::fitting {

enum class Family { kBeckmann, kGgx, kPhong, kSun2008 };

inline constexpr Family kAllFamilies[] = {Family::kBeckmann, Family::kGgx, Family::kPhong,
                                          Family::kSun2008};

const char* Name(Family f);
// Accepts the names Name() returns ("beckmann", "ggx", "phong", "sun2008"); case-sensitive.
std::optional<Family> ParseFamily(std::string_view name);
// The width parameter's name in reports: "alpha", "exponent" or "s".
const char* WidthName(Family f);

double AlphaEquivalent(Family f, double width);
// Inverse of AlphaEquivalent. For Phong, alpha >= 1 has no exponent >= 0: returns nullopt.
std::optional<double> WidthFromAlphaEquivalent(Family f, double alpha);

struct ModelSpec {
  Family family = Family::kBeckmann;
  // Which Smith G1 Beckmann uses (the others have one form each).
  optics::SmithG1 g1 = optics::SmithG1::kExact;
};

std::string Describe(const ModelSpec& m);

// Whether a model family has a reflection (BRDF) form here: Walter's microfacet families do (eq.
// 20); Sun 2008 is a transmission model only, and the fitter refuses it for reflection samples.
bool HasBrdf(Family f);

// Calls op(d) with the microfacet distribution of one of Walter's families (Beckmann, GGX,
// Phong) at `width`: the one place a family becomes a distribution. Not for Sun 2008, which has
// its own functions (sun2008.h); callers branch on it first.
template <typename T, typename Op>
T WithWalterDistribution(const ModelSpec& m, const T& width, Op&& op) {
  using namespace optics;
  switch (m.family) {
    case Family::kBeckmann:
      return op(BeckmannDistribution<T>(width, m.g1));
    case Family::kGgx:
      return op(GgxDistribution<T>(width));
    case Family::kPhong:
      return op(PhongDistribution<T>(width));
    case Family::kSun2008:
      break;
  }
  return T(0);
}

// The transmitted radiance BTDF f(l, v) of the family (microfacet.h conventions: l = light,
// v = view, eta = index below / above), for any scalar T (double or ceres::Jet).
template <typename T>
T ModelBtdf(const ModelSpec& m, const optics::Vec3<T>& l, const optics::Vec3<T>& v, const T& width,
            const T& eta) {
  if (m.family == Family::kSun2008) return optics::Sun2008Btdf(l, v, width, eta);
  return WithWalterDistribution(m, width, [&](const auto& d) {
    return optics::RoughDielectricBsdf<std::decay_t<decltype(d)>>(d, eta).Btdf(l, v);
  });
}

// The BRDF of the family, eq. 20: F(l, h_r) G(l, v, h_r) D(h_r) / (4 |l.n| |v.n|), l and v both
// on the air side. Zero for Sun 2008 (HasBrdf).
template <typename T>
T ModelBrdf(const ModelSpec& m, const optics::Vec3<T>& l, const optics::Vec3<T>& v, const T& width,
            const T& eta) {
  if (m.family == Family::kSun2008) return T(0);
  return WithWalterDistribution(m, width, [&](const auto& d) {
    return optics::RoughDielectricBsdf<std::decay_t<decltype(d)>>(d, eta).Brdf(l, v);
  });
}

// ---- The same model split for a fixed eta (the fitter's fast path) ---------------------------
// With eta fixed, everything in eq. 21 except D and the shadowing depends on the geometry only:
//   S = k * factor(l, v; eta) * D(h; width) * Shadowing(l, v, h; width)
// with factor = |l.h| |v.h| eta_o^2 (1 - F) |cos theta_l| / (|l.n| |v.n| (eta_i l.h + eta_o
// v.h)^2), Shadowing = G1(l, h) G1(v, h) (Walter) or V(0, theta_l) V(0, theta_v) (Sun 2008; its chi
// of eq. A.14 is the same Jacobian, docs/optics.md). For a reflection pair (v on the air side) h
// is h_r and factor = F(l.h_r) |cos theta_l| / (4 |l.n| |v.n|) (eq. 20). The fitter computes
// factor once per sample and differentiates only D * Shadowing. tests/fitting/model_test.cc checks
// it equals MeasurementModel.
struct FixedGeometry {
  optics::Vec3<double> l, v, h;  // h = h_t or h_r (upper hemisphere)
  double factor = 0;             // 0 where no facet refracts l into v
};

FixedGeometry PrecomputeGeometry(const optics::Vec3<double>& l, const optics::Vec3<double>& v,
                                 double eta);

// The shadowing splits into a light part and a view part (Smith's separable G, eq. 23, and Sun's
// V(0, theta_i) V(0, theta_o) alike). The light part is shared by every sample of an incidence,
// so the fitter computes it once per incidence.
template <typename T>
T ShadowingLight(const ModelSpec& m, const optics::Vec3<double>& light, const T& width) {
  const optics::Vec3<T> l(light);
  if (m.family == Family::kSun2008) return optics::Sun2008Visibility(l, width);
  return WithWalterDistribution(m, width, [&](const auto& d) { return d.G1(l); });
}

// D(h) times the view part of the shadowing.
template <typename T>
T DTimesShadowingView(const ModelSpec& m, const FixedGeometry& g, const T& width) {
  const optics::Vec3<T> v(g.v), h(g.h);
  if (m.family == Family::kSun2008)
    return optics::Sun2008OrientationD(h, width) * optics::Sun2008Visibility(v, width);
  return WithWalterDistribution(m, width, [&](const auto& d) { return d.D(h) * d.G1(v); });
}

template <typename T>
T DTimesShadowing(const ModelSpec& m, const FixedGeometry& g, const T& width) {
  return ShadowingLight(m, g.l, width) * DTimesShadowingView(m, g, width);
}

// S = k f(l, v) |cos theta_l|: f the BTDF for a view on the glass side (v.z < 0), the BRDF for one
// on the air side (a reflection sample).
template <typename T>
T MeasurementModel(const ModelSpec& m, const optics::Vec3<T>& l, const optics::Vec3<T>& v,
                   const T& width, const T& k, const T& eta) {
  const T f =
      optics::CosTheta(v) > T(0) ? ModelBrdf(m, l, v, width, eta) : ModelBtdf(m, l, v, width, eta);
  return k * f * optics::AbsCosTheta(l);
}

}  // namespace gonio::fitting
