// Degenerate and extreme inputs: every evaluation is finite, and each case has the documented
// result of microfacet.h's header.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>

#include "optics/microfacet.h"
#include "optics/sun2008.h"

namespace gonio::optics {
namespace {

constexpr double kDeg = kPi / 180;

template <typename Dist>
void ExpectAllFinite(const Dist& d, double eta, const char* what) {
  for (Masking masking : {Masking::kSeparable, Masking::kHeightCorrelated}) {
    RoughDielectricBsdf<Dist> bsdf(d, eta, masking);
    // Angles from 0 to 180 deg in the x-z plane, including exactly 90 (the horizon) and values a
    // hair from it, and out-of-plane views.
    std::vector<double> angles;
    for (double t = 0; t <= 180.0; t += 0.5) angles.push_back(t);
    for (double t : {89.999999, 90.000001, 1e-9, 180 - 1e-9}) angles.push_back(t);
    for (double ti : angles)
      for (double to : angles)
        for (double phi : {0.0, 90.0, 180.0}) {
          const Vec3<double> i = DirectionInPlane(ti * kDeg);
          const double t = to * kDeg;
          const Vec3<double> o = SphericalDirection(std::sin(t), std::cos(t), phi * kDeg);
          const double fr = bsdf.Brdf(i, o), ft = bsdf.Btdf(i, o), p = bsdf.Pdf(i, o);
          ASSERT_TRUE(std::isfinite(fr) && std::isfinite(ft) && std::isfinite(p))
              << what << " eta " << eta << " ti " << ti << " to " << to << " phi " << phi << ": fr "
              << fr << " ft " << ft << " pdf " << p;
          ASSERT_GE(fr, 0.0);
          ASSERT_GE(ft, 0.0);
        }
  }
}

TEST(Stability, NoNanOrInfForAnyAngleAtExtremeWidths) {
  for (double eta : {1.51, 1 / 1.51, 1.0}) {
    for (double a : {1e-3, 0.02, 2.0}) {
      ExpectAllFinite(BeckmannDistribution<double>(a), eta, "Beckmann");
      ExpectAllFinite(BeckmannDistribution<double>(a, SmithG1::kRational), eta, "Beckmann-rat");
      ExpectAllFinite(GgxDistribution<double>(a), eta, "GGX");
    }
    for (double e : {0.0, 1e6}) ExpectAllFinite(PhongDistribution<double>(e), eta, "Phong");
  }
}

TEST(Stability, SamplingNeverReturnsNonFiniteValues) {
  std::mt19937_64 rng(9);
  std::uniform_real_distribution<double> u(0, 1);
  for (double a : {1e-3, 2.0})
    for (double ti : {0.0, 89.999, 90.0, 90.001, 179.0}) {
      RoughDielectricBsdf<GgxDistribution<double>> bsdf(GgxDistribution<double>(a), 1.51);
      const Vec3<double> i = DirectionInPlane(ti * kDeg);
      for (NormalSampling how :
           {NormalSampling::kDistribution, NormalSampling::kWidened, NormalSampling::kVisible})
        for (int k = 0; k < 20000; ++k) {
          auto s = bsdf.Sample(i, u(rng), {u(rng), u(rng)}, how);
          if (!s) continue;
          ASSERT_TRUE(std::isfinite(s->f) && std::isfinite(s->pdf) && std::isfinite(s->weight) &&
                      std::isfinite(s->wo.z))
              << "alpha " << a << " ti " << ti;
        }
    }
}

using Bsdf = RoughDielectricBsdf<BeckmannDistribution<double>>;

TEST(Stability, ExactlyGrazingDirectionsGiveZero) {
  Bsdf bsdf(BeckmannDistribution<double>(0.344), 1.51);
  const Vec3<double> horizon{1, 0, 0}, up{0, 0, 1}, down{0, 0, -1};
  EXPECT_EQ(bsdf.Btdf(horizon, down), 0.0);
  EXPECT_EQ(bsdf.Btdf(up, horizon), 0.0);
  EXPECT_EQ(bsdf.Brdf(horizon, up), 0.0);
  EXPECT_EQ(bsdf.Pdf(horizon, down), 0.0);
  EXPECT_FALSE(bsdf.Sample(horizon, 0.5, {0.5, 0.5}).has_value());
}

TEST(Stability, SameSideGivesNoTransmissionAndOppositeSidesNoReflection) {
  Bsdf bsdf(BeckmannDistribution<double>(0.344), 1.51);
  const Vec3<double> a = DirectionInPlane(20 * kDeg), b = DirectionInPlane(-30 * kDeg);
  EXPECT_EQ(bsdf.Btdf(a, b), 0.0);
  EXPECT_GT(bsdf.Brdf(a, b), 0.0);
  const Vec3<double> c = DirectionInPlane(170 * kDeg);
  EXPECT_EQ(bsdf.Brdf(a, c), 0.0);
  EXPECT_GT(bsdf.Btdf(a, c), 0.0);
}

TEST(Stability, EqualIndicesGiveZeroNotNan) {
  // h_t = -(i + o) is undefined for o = -i: the transmission is a delta, not a function.
  Bsdf bsdf(BeckmannDistribution<double>(0.344), 1.0);
  const Vec3<double> i = DirectionInPlane(30 * kDeg);
  EXPECT_EQ(bsdf.Btdf(i, -i), 0.0);
  EXPECT_EQ(bsdf.Btdf(i, DirectionInPlane(200 * kDeg)), 0.0);
  EXPECT_EQ(bsdf.Brdf(i, DirectionInPlane(-30 * kDeg)), 0.0);  // F = 0 at equal indices
  EXPECT_EQ(Sun2008Btdf(i, -i, 3.0, 1.0), 0.0);
}

TEST(Stability, StraightThroughIsFiniteAndPositive) {
  // i = -o at eta != 1: refraction through the facet m = i, at normal facet incidence.
  Bsdf bsdf(BeckmannDistribution<double>(0.344), 1.51);
  for (double t : {0.0, 30.0, 60.0}) {
    const Vec3<double> i = DirectionInPlane(t * kDeg);
    const double f = bsdf.Btdf(i, -i);
    EXPECT_TRUE(std::isfinite(f));
    EXPECT_GT(f, 0.0) << t;
  }
}

TEST(Stability, TotalInternalReflectionFromTheGlassSide) {
  // Light from the glass at 60 deg (beyond the 41.5 deg critical angle) onto a nearly smooth
  // surface: no transmission near the mirror configuration, and the specular reflection has F = 1.
  Bsdf bsdf(BeckmannDistribution<double>(0.01), 1.51);
  const Vec3<double> i = DirectionInPlane(180 * kDeg - 60 * kDeg);  // below, 60 deg from -z
  const Vec3<double> mirror{-i.x, -i.y, i.z};
  const double fr = bsdf.Brdf(i, mirror);
  EXPECT_GT(fr, 0.0);
  // With F = 1 the BRDF is exactly G D / (4 cos cos).
  const double g_d = BeckmannDistribution<double>(0.01).D({0, 0, 1}) *
                     std::pow(BeckmannDistribution<double>(0.01).G1(i), 2) /
                     (4 * std::cos(60 * kDeg) * std::cos(60 * kDeg));
  EXPECT_NEAR(fr / g_d, 1.0, 1e-12);
  EXPECT_EQ(bsdf.Btdf(i, DirectionInPlane(-60 * kDeg)), 0.0);
}

TEST(Stability, SunModelIsFiniteEverywhere) {
  for (double s : {0.1, 0.5, 3.0, 1e3})
    for (double ti = 0; ti <= 180; ti += 1)
      for (double to = 0; to <= 180; to += 1) {
        const double f =
            Sun2008Btdf(DirectionInPlane(ti * kDeg), DirectionInPlane(-to * kDeg), s, 1.4);
        ASSERT_TRUE(std::isfinite(f)) << s << " " << ti << " " << to;
      }
}

}  // namespace
}  // namespace gonio::optics
