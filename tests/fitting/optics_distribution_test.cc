// Distributions of normals and Smith masking: normalisation (Walter 2007 eq. 4), the projected
// area identity (eq. 3 of the geometric seed), and the accuracy of the rational G1 (eq. 27).
#include <gtest/gtest.h>

#include <cmath>
#include <iostream>

#include "optics/distribution.h"
#include "tests/fitting/sphere_quadrature.h"

namespace gonio::optics {
namespace {

using testing::IntegrateHemisphereIsotropic;
using testing::IntegrateSphere;

constexpr double kDeg = kPi / 180;
const double kAlphas[] = {0.02, 0.05, 0.1, 0.2, 0.344, 0.5, 0.75, 1.0};

template <typename Dist>
double ProjectedAreaIntegral(const Dist& d) {
  return IntegrateHemisphereIsotropic(
      [&](double t) { return d.D(DirectionInPlane(t)) * std::cos(t); });
}

TEST(Distribution, BeckmannProjectedAreaIsOneForAlphaFrom002To1) {
  for (double a : kAlphas)
    EXPECT_NEAR(ProjectedAreaIntegral(BeckmannDistribution<double>(a)), 1.0, 1e-6) << "alpha " << a;
}

TEST(Distribution, GgxProjectedAreaIsOneForAlphaFrom002To1) {
  for (double a : kAlphas)
    EXPECT_NEAR(ProjectedAreaIntegral(GgxDistribution<double>(a)), 1.0, 1e-6) << "alpha " << a;
}

TEST(Distribution, PhongProjectedAreaIsOneForTheExponentsEquivalentToAlpha) {
  for (double a : kAlphas) {
    const double e = BeckmannToPhongExponent(a);  // 4998 .. 0
    EXPECT_NEAR(ProjectedAreaIntegral(PhongDistribution<double>(e)), 1.0, 1e-6) << "exponent " << e;
  }
}

TEST(Distribution, DIsZeroBelowTheHorizon) {
  const Vec3<double> below{0.3, 0.0, -0.9539392014169456};
  EXPECT_EQ(BeckmannDistribution<double>(0.3).D(below), 0.0);
  EXPECT_EQ(GgxDistribution<double>(0.3).D(below), 0.0);
  EXPECT_EQ(PhongDistribution<double>(20.0).D(below), 0.0);
}

// eq. 3: integral over m of G1(v, m) max(0, v.m) D(m) = v.n, for every view v. It holds exactly
// for the exact Smith G1 of a distribution, approximately for the rational forms.
template <typename Dist>
double VisibleProjectedAreaRatio(const Dist& d, double theta_v) {
  const Vec3<double> v = DirectionInPlane(theta_v);
  const double integral = IntegrateSphere(
      [&](const Vec3<double>& m) { return d.G1(v, m) * std::max(0.0, Dot(v, m)) * d.D(m); }, 0.0,
      kPi / 2, 64, 64);
  return integral / std::cos(theta_v);
}

TEST(Distribution, ProjectedAreaIdentityHoldsForExactSmithG1) {
  for (double a : {0.1, 0.344, 0.8})
    for (double tv : {0.0, 30.0, 60.0, 80.0, 88.0}) {
      EXPECT_NEAR(VisibleProjectedAreaRatio(BeckmannDistribution<double>(a), tv * kDeg), 1.0, 2e-4)
          << "Beckmann alpha " << a << " theta_v " << tv;
      EXPECT_NEAR(VisibleProjectedAreaRatio(GgxDistribution<double>(a), tv * kDeg), 1.0, 2e-4)
          << "GGX alpha " << a << " theta_v " << tv;
    }
}

TEST(Distribution, ProjectedAreaIdentityHoldsApproximatelyForRationalG1) {
  // The rational G1 is within 0.35 % of the exact one, so the identity is within that too.
  for (double a : {0.1, 0.344, 0.8})
    for (double tv : {30.0, 60.0, 80.0, 88.0}) {
      BeckmannDistribution<double> d(a, SmithG1::kRational);
      EXPECT_NEAR(VisibleProjectedAreaRatio(d, tv * kDeg), 1.0, 0.0036)
          << "alpha " << a << " theta_v " << tv;
    }
}

TEST(Distribution, PhongMaskingThroughEq27HoldsTheIdentityOnlyForNarrowLobes) {
  // Walter recommends eq. 27 with a mapped argument for Phong "based on its similarity to
  // Beckmann and some numerical testing": it is not Phong's exact Smith G1. Measured here: the
  // identity holds to 1.5 % for alpha_b <= 0.2 (exponent >= 48) up to 88 degrees, but misses by
  // ~4 % at exponent 14.9 (alpha_b 0.344) and by > 20 % at exponent 2 near grazing. The fitter
  // must not trust Phong at grazing views on rough samples (docs/optics.md).
  auto worst = [](double e) {
    double w = 0;
    for (double tv : {30.0, 60.0, 80.0, 88.0})
      w = std::max(
          w, std::abs(VisibleProjectedAreaRatio(PhongDistribution<double>(e), tv * kDeg) - 1.0));
    return w;
  };
  const double e2 = worst(2.0), e15 = worst(14.9), e48 = worst(48.0), e200 = worst(200.0);
  std::cout << "[ info ] Phong eq. 27 identity, worst |ratio - 1| to 88 deg: exponent 2 " << e2
            << ", 14.9 " << e15 << ", 48 " << e48 << ", 200 " << e200 << "\n";
  EXPECT_LT(e200, 0.002);
  EXPECT_LT(e48, 0.015);
  EXPECT_LT(e15, 0.05);
  EXPECT_GT(e2, 0.1);  // the documented failure region: if this improves, update the docs
  EXPECT_LT(e200, e48);
  EXPECT_LT(e48, e15);
  EXPECT_LT(e15, e2);
}

TEST(Distribution, VisibleNormalDensityIntegratesToOne) {
  for (double a : {0.05, 0.344, 1.0})
    for (double tv : {0.0, 45.0, 85.0, 135.0}) {  // 135: viewed from below
      GgxDistribution<double> d(a);
      const Vec3<double> v = DirectionInPlane(tv * kDeg);
      const double mass = IntegrateSphere(
          [&](const Vec3<double>& m) { return d.PdfVisibleWm(v, m); }, 0.0, kPi / 2, 96, 64);
      EXPECT_NEAR(mass, 1.0, 2e-4) << "alpha " << a << " theta_v " << tv;
    }
}

// ---- eq. 27 against eq. 26 -------------------------------------------------------------------

TEST(SmithG1, RationalApproximationIsWithin035PercentOfExactBeckmann) {
  double worst = 0, worst_a = 0;
  for (int k = 1; k <= 200000; ++k) {
    const double a = 1e-4 + 4.0 * k / 200000;  // covers (0, 4]; both are 1 to 1e-8 beyond
    const double exact = SmithG1ExactBeckmann(a);
    const double rel = std::abs(SmithG1RationalBeckmann(a) - exact) / exact;
    if (rel > worst) worst = rel, worst_a = a;
  }
  std::cout << "[ info ] eq. 27 max relative error " << worst * 100 << " % at a = " << worst_a
            << "\n";
  EXPECT_LT(worst, 0.0035);
  EXPECT_GT(worst, 0.001);  // it is an approximation: an error of 0 would mean we test eq. 26
}

TEST(SmithG1, RationalApproximationOvershootsOneSlightlyBelowA16) {
  // Published behaviour, kept: the fit rises above 1 by ~6e-5 just below a = 1.6, then the
  // piecewise definition snaps to exactly 1.
  double max_value = 0, at = 0;
  for (int k = 0; k <= 100000; ++k) {
    const double a = 1.0 + 0.6 * k / 100000;
    const double g = SmithG1RationalBeckmann(a);
    if (g > max_value) max_value = g, at = a;
  }
  EXPECT_GT(max_value, 1.0);
  EXPECT_LT(max_value - 1.0, 1e-4);
  EXPECT_GT(at, 1.4);
  EXPECT_EQ(SmithG1RationalBeckmann(1.6), 1.0);
}

TEST(SmithG1, ExactBeckmannLimits) {
  EXPECT_EQ(SmithG1ExactBeckmann(0.0), 0.0);            // grazing
  EXPECT_NEAR(SmithG1ExactBeckmann(30.0), 1.0, 1e-15);  // near the normal
  // 2 / (1 + erf(1) + e^-1 / sqrt(pi)) = 2 / (1 + 0.8427008 + 0.2075537)
  EXPECT_NEAR(SmithG1ExactBeckmann(1.0), 0.9754886, 1e-6);
}

TEST(SmithG1, GgxMatchesEq34AndSidedness) {
  GgxDistribution<double> d(0.5);
  const Vec3<double> v = DirectionInPlane(60 * kDeg);
  const double t = std::tan(60 * kDeg);
  EXPECT_NEAR(d.G1(v), 2 / (1 + std::sqrt(1 + 0.25 * t * t)), 1e-14);
  // A facet facing away from v is not seen: chi+((v.m)/(v.n)) = 0.
  const Vec3<double> m = DirectionInPlane(-50 * kDeg);
  EXPECT_LT(Dot(v, m), 0.0);
  EXPECT_EQ(d.G1(v, m), 0.0);
}

// ---- Phong and Beckmann under alpha_p = 2 alpha_b^-2 - 2 -------------------------------------

TEST(Distribution, PhongIsCloseToBeckmannUnderTheMappingAndCloserForNarrowLobes) {
  // L1 distance of the two projected-area densities D(m) cos(theta_m): 0 means identical, 2 means
  // disjoint. Walter: "very similar, especially for narrow widths".
  auto l1 = [](double ab) {
    BeckmannDistribution<double> b(ab);
    PhongDistribution<double> p(BeckmannToPhongExponent(ab));
    return IntegrateHemisphereIsotropic([&](double t) {
      const Vec3<double> m = DirectionInPlane(t);
      return std::abs(b.D(m) - p.D(m)) * std::cos(t);
    });
  };
  const double wide = l1(0.5), mid = l1(0.2), narrow = l1(0.05);
  std::cout << "[ info ] L1(Beckmann, Phong): alpha 0.5 " << wide << ", 0.2 " << mid << ", 0.05 "
            << narrow << "\n";
  EXPECT_LT(mid, 0.05);
  EXPECT_LT(narrow, mid);
  EXPECT_LT(mid, wide);
}

}  // namespace
}  // namespace gonio::optics
