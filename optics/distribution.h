// Microfacet normal distributions D(m), their Smith masking G1, and their samplers.
//
// Walter, Marschner, Li, Torrance 2007 ("Microfacet models for refraction through rough surfaces"),
// section 5.2. All three are isotropic height-field distributions: D(m) = 0 for m.n <= 0, and
//   integral over the hemisphere of D(m) (m.n) dw_m = 1                       (projected area)
// Their samplers draw m with the density p_m(m) = D(m) |m.n| (eq. 24) from two uniform variates.
//
// Every distribution satisfies the MicrofacetDistribution concept below:
//   T D(m)                      distribution of normals, 1/sr
//   T Lambda(w)                 Smith's Lambda for direction w (either hemisphere; uses |tan
//   theta|) T G1(w)                     Smith masking for a facet facing w, 1 / (1 + Lambda) or its
//                               rational approximation
//   T G1(w, m)                  G1(w) times the sidedness factor chi+((w.m)/(w.n)) of eq. 26/34
//   Vec3<T> SampleWm(u)         m ~ D(m)|m.n|            (eq. 28-29, 31-32, 35-36)
//   T PdfWm(m)                  D(m)|m.n|, density of SampleWm over solid angle
//
// Every sampler maps the closed unit square [0, 1]^2 to a finite unit normal strictly above the
// horizon (m.n > 0): the end points of the uniforms, which eq. 28, 31 and 35 send to the horizon,
// are moved in by the smallest step that keeps them inside. Every pdf is the density its sampler
// draws, whatever G1 the distribution evaluates.
//
// Phong's width is an exponent, the others' a slope-like alpha; RoughnessToPhong() relates them.
#pragma once

#include <algorithm>
#include <concepts>
#include <limits>

#include "optics/vecmath.h"

namespace gonio::optics {

// Which Smith G1 a Beckmann distribution evaluates. The rational form (eq. 27) avoids erf at a
// maximum relative error of ~0.35 % (measured in tests/fitting; cost ratio in docs/optics.md).
enum class SmithG1 { kExact, kRational };

// Walter's rational approximation to the Beckmann Smith G1 (eq. 27), as a function of
// a = 1 / (alpha tan theta). Exceeds 1 by up to ~6e-5 just below a = 1.6 (the published fit is
// not clamped; we keep it as published so that it is the paper's function).
template <typename T>
T SmithG1RationalBeckmann(const T& a) {
  if (a >= T(1.6)) return T(1);
  return (T(3.535) * a + T(2.181) * a * a) / (T(1) + T(2.276) * a + T(2.577) * a * a);
}

// Exact Beckmann Smith G1 (eq. 26) as a function of a = 1 / (alpha tan theta).
template <typename T>
T SmithG1ExactBeckmann(const T& a) {
  using std::erf;
  using std::exp;
  using std::sqrt;
  if (a <= T(0)) return T(0);
  if (a > T(25)) return T(1);  // erf(a) = 1 and exp(-a^2) = 0 in double precision
  return T(2) / (T(1) + erf(a) + exp(-a * a) / (a * sqrt(T(kPi))));
}

// The largest double below 1 and the smallest positive normal double: the closed unit interval
// of a uniform variate is moved into (0, 1) by these, so that no sampler meets its singular ends.
inline constexpr double kOneMinusEpsilon = 1.0 - 0x1.0p-53;
inline double OpenUnit(double u) {
  return std::clamp(u, std::numeric_limits<double>::min(), kOneMinusEpsilon);
}

// Smith's Lambda for the exact Beckmann G1 (eq. 26) as a function of a = 1 / (alpha tan theta),
// accurate also where G1 is within rounding of 1: Lambda = (exp(-a^2) / (a sqrt(pi)) - erfc(a)) / 2
// there, instead of 1 / G1 - 1, which cancels to 0 for a above about 6. 0 where it underflows.
inline double SmithLambdaExactBeckmann(double a) {
  if (a <= 0) return std::numeric_limits<double>::infinity();
  if (a < 2) return 1 / SmithG1ExactBeckmann(a) - 1;
  if (a > 26) return 0;  // below 1e-296
  return 0.5 * (std::exp(-a * a) / (a * std::sqrt(kPi)) - std::erfc(a));
}

// Inverse error function (double): Giles' single-precision approximation ("Approximating the
// erfinv function", GPU Gems 2010) refined to double precision by Newton steps on std::erfc.
// Domain (-1, 1); +-inf at +-1.
inline double ErfInv(double x) {
  if (x <= -1) return -std::numeric_limits<double>::infinity();
  if (x >= 1) return std::numeric_limits<double>::infinity();
  double w = -std::log((1.0 - x) * (1.0 + x)), p;
  if (w < 5) {
    w -= 2.5;
    p = 2.81022636e-08;
    for (double c : {3.43273939e-07, -3.5233877e-06, -4.39150654e-06, 0.00021858087, -0.00125372503,
                     -0.00417768164, 0.246640727, 1.50140941})
      p = c + p * w;
  } else {
    w = std::sqrt(w) - 3;
    p = -0.000200214257;
    for (double c : {0.000100950558, 0.00134934322, -0.00367342844, 0.00573950773, -0.0076224613,
                     0.00943887047, 1.00167406, 2.83297682})
      p = c + p * w;
  }
  // Newton refinement on |y|: on erf(y) = |x| near 0, and on log erfc(y) = log(1 - |x|) in the
  // tails, where erf(y) - x cancels and log erfc is nearly quadratic (Giles' fit is for floats).
  const double ax = std::abs(x);
  double y = std::abs(p * x);
  for (int k = 0; k < 20; ++k) {
    const double g = 2 / std::sqrt(kPi) * std::exp(-y * y);
    double step;
    if (ax < 0.5) {
      step = (std::erf(y) - ax) / g;
    } else {
      const double e = std::erfc(y);
      step = -(std::log(e) - std::log1p(-ax)) * e / g;
    }
    y -= step;
    if (std::abs(step) <= 1e-15 * (1 + y)) break;
  }
  return x < 0 ? -y : y;
}

// The distribution of visible normals (geometric seed eq. 3b) of any distribution d, seen from w
// in either hemisphere (from below, the surface is seen from -w, as pbrt-v4 does):
// D_vis(w, m) = G1(w, m) max(0, w'.m) D(m) / |w.n| with w' = w flipped to the upper hemisphere.
template <typename Dist, typename T>
T VisibleNormalDensity(const Dist& d, const Vec3<T>& w, const Vec3<T>& wm) {
  const T cos_w = AbsCosTheta(w);
  if (cos_w <= T(0)) return T(0);
  const T wm_dot = CosTheta(w) < T(0) ? -Dot(w, wm) : Dot(w, wm);
  if (wm_dot <= T(0)) return T(0);
  return d.G1(w, wm) * wm_dot * d.D(wm) / cos_w;
}

// ---------------------------------------------------------------------------------------------
// Beckmann, eq. 25 (D), 26 (G1 exact), 27 (G1 rational), 28-29 (sampling). alpha_b > 0.
template <typename T>
class BeckmannDistribution {
 public:
  using Scalar = T;

  explicit BeckmannDistribution(T alpha, SmithG1 g1 = SmithG1::kExact) : alpha_(alpha), g1_(g1) {}

  const T& alpha() const { return alpha_; }
  SmithG1 g1_form() const { return g1_; }

  // eq. 25: D(m) = chi+(m.n) exp(-tan^2 theta_m / alpha^2) / (pi alpha^2 cos^4 theta_m)
  T D(const Vec3<T>& wm) const {
    using std::exp;
    const T cos2 = Cos2Theta(wm);
    if (CosTheta(wm) <= T(0)) return T(0);
    const T tan2 = Sin2Theta(wm) / cos2;
    const T e = tan2 / (alpha_ * alpha_);
    if (e > T(700)) return T(0);  // exp underflows; also avoids 0/0 when cos^4 underflows
    return exp(-e) / (T(kPi) * alpha_ * alpha_ * cos2 * cos2);
  }

  // a = 1 / (alpha tan theta_v) of eq. 26; +inf (returned as a large value) along the normal.
  T A(const Vec3<T>& w) const {
    using std::sqrt;
    const T sin2 = Sin2Theta(w);
    if (sin2 <= T(0)) return T(1e30);
    return AbsCosTheta(w) / (alpha_ * sqrt(sin2));
  }

  T G1(const Vec3<T>& w) const {
    const T a = A(w);
    return g1_ == SmithG1::kExact ? SmithG1ExactBeckmann(a) : SmithG1RationalBeckmann(a);
  }
  T G1(const Vec3<T>& w, const Vec3<T>& wm) const {
    return Dot(w, wm) * CosTheta(w) > T(0) ? G1(w) : T(0);
  }
  // Lambda = 1/G1 - 1; +inf at the horizon (G1 = 0), 0 along the normal.
  T Lambda(const Vec3<T>& w) const { return T(1) / G1(w) - T(1); }

  // eq. 28-29: theta_m = arctan sqrt(-alpha^2 log(1 - xi_1)), phi_m = 2 pi xi_2.
  Vec3<T> SampleWm(Point2 u) const {
    using std::log;
    using std::sqrt;
    const T tan2 = -alpha_ * alpha_ * T(std::log1p(-std::min(u.x, kOneMinusEpsilon)));
    const T cosTheta = T(1) / sqrt(T(1) + tan2);
    const T sinTheta = SafeSqrt(T(1) - cosTheta * cosTheta);
    return SphericalDirection(sinTheta, cosTheta, T(2 * kPi * u.y));
  }
  T PdfWm(const Vec3<T>& wm) const { return D(wm) * AbsCosTheta(wm); }

  // Visible normals seen from w (either hemisphere, as GgxDistribution::SampleVisibleWm: from
  // below, the surface is seen from -w): density D_vis(w, m) = G1(w, m) max(0, w'.m) D(m) / |w.n|
  // with the EXACT Smith G1, whichever G1 this distribution evaluates: the sampler draws the
  // exact visible-normal distribution (Heitz and d'Eon 2014 in pbrt-v3's robust form,
  // BeckmannSample11), so its pdf is that density also for SmithG1::kRational (whose own G1
  // differs by up to 0.35 %). An estimator f / pdf stays unbiased; f keeps the rational G1.
  Vec3<T> SampleVisibleWm(const Vec3<T>& w, Point2 u) const {
    return SampleVisibleUnflipped(CosTheta(w) < T(0) ? -w : w, u);
  }
  T PdfVisibleWm(const Vec3<T>& w, const Vec3<T>& wm) const {
    return VisibleNormalDensity(BeckmannDistribution(alpha_, SmithG1::kExact), w, wm);
  }

  // Visible normals of the upper-hemisphere facets for any unit w with w.z > -1, NOT flipped:
  // what a ray travelling along -w meets, also when it arrives from below the mean plane
  // mid-walk (Heitz et al. 2016). Density max(0, w.m) D(m) / A(w) with projected area
  // A(w) = cos(theta)(1 + Lambda(w)) for w.z > 0 and |cos(theta)| Lambda(-w) for w.z < 0 (exact
  // Smith Lambda). The whole domain is served: steep directions from below, whose visible facets
  // lie in the far tail of the slopes, are sampled there exactly (SampleSlopeTail11). For
  // w.z = -1 nothing is visible; the normal returned is then +n, with density 0.
  // PdfVisibleUnflipped is that density; it underflows to 0 where the visible facets' D and the
  // projected area both fall below about 1e-300 (from below, |cot theta| / alpha above about 26),
  // where the sampler still serves.
  Vec3<T> SampleVisibleUnflipped(const Vec3<T>& w, Point2 u) const {
    if (!(CosTheta(w) > T(-1))) return Vec3<T>(T(0), T(0), T(1));
    const Vec3<T> ws = Normalize(Vec3<T>(alpha_ * w.x, alpha_ * w.y, w.z));
    double slope_x, slope_y;
    SampleSlope11(ws.z, u, &slope_x, &slope_y);
    // Rotate into the azimuth of the stretched direction, unstretch, and form the normal.
    const double sinTheta = std::sqrt(ws.x * ws.x + ws.y * ws.y);
    const double cosPhi = sinTheta > 0 ? ws.x / sinTheta : 1;
    const double sinPhi = sinTheta > 0 ? ws.y / sinTheta : 0;
    const double sx = cosPhi * slope_x - sinPhi * slope_y;
    const double sy = sinPhi * slope_x + cosPhi * slope_y;
    return Normalize(Vec3<T>(T(-alpha_ * sx), T(-alpha_ * sy), T(1)));
  }
  T PdfVisibleUnflipped(const Vec3<T>& w, const Vec3<T>& wm) const {
    const T wm_dot = Dot(w, wm);
    if (wm_dot <= T(0) || CosTheta(wm) <= T(0)) return T(0);
    const T area =
        CosTheta(w) > T(0) ? CosTheta(w) * (T(1) + ExactLambda(w)) : -CosTheta(w) * ExactLambda(-w);
    return area > T(0) ? wm_dot * D(wm) / area : T(0);
  }

  // The widened width of section 5.3 for sampling at incidence w: alpha' = (1.2 - 0.2 sqrt|i.n|)
  // alpha. Sampling with it bounds the eq. 41 weights (to about 4) at grazing incidence.
  BeckmannDistribution Widened(const Vec3<T>& wi) const {
    using std::sqrt;
    return BeckmannDistribution((T(1.2) - T(0.2) * sqrt(AbsCosTheta(wi))) * alpha_, g1_);
  }

 private:
  T ExactLambda(const Vec3<T>& w) const { return T(SmithLambdaExactBeckmann(double(A(w)))); }

  // Slope of the unit-width visible distribution for a direction at cos(theta) in (-1, 1]
  // (pbrt-v3's BeckmannSample11: invert the CDF in the erf domain by safeguarded Newton). The
  // CDF expression holds for cos(theta) < 0 as well (it is cos(theta) (1 + Lambda) normalised).
  static void SampleSlope11(double cosThetaI, Point2 u, double* slope_x, double* slope_y) {
    if (cosThetaI > 0.99999999) {
      const double r = std::sqrt(-std::log1p(-std::min(u.x, kOneMinusEpsilon)));
      *slope_x = r * std::cos(2 * kPi * u.y);
      *slope_y = r * std::sin(2 * kPi * u.y);
      return;
    }
    const double sinThetaI = std::sqrt(std::max(0.0, 1 - cosThetaI * cosThetaI));
    const double tanThetaI = sinThetaI / cosThetaI, cotThetaI = cosThetaI / sinThetaI;
    *slope_y = ErfInv(2 * std::clamp(u.y, 1e-12, 1 - 1e-12) - 1);
    // Seen steeply from below, every visible facet lies beyond the slope cot(theta) < -2, where
    // the erf-domain search below runs out of precision (1 + erf(cot) underflows by -5.9).
    if (cotThetaI < -2) {
      *slope_x = SampleSlopeTail11(-cotThetaI, u.x);
      return;
    }
    // Search in the erf domain, [a, c]; b from Jakob's fitted initial guess.
    double a = -1, c = std::erf(cotThetaI);
    const double x = std::clamp(u.x, 1e-12, 1 - 1e-12);
    const double thetaI = std::acos(cosThetaI);
    const double fit = 1 + thetaI * (-0.876 + thetaI * (0.4265 - 0.0594 * thetaI));
    double b = c - (1 + c) * std::pow(1 - x, fit);
    const double inv_sqrt_pi = 1 / std::sqrt(kPi);
    const double norm = 1 / (1 + c + inv_sqrt_pi * tanThetaI * std::exp(-cotThetaI * cotThetaI));
    for (int it = 0; it < 100; ++it) {
      if (!(b >= a && b <= c)) b = 0.5 * (a + c);  // bisection fallback (also catches NaN)
      const double inv = ErfInv(b);
      const double value = norm * (1 + b + inv_sqrt_pi * tanThetaI * std::exp(-inv * inv)) - x;
      if (std::abs(value) < 1e-12 || c - a < 1e-15) break;
      const double derivative = norm * (1 - inv * tanThetaI);
      if (value > 0)
        c = b;
      else
        a = b;
      b -= value / derivative;
    }
    *slope_x = ErfInv(b);
  }

  // The slope x < -c (c > 2) of a facet visible from a direction with cot(theta) = -c: its
  // density is proportional to (cot - x) exp(-x^2) (the unit-width Beckmann slopes weighted by the
  // projected area), that is, with x = -c - r / (2c), to q(r) = r exp(-r - r^2 / (4c^2)) for r > 0.
  // The CDF of q is inverted exactly: its integrals by 8-point Gauss-Legendre on panels of width
  // at most 1 (the integrand is smooth; the tail beyond r = 40 holds less than 1e-16), Newton
  // steps safeguarded by bisection. No cancellation at any c: nothing here is exp(c^2)-scaled.
  static double SampleSlopeTail11(double c, double u) {
    if (!(c < 1e150)) return -c;  // looking straight up from below: the limit
    const double k = 1 / (4 * c * c);
    auto q = [k](double r) { return r * std::exp(-r - k * r * r); };
    auto integral = [&](double r0, double r1) {  // of q over [r0, r1], either order
      static constexpr double kX[4] = {0.1834346424956498, 0.5255324099163290, 0.7966664774136267,
                                       0.9602898564975363};
      static constexpr double kW[4] = {0.3626837833783620, 0.3137066458778873, 0.2223810344533745,
                                       0.1012285362903763};
      const int panels = std::max(1, int(std::ceil(std::abs(r1 - r0))));
      const double h = (r1 - r0) / panels;
      double sum = 0;
      for (int p = 0; p < panels; ++p) {
        const double mid = r0 + (p + 0.5) * h;
        for (int i = 0; i < 4; ++i)
          sum += kW[i] * (q(mid - 0.5 * h * kX[i]) + q(mid + 0.5 * h * kX[i]));
      }
      return 0.5 * h * sum;
    };
    constexpr double kR = 40;
    const double target = OpenUnit(u) * integral(0, kR);
    double lo = 0, hi = kR, r = 1.68, cdf = integral(0, r);  // r: about the median of q
    for (int it = 0; it < 60; ++it) {
      const double value = cdf - target;
      if (value > 0)
        hi = r;
      else
        lo = r;
      if (std::abs(value) <= 1e-14 * target || hi - lo <= 1e-15 * hi) break;
      double next = r - value / q(r);
      if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);
      cdf += integral(r, next);
      r = next;
    }
    return -c - r / (2 * c);
  }

  T alpha_;
  SmithG1 g1_;
};

// ---------------------------------------------------------------------------------------------
// GGX (Trowbridge-Reitz), eq. 33 (D), 34 (G1), 35-36 (sampling); visible normals after Heitz
// 2018 (the density of eq. 3b of the geometric seed, docs/reference.md source 4). alpha_g > 0.
template <typename T>
class GgxDistribution {
 public:
  using Scalar = T;

  explicit GgxDistribution(T alpha) : alpha_(alpha) {}

  const T& alpha() const { return alpha_; }

  // eq. 33, rearranged as alpha^2 / (pi (alpha^2 cos^2 + sin^2)^2) so it stays finite
  // (and correct) as cos theta_m -> 0.
  T D(const Vec3<T>& wm) const {
    if (CosTheta(wm) <= T(0)) return T(0);
    const T a2 = alpha_ * alpha_;
    const T d = a2 * Cos2Theta(wm) + Sin2Theta(wm);
    return a2 / (T(kPi) * d * d);
  }

  // eq. 34: G1 = 2 / (1 + sqrt(1 + alpha^2 tan^2 theta_v)); Lambda = (sqrt(1 + a^2 t^2) - 1) / 2,
  // written with cos^2 in the denominator only after the product so the horizon gives +inf.
  T Lambda(const Vec3<T>& w) const {
    using std::sqrt;
    const T cos2 = Cos2Theta(w);
    if (cos2 <= T(0)) return T(1e300);
    const T a2t2 = alpha_ * alpha_ * Sin2Theta(w) / cos2;
    return (sqrt(T(1) + a2t2) - T(1)) / T(2);
  }
  T G1(const Vec3<T>& w) const {
    using std::sqrt;
    const T cos2 = Cos2Theta(w);
    if (cos2 <= T(0)) return T(0);
    return T(2) / (T(1) + sqrt(T(1) + alpha_ * alpha_ * Sin2Theta(w) / cos2));
  }
  T G1(const Vec3<T>& w, const Vec3<T>& wm) const {
    return Dot(w, wm) * CosTheta(w) > T(0) ? G1(w) : T(0);
  }

  // eq. 35-36: theta_m = arctan(alpha sqrt(xi_1) / sqrt(1 - xi_1)), phi_m = 2 pi xi_2.
  Vec3<T> SampleWm(Point2 u) const {
    using std::sqrt;
    const double x = std::min(u.x, kOneMinusEpsilon);
    const T tan2 = alpha_ * alpha_ * T(x / (1 - x));
    const T cosTheta = T(1) / sqrt(T(1) + tan2);
    const T sinTheta = SafeSqrt(T(1) - cosTheta * cosTheta);
    return SphericalDirection(sinTheta, cosTheta, T(2 * kPi * u.y));
  }
  T PdfWm(const Vec3<T>& wm) const { return D(wm) * AbsCosTheta(wm); }

  // Visible normals seen from w (either hemisphere; from below, the surface is seen from -w as
  // in pbrt-v4): density D_vis(w, m) = G1(w, m) max(0, w'.m) D(m) / |w.n| with w' = w flipped to
  // the upper hemisphere (eq. 3b of the geometric seed). Heitz 2018, "Sampling the GGX
  // distribution of visible normals", listing 1.
  Vec3<T> SampleVisibleWm(const Vec3<T>& w, Point2 u) const {
    using std::cos;
    using std::sin;
    using std::sqrt;
    Vec3<T> wv = CosTheta(w) < T(0) ? -w : w;
    // Transform to the hemisphere configuration (stretch by alpha).
    const Vec3<T> wh = Normalize(Vec3<T>(alpha_ * wv.x, alpha_ * wv.y, wv.z));
    const T lensq = wh.x * wh.x + wh.y * wh.y;
    const Vec3<T> t1 =
        lensq > T(0) ? Vec3<T>(-wh.y, wh.x, T(0)) / sqrt(lensq) : Vec3<T>(T(1), T(0), T(0));
    const Vec3<T> t2 = Cross(wh, t1);
    // Uniform point on the projected disk, warped to the visible half.
    const T r = T(std::sqrt(u.x));
    const T phi = T(2 * kPi * u.y);
    const T p1 = r * cos(phi);
    T p2 = r * sin(phi);
    const T s = T(0.5) * (T(1) + wh.z);
    p2 = (T(1) - s) * SafeSqrt(T(1) - p1 * p1) + s * p2;
    const Vec3<T> nh = t1 * p1 + t2 * p2 + wh * SafeSqrt(T(1) - p1 * p1 - p2 * p2);
    // Back to the ellipsoid configuration. u.x = 1 (the disk's rim) and rounding can put nh on the
    // horizon; it is kept just above it, where the density is the limit of its neighbours'.
    const T z = nh.z > T(1e-300) ? nh.z : T(1e-300);
    return Normalize(Vec3<T>(alpha_ * nh.x, alpha_ * nh.y, z));
  }
  T PdfVisibleWm(const Vec3<T>& w, const Vec3<T>& wm) const {
    return VisibleNormalDensity(*this, w, wm);
  }

  GgxDistribution Widened(const Vec3<T>& wi) const {
    using std::sqrt;
    // Walter gives the widening for Beckmann only; the same factor is used for GGX (measured in
    // tests: it lowers the maximum weight there too).
    return GgxDistribution((T(1.2) - T(0.2) * sqrt(AbsCosTheta(wi))) * alpha_);
  }

 private:
  T alpha_;
};

// ---------------------------------------------------------------------------------------------
// Phong (Blinn), eq. 30 (D), G1 through eq. 27 with a = sqrt(0.5 alpha_p + 1) / tan theta_v,
// 31-32 (sampling). Exponent alpha_p >= 0.
template <typename T>
class PhongDistribution {
 public:
  using Scalar = T;

  explicit PhongDistribution(T exponent) : exponent_(exponent) {}

  const T& exponent() const { return exponent_; }

  // eq. 30: D(m) = chi+(m.n) (alpha_p + 2) / (2 pi) cos^alpha_p theta_m
  T D(const Vec3<T>& wm) const {
    using std::pow;
    if (CosTheta(wm) <= T(0)) return T(0);
    return (exponent_ + T(2)) / T(2 * kPi) * pow(CosTheta(wm), exponent_);
  }

  T G1(const Vec3<T>& w) const {
    using std::sqrt;
    const T sin2 = Sin2Theta(w);
    if (sin2 <= T(0)) return T(1);
    const T a = sqrt(T(0.5) * exponent_ + T(1)) * AbsCosTheta(w) / sqrt(sin2);
    return SmithG1RationalBeckmann(a);
  }
  T G1(const Vec3<T>& w, const Vec3<T>& wm) const {
    return Dot(w, wm) * CosTheta(w) > T(0) ? G1(w) : T(0);
  }
  T Lambda(const Vec3<T>& w) const { return T(1) / G1(w) - T(1); }

  // eq. 31-32: theta_m = arccos(xi_1^(1 / (alpha_p + 2))), phi_m = 2 pi xi_2.
  Vec3<T> SampleWm(Point2 u) const {
    using std::pow;
    // xi_1 = 0 would be the horizon (eq. 31): moved in to the smallest normal double.
    const T cosTheta = pow(T(OpenUnit(u.x)), T(1) / (exponent_ + T(2)));
    const T sinTheta = SafeSqrt(T(1) - cosTheta * cosTheta);
    return SphericalDirection(sinTheta, cosTheta, T(2 * kPi * u.y));
  }
  T PdfWm(const Vec3<T>& wm) const { return D(wm) * AbsCosTheta(wm); }

 private:
  T exponent_;
};

// The mapping under which Phong and Beckmann are close (section 5.2): alpha_p = 2 alpha_b^-2 - 2.
template <typename T>
T BeckmannToPhongExponent(const T& alpha_b) {
  return T(2) / (alpha_b * alpha_b) - T(2);
}

// ---------------------------------------------------------------------------------------------
template <typename Dist>
concept MicrofacetDistribution = requires(const Dist& d, const Vec3<typename Dist::Scalar>& w,
                                          Point2 u) {
  {d.D(w)};
  {d.G1(w)};
  {d.G1(w, w)};
  {d.Lambda(w)};
  {d.SampleWm(u)};
  {d.PdfWm(w)};
};

}  // namespace gonio::optics
