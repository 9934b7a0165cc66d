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
