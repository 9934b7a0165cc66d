// Sun 2008, "A physically based transmission model of rough surfaces" (J. Virtual Reality and
// Broadcasting 5(9)): the single-scattering BTDF of a Gaussian rough surface, the project's second
// model family beside Walter's microfacet BTDF.
//
// The surface: Gaussian heights of RMS sigma, Gaussian correlation C(r) = exp(-r^2 / tau^2), and
// smoothness s = tau / sigma (eq. 6; smaller is rougher). The model (eq. 25):
//
//   rho = s^2 cos(alpha) F_t(alpha) exp(-s^2 tan^2 theta_n / 4)
//         ---------------------------------------------------- chi(alpha, beta) V(0,theta_i)
//         V(0,theta_o)
//              4 pi cos(theta_i) |cos(theta_o)| cos^4(theta_n)
//
// with theta_n the polar angle of the facet normal that refracts i into o (the generalised half
// vector h_t of Walter eq. 16), alpha and beta the facet-local angles of incidence and refraction,
// chi = dOmega_n / dOmega_o (eq. A.14) and V(0, theta) the visibility of eq. 24.
//
// Same conventions as microfacet.h: n = +z, directions point away from the surface, i = light,
// o = view, eta = index below / index above. Sun's relative index n is eta_o / eta_i, so light from
// the denser side gives n < 1 (A.14 holds for both, as the paper notes).
//
// Relation to Walter's model (used by the tests as a check, not by this code): the orientation
// density of eq. 8 is Beckmann's D with alpha = 2 / s, chi is Walter's Jacobian of eq. 17, and so
// eq. 25 is eq. 21 with G(i, o, m) replaced by V(0, theta_i) V(0, theta_o).
#pragma once

#include "optics/fresnel.h"
#include "optics/microfacet.h"
#include "optics/vecmath.h"

namespace gonio::optics {

// k0 of eq. 24 (from Sun 2007).
inline constexpr double kSun2008K0 = 0.7;

// The Beckmann width equivalent to smoothness s: both slope densities are Gaussians with
// per-axis variance 2 / s^2 = alpha^2 / 2.
template <typename T>
T Sun2008EquivalentAlpha(const T& s) {
  return T(2) / s;
}

// eq. 8 written as a distribution of normals (per steradian of facet normal, projected):
// p(zeta'_x, zeta'_y) dzeta'_x dzeta'_y = s^2 / (4 pi) exp(-s^2 tan^2 theta_n / 4) dOmega_n /
// cos^3, so D(m) = s^2 exp(-s^2 tan^2 theta_n / 4) / (4 pi cos^4 theta_n).
template <typename T>
T Sun2008OrientationD(const Vec3<T>& wm, const T& s) {
  using std::exp;
  if (CosTheta(wm) <= T(0)) return T(0);
  const T cos2 = Cos2Theta(wm);
  const T e = s * s * (Sin2Theta(wm) / cos2) / T(4);
  if (e > T(700)) return T(0);
  return s * s * exp(-e) / (T(4 * kPi) * cos2 * cos2);
}

// eq. 24: V(0, theta) = exp(-k0 tan(theta) / s * exp(-s^2 / (4 tan^2 theta))), with theta the
// angle of w from the normal on its own side. V = 1 along the normal, -> 0 at the horizon.
template <typename T>
T Sun2008Visibility(const Vec3<T>& w, const T& s) {
  using std::exp;
  using std::sqrt;
  const T sin2 = Sin2Theta(w);
  if (sin2 <= T(0)) return T(1);
  const T cosAbs = AbsCosTheta(w);
  if (cosAbs <= T(0)) return T(0);
  const T tanTheta = sqrt(sin2) / cosAbs;
  return exp(-T(kSun2008K0) * tanTheta / s * exp(-s * s / (T(4) * tanTheta * tanTheta)));
}

// eq. A.14: chi(alpha, beta) = sin(alpha) / sin(alpha - beta) * (1 - cos(alpha) / (n
// cos(beta)))^-1. With Snell (sin(alpha) = n sin(beta)) this equals n^2 cos(beta) / (n cos(beta) -
// cos(alpha))^2, the form evaluated here: it has no 0/0 at alpha = beta = 0. (The test checks the
// two agree.)
template <typename T>
T Sun2008Chi(const T& cosAlpha, const T& cosBeta, const T& n) {
  const T d = n * cosBeta - cosAlpha;
  return n * n * cosBeta / (d * d);
}

// eq. 25, the single-scattering BTDF rho_single(i -> o). Zero unless i and o are on opposite
// sides, at eta = 1 (no refraction), and where no facet refracts i into o.
template <typename T>
T Sun2008Btdf(const Vec3<T>& wi, const Vec3<T>& wo, const T& s, const T& eta) {
  if (!(CosTheta(wi) * CosTheta(wo) < T(0))) return T(0);
  if (eta == T(1)) return T(0);
  const T eta_i = CosTheta(wi) > T(0) ? T(1) : eta;
  const T eta_o = CosTheta(wo) > T(0) ? T(1) : eta;
  const auto wn = HalfVectorTransmission(wi, eta_i, wo, eta_o);
  if (!wn) return T(0);
  // The delta of eq. 10 selects a facet only if i and o lie on its correct sides.
  if (!(Dot(wi, *wn) * CosTheta(wi) > T(0)) || !(Dot(wo, *wn) * CosTheta(wo) > T(0))) return T(0);
  const T n = eta_o / eta_i;
  const T cosAlpha = AbsDot(wi, *wn), cosBeta = AbsDot(wo, *wn);
  const T Ft = T(1) - FresnelDielectric(cosAlpha, n);
  const T orientation = Sun2008OrientationD(*wn, s);  // = s^2 exp(..) / (4 pi cos^4 theta_n)
  return cosAlpha * Ft * orientation * Sun2008Chi(cosAlpha, cosBeta, n) * Sun2008Visibility(wi, s) *
         Sun2008Visibility(wo, s) / (AbsCosTheta(wi) * AbsCosTheta(wo));
}

}  // namespace gonio::optics
