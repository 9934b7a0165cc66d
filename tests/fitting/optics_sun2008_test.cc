// Sun 2008's single-scattering BTDF: its pieces against the paper's literal formulas, and the
// relation to Walter's model that the derivation implies.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "optics/microfacet.h"
#include "optics/sun2008.h"

namespace gonio::optics {
namespace {

constexpr double kDeg = kPi / 180;

TEST(Sun2008, ChiEqualsTheLiteralEqA14) {
  // A.14 as printed: sin(alpha) / sin(alpha - beta) * (1 - cos(alpha) / (n cos(beta)))^-1, with
  // beta from Snell's law; both n > 1 and n < 1.
  for (double n : {1.4, 1.51, 1 / 1.4})
    for (double a_deg = 1; a_deg < 89; a_deg += 1.5) {
      const double alpha = a_deg * kDeg;
      const double sb = std::sin(alpha) / n;
      if (sb >= 1) continue;  // no refraction
      const double beta = std::asin(sb);
      const double literal =
          std::sin(alpha) / std::sin(alpha - beta) / (1 - std::cos(alpha) / (n * std::cos(beta)));
      EXPECT_NEAR(Sun2008Chi(std::cos(alpha), std::cos(beta), n), literal, 1e-9 * literal)
          << "n " << n << " alpha " << a_deg;
    }
}

TEST(Sun2008, ChiIsWaltersRefractionJacobianEq17) {
  std::mt19937_64 rng(2);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int k = 0; k < 500; ++k) {
    const Vec3<double> i = Normalize(Vec3<double>(u(rng), u(rng), 1.2 + u(rng)));
    const Vec3<double> o = Normalize(Vec3<double>(u(rng), u(rng), -1.2 + u(rng)));
    const auto m = HalfVectorTransmission(i, 1.0, o, 1.5);
    ASSERT_TRUE(m);
    if (Dot(i, *m) <= 0 || Dot(o, *m) >= 0) continue;
    EXPECT_NEAR(Sun2008Chi(AbsDot(i, *m), AbsDot(o, *m), 1.5),
                JacobianTransmission(i, 1.0, o, 1.5, *m),
                1e-9 * JacobianTransmission(i, 1.0, o, 1.5, *m));
  }
}

TEST(Sun2008, OrientationDensityIsBeckmannWithAlphaTwoOverS) {
  // eq. 8: Gaussian slopes of per-axis variance 2 / s^2; Beckmann's have alpha^2 / 2.
  for (double s : {0.5, 1.0, 3.0, 6.0})
    for (double t = 0; t < 89; t += 3) {
      const Vec3<double> m = DirectionInPlane(t * kDeg);
      const double b = BeckmannDistribution<double>(Sun2008EquivalentAlpha(s)).D(m);
      EXPECT_NEAR(Sun2008OrientationD(m, s), b, 1e-12 * (1 + b)) << s << " " << t;
    }
}

TEST(Sun2008, VisibilityEq24Limits) {
  EXPECT_EQ(Sun2008Visibility(Vec3<double>{0, 0, 1}, 3.0), 1.0);
  // Near the normal a smooth surface hides nothing; toward the horizon everything.
  EXPECT_NEAR(Sun2008Visibility(DirectionInPlane(10 * kDeg), 6.0), 1.0, 1e-12);
  EXPECT_LT(Sun2008Visibility(DirectionInPlane(89.9 * kDeg), 1.0), 1e-3);
  // A literal evaluation at one point.
  const double t = std::tan(70 * kDeg), s = 2.0;
  EXPECT_NEAR(Sun2008Visibility(DirectionInPlane(70 * kDeg), s),
              std::exp(-0.7 * t / s * std::exp(-s * s / (4 * t * t))), 1e-14);
}

TEST(Sun2008, IsWaltersBtdfWithGReplacedByTheVisibilities) {
  // Eq. 25 and eq. 21 share D, the Jacobian and the Fresnel transmittance; they differ in the
  // shadowing. Dividing each by its own shadowing must give the same function.
  const double s = 3.0, eta = 1.4;
  RoughDielectricBsdf<BeckmannDistribution<double>> walter(
      BeckmannDistribution<double>(Sun2008EquivalentAlpha(s)), eta);
  int compared = 0;
  for (double ti : {0.0, 30.0, 160.0})
    for (double to = -89; to < 90; to += 2) {
      const Vec3<double> i = DirectionInPlane(ti * kDeg);
      const Vec3<double> o = DirectionInPlane((ti < 90 ? 180.0 : 0.0) + to * kDeg);
      const double fw = walter.Btdf(i, o), fs = Sun2008Btdf(i, o, s, eta);
      if (fw == 0) {
        EXPECT_EQ(fs, 0.0);
        continue;
      }
      const auto m = HalfVectorTransmission(i, walter.EtaOf(i), o, walter.EtaOf(o));
      const double g = walter.G(i, o, *m);
      const double v = Sun2008Visibility(i, s) * Sun2008Visibility(o, s);
      EXPECT_NEAR(fs / v, fw / g, 1e-9 * fw / g) << ti << " " << to;
      ++compared;
    }
  EXPECT_GT(compared, 60);
}

TEST(Sun2008, NormalIncidenceLobeWidensAsSmoothnessFalls) {
  // Figure 6 of the paper (n = 1.4): the s = 3 lobe is wider than the s = 6 lobe. Measured as the
  // view angle where rho falls to half its peak.
  auto half_width = [](double s) {
    const Vec3<double> i{0, 0, 1};
    const double peak = Sun2008Btdf(i, Vec3<double>{0, 0, -1}, s, 1.4);
    for (double t = 0; t < 90; t += 0.05)
      if (Sun2008Btdf(i, DirectionInPlane(kPi - t * kDeg), s, 1.4) < peak / 2) return t;
    return 90.0;
  };
  EXPECT_GT(half_width(3.0), 1.5 * half_width(6.0));
}

}  // namespace
}  // namespace gonio::optics
