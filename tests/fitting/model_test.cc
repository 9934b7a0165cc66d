// The fitter's fast path (precomputed geometry, model.h) is the same function as the full model.
#include "fitting/model.h"

#include <gtest/gtest.h>

#include <random>

#include "fitting/sample.h"

namespace gonio::fitting {
namespace {

TEST(FixedGeometry, FactorTimesDTimesShadowingEqualsTheFullModel) {
  std::mt19937_64 rng(4);
  std::uniform_real_distribution<double> tl(0, 85), tv(-89, 89), phi(0, 360);
  int nonzero = 0;
  for (Family f : kAllFamilies)
    for (double width : {0.05, 0.344, 0.9}) {
      ModelSpec m{f};
      const double w = f == Family::kPhong ? *WidthFromAlphaEquivalent(f, width)
                                           : (f == Family::kSun2008 ? 2 / width : width);
      for (int k = 0; k < 2000; ++k) {
        const Sample s = SampleFromBenchAngles(tl(rng), phi(rng), tv(rng), phi(rng), 0, 1);
        const double full = MeasurementModel(m, s.light, s.view, w, 0.7, 1.51);
        const FixedGeometry g = PrecomputeGeometry(s.light, s.view, 1.51);
        const double fast = g.factor > 0 ? 0.7 * g.factor * DTimesShadowing(m, g, w) : 0.0;
        ASSERT_NEAR(fast, full, 1e-12 * (1 + std::abs(full))) << Name(f) << " width " << w;
        nonzero += full > 0;
      }
    }
  EXPECT_GT(nonzero, 5000);  // about 30 % of random pairs have a refracting facet
}

TEST(FixedGeometry, ReflectionSamplesTakeTheBrdfOnTheSameFastPath) {
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> tl(0, 85), tv(-89, 89), phi(0, 360);
  int nonzero = 0;
  for (Family f : {Family::kBeckmann, Family::kGgx, Family::kPhong})
    for (double width : {0.05, 0.344, 0.9}) {
      ModelSpec m{f};
      const double w = f == Family::kPhong ? *WidthFromAlphaEquivalent(f, width) : width;
      for (int k = 0; k < 2000; ++k) {
        const Sample s = SampleFromReflectionAngles(tl(rng), phi(rng), tv(rng), phi(rng), 0, 1);
        ASSERT_TRUE(IsReflection(s));
        const double full = MeasurementModel(m, s.light, s.view, w, 0.7, 1.51);
        const FixedGeometry g = PrecomputeGeometry(s.light, s.view, 1.51);
        const double fast = g.factor > 0 ? 0.7 * g.factor * DTimesShadowing(m, g, w) : 0.0;
        ASSERT_NEAR(fast, full, 1e-12 * (1 + std::abs(full))) << Name(f) << " width " << w;
        nonzero += full > 0;
      }
    }
  EXPECT_GT(nonzero, 17000);  // every pair on the air side has its mirror facet
  EXPECT_FALSE(HasBrdf(Family::kSun2008));
}

// Eq. 20 written out here from its parts, independently of microfacet.h: Beckmann's D (eq. 25),
// Smith's exact G1 (eq. 26, with erf) and the unpolarised Fresnel reflectance of a dielectric.
TEST(Model, TheReflectionSampleIsEquation20AtTheMirrorAngles) {
  const double alpha = 0.344, eta = 1.51, deg = optics::kPi / 180;
  auto fresnel = [&](double c) {
    const double g = std::sqrt(eta * eta - 1 + c * c);
    const double a = (g - c) / (g + c), b = (c * (g + c) - 1) / (c * (g - c) + 1);
    return 0.5 * a * a * (1 + b * b);
  };
  auto g1 = [&](double theta) {
    const double a = 1 / (alpha * std::tan(theta));
    return 2 / (1 + std::erf(a) + std::exp(-a * a) / (a * std::sqrt(optics::kPi)));
  };
  for (const auto& [tl, tv] : {std::pair{30.0, 30.0}, {30.0, 50.0}, {60.0, 20.0}, {10.0, -40.0}}) {
    const Sample s = SampleFromReflectionAngles(tl, 0, tv, 0, 0, 1);
    // The view is theta_v from +n on the far side of the normal from the light.
    EXPECT_NEAR(s.view.z, std::cos(tv * deg), 1e-12);
    EXPECT_NEAR(s.view.x, -std::sin(tv * deg), 1e-12);
    EXPECT_NEAR(ThetaViewDeg(s), tv, 1e-9);
    // In the plane of incidence the half vector bisects l and v: polar angle (tl - tv) / 2.
    const double th = (tl - tv) / 2 * deg, ti = (tl + tv) / 2 * deg;  // ti: angle to the facet
    const double t = std::tan(th);
    const double d = std::exp(-t * t / (alpha * alpha)) /
                     (optics::kPi * alpha * alpha * std::pow(std::cos(th), 4));
    const double f_r = fresnel(std::cos(ti)) * g1(tl * deg) * g1(std::abs(tv) * deg) * d /
                       (4 * std::cos(tl * deg) * std::cos(tv * deg));
    const double model = MeasurementModel(ModelSpec{}, s.light, s.view, alpha, 2.0, eta);
    EXPECT_NEAR(model / (2.0 * f_r * std::cos(tl * deg)), 1.0, 1e-9) << tl << ", " << tv;
  }
}

TEST(Model, AlphaEquivalentRoundTripsAndMatchesTheMappings) {
  for (Family f : kAllFamilies)
    for (double a : {0.02, 0.344, 0.9}) {
      auto w = WidthFromAlphaEquivalent(f, a);
      ASSERT_TRUE(w.has_value());
      EXPECT_NEAR(AlphaEquivalent(f, *w), a, 1e-12);
    }
  EXPECT_NEAR(*WidthFromAlphaEquivalent(Family::kPhong, 0.2), 48.0, 1e-12);  // 2/0.04 - 2
  EXPECT_NEAR(*WidthFromAlphaEquivalent(Family::kSun2008, 0.5), 4.0, 1e-12);
  EXPECT_FALSE(WidthFromAlphaEquivalent(Family::kPhong, 1.2).has_value());
  EXPECT_EQ(ParseFamily("ggx"), Family::kGgx);
  EXPECT_FALSE(ParseFamily("GGX").has_value());
}

}  // namespace
}  // namespace gonio::fitting
