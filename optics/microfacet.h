// The rough dielectric microfacet BSDF: reflection (BRDF) and refraction (BTDF) of a rough
// interface between two dielectrics, after Walter, Marschner, Li, Torrance 2007 (eq. 19-21), with
// its importance sampling (eq. 38-41).
//
// Conventions (docs/reference.md section 2) - read these before calling anything here:
//   * The macrosurface normal n is +z. Directions are unit vectors pointing AWAY from the surface.
//   * eta is the index of the medium BELOW the rough surface (z < 0) relative to the medium ABOVE
//     (z > 0). On the bench the light side (air) is above and the glass (hemisphere side) below,
//     so eta = 1.51 for soda-lime. A direction's own medium follows its sign of z.
//   * f(i, o): i is the LIGHT direction, o the VIEW direction. Read this way, eq. 21 is the
//     radiance BTDF (as in pbrt-v4 and Mitsuba 3): radiance leaving along o per unit irradiance
//     arriving from i. It is not symmetric; it obeys
//         f_t(i, o) / eta_o^2 = f_t(o, i) / eta_i^2          (reciprocity of refraction)
//     with eta_i, eta_o the indices of the media of i and o. f_r(i, o) = f_r(o, i).
//     Energy: for fixed light direction i, integral of (f_r + f_t)(i, o) |o.n| do <= 1.
//   * The measured signal is S(l, v) = k f_t(l, v) |cos theta_l| (docs/reference.md section 1).
//   * Light may arrive from either side. From below (the denser side when eta > 1) total
//     internal reflection occurs; the microsurface is the same height field seen from underneath
//     (facet normals are always taken in the upper hemisphere, as in pbrt-v4), which is
//     the usual approximation and not exact for the shadowing of an upside-down surface.
//
// Degenerate inputs have documented results, never NaN (tests/fitting/optics_stability_test.cc):
//   * a direction exactly at the horizon (cos theta = 0): f = 0, pdf = 0;
//   * i and o on the same side: f_t = 0; on opposite sides: f_r = 0;
//   * eta = 1: f_t = 0 (the transmission is a delta along -i, not a function), f_r = 0 too
//     because F = 0;
//   * i = -o at eta != 1: finite (refraction through the facet m = i at normal facet incidence).
#pragma once

#include <optional>

#include "optics/distribution.h"
#include "optics/fresnel.h"
#include "optics/vecmath.h"

namespace gonio::optics {

// How G(i, o, m) is built from G1 (section 5.1, eq. 23) or from Lambda.
enum class Masking {
  kSeparable,         // G = G1(i, m) G1(o, m), eq. 23 - the paper's choice
  kHeightCorrelated,  // G = chi+ chi+ / (1 + Lambda(i) + Lambda(o)) (geometric seed, eq. 17b);
                      // used for transmission too, as pbrt-v4 does
};

// How SampleWm chooses microfacet normals.
enum class NormalSampling {
  kDistribution,  // p_m = D(m) |m.n| (eq. 24) - the paper's sampling
  kWidened,       // D with alpha' = (1.2 - 0.2 sqrt|i.n|) alpha (section 5.3); distributions
                  // without Widened() (Phong) fall back to kDistribution
  kVisible,       // visible normals D_vis(i, m) (GGX and Beckmann; Phong falls back to
                  // kDistribution)
};

template <typename T>
struct BsdfSample {
  Vec3<T> wo;  // the sampled (view) direction
  Vec3<T> wm;  // the microfacet normal that produced it
  T f{};       // f_s(i, o) (eq. 19)
  T pdf{};     // p_o(o), solid angle density of wo, including the reflect/refract choice
  T weight{};  // f |o.n| / p_o (eq. 41, generalised to the other normal samplers)
  bool reflected = false;
};

// Generalised half vectors, always returned in the upper hemisphere (+z), or nullopt when
// undefined (i + o = 0, or eta_i i + eta_o o = 0: equal indices and o = -i).
template <typename T>
std::optional<Vec3<T>> HalfVectorReflection(const Vec3<T>& wi, const Vec3<T>& wo) {
  Vec3<T> h = wi + wo;  // eq. 13 without the sign: the flip below does its job
  if (LengthSquared(h) <= T(0)) return std::nullopt;
  h = Normalize(h);
  return CosTheta(h) < T(0) ? -h : h;
}
template <typename T>
std::optional<Vec3<T>> HalfVectorTransmission(const Vec3<T>& wi, const T& eta_i, const Vec3<T>& wo,
                                              const T& eta_o) {
  Vec3<T> h = -(wi * eta_i + wo * eta_o);  // eq. 16
  if (LengthSquared(h) <= T(0)) return std::nullopt;
  h = Normalize(h);
  return CosTheta(h) < T(0) ? -h : h;
}

// Jacobians |d w_h / d w_o| of the half-vector maps: eq. 14 (reflection) and eq. 17 (refraction).
template <typename T>
T JacobianReflection(const Vec3<T>& wo, const Vec3<T>& wm) {
  return T(1) / (T(4) * AbsDot(wo, wm));
}
template <typename T>
T JacobianTransmission(const Vec3<T>& wi, const T& eta_i, const Vec3<T>& wo, const T& eta_o,
                       const Vec3<T>& wm) {
  const T denom = eta_i * Dot(wi, wm) + eta_o * Dot(wo, wm);
  return eta_o * eta_o * AbsDot(wo, wm) / (denom * denom);
}

template <MicrofacetDistribution Dist>
class RoughDielectricBsdf {
 public:
  using T = typename Dist::Scalar;

  // eta: index below relative to above (see the header comment); eta > 0.
  RoughDielectricBsdf(Dist distrib, T eta, Masking masking = Masking::kSeparable)
      : distrib_(distrib), eta_(eta), masking_(masking) {}

  const Dist& distribution() const { return distrib_; }
  const T& eta() const { return eta_; }

  // Relative index of the medium a direction lies in (1 above, eta below).
  T EtaOf(const Vec3<T>& w) const { return CosTheta(w) > T(0) ? T(1) : eta_; }
  // Relative index of the medium on the other side from w.
  T EtaAcross(const Vec3<T>& w) const { return CosTheta(w) > T(0) ? eta_ : T(1); }

  // Shadowing-masking G(i, o, m) (eq. 23 or the height-correlated form), including the
  // sidedness factors chi+.
  T G(const Vec3<T>& wi, const Vec3<T>& wo, const Vec3<T>& wm) const {
    if (masking_ == Masking::kSeparable) return distrib_.G1(wi, wm) * distrib_.G1(wo, wm);
    if (Dot(wi, wm) * CosTheta(wi) <= T(0) || Dot(wo, wm) * CosTheta(wo) <= T(0)) return T(0);
    return T(1) / (T(1) + distrib_.Lambda(wi) + distrib_.Lambda(wo));
  }

  // BRDF, eq. 20: F(i, h_r) G(i, o, h_r) D(h_r) / (4 |i.n| |o.n|). Zero unless i and o are on
  // the same side.
  T Brdf(const Vec3<T>& wi, const Vec3<T>& wo) const {
    if (!SameHemisphere(wi, wo)) return T(0);
    const auto wm = HalfVectorReflection(wi, wo);
    if (!wm) return T(0);
    const T F = FresnelDielectric(AbsDot(wi, *wm), EtaAcross(wi) / EtaOf(wi));
    return F * G(wi, wo, *wm) * distrib_.D(*wm) / (T(4) * AbsCosTheta(wi) * AbsCosTheta(wo));
  }

  // BTDF, eq. 21:
  //   |i.h_t| |o.h_t| eta_o^2 (1 - F(i, h_t)) G(i, o, h_t) D(h_t)
  //   ------------------------------------------------------------
  //        |i.n| |o.n| (eta_i (i.h_t) + eta_o (o.h_t))^2
  // Zero unless i and o are on opposite sides, and zero at eta = 1.
  T Btdf(const Vec3<T>& wi, const Vec3<T>& wo) const {
    if (!(CosTheta(wi) * CosTheta(wo) < T(0))) return T(0);
    if (eta_ == T(1)) return T(0);
    const T eta_i = EtaOf(wi), eta_o = EtaOf(wo);
    const auto wm = HalfVectorTransmission(wi, eta_i, wo, eta_o);
    if (!wm) return T(0);
    const T g = G(wi, wo, *wm);
    if (g <= T(0)) return T(0);  // a facet facing away from i or o: no refraction path
    const T idotm = Dot(wi, *wm), odotm = Dot(wo, *wm);
    const T denom = eta_i * idotm + eta_o * odotm;
    const T F = FresnelDielectric(idotm, eta_o / eta_i);
    return AbsDot(wi, *wm) * AbsDot(wo, *wm) * eta_o * eta_o * (T(1) - F) * g * distrib_.D(*wm) /
           (AbsCosTheta(wi) * AbsCosTheta(wo) * denom * denom);
  }

  // eq. 19: f_s = f_r + f_t.
  T F(const Vec3<T>& wi, const Vec3<T>& wo) const { return Brdf(wi, wo) + Btdf(wi, wo); }

  // ---- Sampling (double only; section 5.3) ---------------------------------------------------

  // Density over solid angle of the microfacet normals drawn for incidence wi.
  T PdfWm(const Vec3<T>& wi, const Vec3<T>& wm, NormalSampling how) const {
    if (how == NormalSampling::kWidened) {
      if constexpr (requires { distrib_.Widened(wi); }) return distrib_.Widened(wi).PdfWm(wm);
    }
    if (how == NormalSampling::kVisible) {
      if constexpr (requires { distrib_.PdfVisibleWm(wi, wm); })
        return distrib_.PdfVisibleWm(wi, wm);
    }
    return distrib_.PdfWm(wm);
  }

  Vec3<T> SampleWm(const Vec3<T>& wi, Point2 u, NormalSampling how) const {
    if (how == NormalSampling::kWidened) {
      if constexpr (requires { distrib_.Widened(wi); }) return distrib_.Widened(wi).SampleWm(u);
    }
    if (how == NormalSampling::kVisible) {
      if constexpr (requires { distrib_.SampleVisibleWm(wi, u); })
        return distrib_.SampleVisibleWm(wi, u);
    }
    return distrib_.SampleWm(u);
  }

  // Samples a view direction o for light direction wi: m from SampleWm, then reflection with
  // probability F(i, m) (eq. 39) or refraction (eq. 40). uc and u are independent uniforms in
  // [0, 1). Returns nullopt when the draw produces no valid path (m facing away from i, or o on
  // the wrong side); that lost probability is the single-scattering loss and the shadowing of
  // the sampler, so the density of returned samples integrates to <= 1.
  std::optional<BsdfSample<T>> Sample(const Vec3<T>& wi, double uc, Point2 u,
                                      NormalSampling how = NormalSampling::kDistribution) const {
    using std::sqrt;
    if (CosTheta(wi) == T(0)) return std::nullopt;
    const Vec3<T> wm = SampleWm(wi, u, how);
    const T idotm = Dot(wi, wm);
    if (!(idotm * CosTheta(wi) > T(0))) return std::nullopt;
    const T eta_i = EtaOf(wi), eta_t = EtaAcross(wi);
    const T Fr = FresnelDielectric(idotm, eta_t / eta_i);
    const T pm = PdfWm(wi, wm, how);

    BsdfSample<T> s;
    s.wm = wm;
    if (T(uc) < Fr) {
      s.wo = wm * (T(2) * idotm) - wi;  // eq. 39 (reflect about m)
      if (!SameHemisphere(wi, s.wo)) return std::nullopt;
      s.reflected = true;
      s.pdf = Fr * pm * JacobianReflection(s.wo, wm);
    } else {
      // eq. 40 with eta = eta_i / eta_t and c = i.m; the sign picks the root on the far side of m.
      const T eta = eta_i / eta_t;
      const T c = idotm;
      const T k = T(1) + eta * eta * (c * c - T(1));  // > 0: Fr < 1 rules out TIR
      const T sgn = c > T(0) ? T(1) : T(-1);
      s.wo = Normalize(wm * (eta * c - sgn * SafeSqrt(k)) - wi * eta);
      if (SameHemisphere(wi, s.wo) || CosTheta(s.wo) == T(0)) return std::nullopt;
      s.pdf = (T(1) - Fr) * pm * JacobianTransmission(wi, eta_i, s.wo, eta_t, wm);
    }
    s.f = F(wi, s.wo);
    // eq. 41, generalised: |i.m| G D(m) / (|i.n| p_m(m)); with p_m = D |m.n| it is eq. 41 itself.
    s.weight = pm > T(0)
                   ? AbsDot(wi, wm) * G(wi, s.wo, wm) * distrib_.D(wm) / (AbsCosTheta(wi) * pm)
                   : T(0);
    return s;
  }

  // Density over solid angle with which Sample() returns wo for light direction wi.
  T Pdf(const Vec3<T>& wi, const Vec3<T>& wo,
        NormalSampling how = NormalSampling::kDistribution) const {
    if (CosTheta(wi) == T(0) || CosTheta(wo) == T(0)) return T(0);
    const T eta_i = EtaOf(wi), eta_t = EtaAcross(wi);
    if (SameHemisphere(wi, wo)) {
      const auto wm = HalfVectorReflection(wi, wo);
      if (!wm || !(Dot(wi, *wm) * CosTheta(wi) > T(0))) return T(0);
      const T F = FresnelDielectric(Dot(wi, *wm), eta_t / eta_i);
      return F * PdfWm(wi, *wm, how) * JacobianReflection(wo, *wm);
    }
    if (eta_ == T(1)) return T(0);
    const auto wm = HalfVectorTransmission(wi, eta_i, wo, eta_t);
    if (!wm) return T(0);
    // Reachable by refraction only if i and o lie on the correct sides of the facet.
    if (!(Dot(wi, *wm) * CosTheta(wi) > T(0)) || !(Dot(wo, *wm) * CosTheta(wo) > T(0))) return T(0);
    const T F = FresnelDielectric(Dot(wi, *wm), eta_t / eta_i);
    return (T(1) - F) * PdfWm(wi, *wm, how) * JacobianTransmission(wi, eta_i, wo, eta_t, *wm);
  }

 private:
  Dist distrib_;
  T eta_;
  Masking masking_;
};

}  // namespace gonio::optics
