// The optics layer is templated on the scalar so that Ceres' automatic differentiation flows
// through it: derivatives of the BTDF with respect to alpha and eta, from Jets, match central
// finite differences.
#include <ceres/jet.h>
#include <gtest/gtest.h>

#include "optics/microfacet.h"
#include "optics/sun2008.h"

namespace gonio::optics {
namespace {

constexpr double kDeg = kPi / 180;
using Jet2 = ceres::Jet<double, 2>;

template <template <typename> class Dist>
void ExpectJetDerivativesMatchFiniteDifferences(const char* name) {
  const Vec3<double> i = DirectionInPlane(20 * kDeg);
  for (double to : {150.0, 175.0, 200.0}) {
    const Vec3<double> o = DirectionInPlane(to * kDeg);
    const double alpha = 0.344, eta = 1.51;
    auto f = [&](double a, double e) {
      return RoughDielectricBsdf<Dist<double>>(Dist<double>(a), e).Btdf(i, o);
    };
    const Jet2 ja(alpha, 0), je(eta, 1);
    const Jet2 fj =
        RoughDielectricBsdf<Dist<Jet2>>(Dist<Jet2>(ja), je).Btdf(Vec3<Jet2>(i), Vec3<Jet2>(o));
    const double h = 1e-6;
    const double dfa = (f(alpha + h, eta) - f(alpha - h, eta)) / (2 * h);
    const double dfe = (f(alpha, eta + h) - f(alpha, eta - h)) / (2 * h);
    EXPECT_NEAR(fj.a, f(alpha, eta), 1e-14);
    EXPECT_NEAR(fj.v[0], dfa, 1e-6 * (1 + std::abs(dfa))) << name << " d/dalpha at " << to;
    EXPECT_NEAR(fj.v[1], dfe, 1e-6 * (1 + std::abs(dfe))) << name << " d/deta at " << to;
  }
}

template <typename T>
using BeckmannExact = BeckmannDistribution<T>;

TEST(Jet, BeckmannBtdfDerivativesMatchFiniteDifferences) {
  ExpectJetDerivativesMatchFiniteDifferences<BeckmannExact>("Beckmann");
}
TEST(Jet, GgxBtdfDerivativesMatchFiniteDifferences) {
  ExpectJetDerivativesMatchFiniteDifferences<GgxDistribution>("GGX");
}

TEST(Jet, SunModelDerivativeInSmoothness) {
  const Vec3<double> i = DirectionInPlane(30 * kDeg), o = DirectionInPlane(190 * kDeg);
  const Jet2 fj = Sun2008Btdf(Vec3<Jet2>(i), Vec3<Jet2>(o), Jet2(3.0, 0), Jet2(1.4));
  const double h = 1e-6;
  const double d = (Sun2008Btdf(i, o, 3.0 + h, 1.4) - Sun2008Btdf(i, o, 3.0 - h, 1.4)) / (2 * h);
  EXPECT_NEAR(fj.v[0], d, 1e-6 * (1 + std::abs(d)));
}

}  // namespace
}  // namespace gonio::optics
