// The samplers' contracts at the edges (issue #21): every sampler maps the closed unit square to a
// finite unit normal above the horizon; the visible-normal pdf is the density that is drawn for
// each Smith G1 option; the unflipped Beckmann sampler serves its whole domain, grazing and
// steeply from below the mean plane included. The densities are checked by chi-square against
// quadrature of the pdf (tests/fitting/chi2.h), and the pdf's total mass against 1.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "optics/microfacet.h"
#include "tests/fitting/chi2.h"

namespace gonio::optics {
namespace {

using testing::Chi2Options;
using testing::RunChi2;
using testing::SidakLevel;

constexpr double kDeg = kPi / 180;
constexpr double kEps = 0x1.0p-53;  // the step below 1
// The chi-square tests in this file, for the multiple-test correction.
constexpr int kNumChi2 = 2 * 2 * 2 + 4;
const double kLevel = SidakLevel(kNumChi2);

// The corners and edges of [0, 1]^2, with the points just inside them.
std::vector<Point2> EdgePoints() {
  std::vector<Point2> out;
  const double ends[] = {0.0, kEps, 0.5, 1 - kEps, 1.0};
  for (double a : ends)
    for (double b : ends) out.push_back({a, b});
  for (int k = 0; k <= 16; ++k) {
    const double t = k / 16.0;
    for (double e : {0.0, 1.0}) {
      out.push_back({e, t});
      out.push_back({t, e});
    }
  }
  return out;
}

std::string Where(const std::string& what, Point2 u) {
  return what + " at u = (" + std::to_string(u.x) + ", " + std::to_string(u.y) + ")";
}

// A normal the samplers promise: finite, unit length, strictly above the horizon.
void ExpectValidNormal(const Vec3<double>& m, const std::string& where) {
  ASSERT_TRUE(std::isfinite(m.x) && std::isfinite(m.y) && std::isfinite(m.z))
      << where << ": (" << m.x << ", " << m.y << ", " << m.z << ")";
  EXPECT_NEAR(Length(m), 1.0, 1e-12) << where;
  EXPECT_GT(m.z, 0.0) << where;
}

template <typename Dist>
void ExpectSampleWmValidOnTheSquare(const Dist& d, const std::string& what) {
  for (Point2 u : EdgePoints()) {
    const Vec3<double> m = d.SampleWm(u);
    ExpectValidNormal(m, Where(what, u));
    const double pdf = d.PdfWm(m);
    EXPECT_TRUE(std::isfinite(pdf) && pdf > 0) << Where(what, u) << ": pdf " << pdf;
  }
}

TEST(SamplerDomain, EverySamplerMapsTheClosedSquareAboveTheHorizon) {
  for (double a : {0.01, 0.344, 1.0, 3.0}) {
    ExpectSampleWmValidOnTheSquare(BeckmannDistribution<double>(a),
                                   "Beckmann " + std::to_string(a));
    ExpectSampleWmValidOnTheSquare(GgxDistribution<double>(a), "GGX " + std::to_string(a));
    ExpectSampleWmValidOnTheSquare(
        BeckmannDistribution<double>(a).Widened(DirectionInPlane(89 * kDeg)),
        "widened Beckmann " + std::to_string(a));
  }
  for (double e : {0.0, 4.0, 200.0, 1e5})
    ExpectSampleWmValidOnTheSquare(PhongDistribution<double>(e), "Phong " + std::to_string(e));
}

// eq. 31 sends xi_1 = 0 to the horizon, where Sample() would return a direction of pdf 0.
TEST(SamplerDomain, PhongAtXiZeroGivesADirectionWithPositivePdf) {
  const RoughDielectricBsdf<PhongDistribution<double>> bsdf(PhongDistribution<double>(14.9), 1.51);
  const Vec3<double> wi = DirectionInPlane(30 * kDeg);
  int returned = 0;
  for (double uc : {0.0, 0.5, 0.999})
    for (double uy : {0.0, 0.25, 0.5}) {
      const auto s = bsdf.Sample(wi, uc, {0.0, uy});
      if (!s) continue;  // a draw may be declined (no valid path); what is returned must be valid
      ++returned;
      EXPECT_GT(s->pdf, 0.0) << "uc " << uc << " uy " << uy;
      EXPECT_GT(s->wm.z, 0.0);
    }
  EXPECT_GT(returned, 0);
}

TEST(SamplerDomain, VisibleNormalSamplersGiveValidNormalsForEveryDirection) {
  for (double a : {0.05, 0.344, 1.0, 2.5})
    for (double tv : {0.0, 1e-6, 30.0, 60.0, 85.0, 89.9, 90.1, 95.0, 135.0, 170.0, 179.9}) {
      const Vec3<double> w = DirectionInPlane(tv * kDeg);
      const BeckmannDistribution<double> b(a);
      const GgxDistribution<double> g(a);
      for (Point2 u : EdgePoints()) {
        const std::string what = "alpha " + std::to_string(a) + " theta_v " + std::to_string(tv);
        const Vec3<double> mb = b.SampleVisibleWm(w, u);
        ExpectValidNormal(mb, Where("Beckmann visible " + what, u));
        const Vec3<double> mg = g.SampleVisibleWm(w, u);
        ExpectValidNormal(mg, Where("GGX visible " + what, u));
        for (const Vec3<double>* m : {&mb, &mg}) {
          const double pb = b.PdfVisibleWm(w, *m), pg = g.PdfVisibleWm(w, *m);
          EXPECT_TRUE(std::isfinite(pb) && std::isfinite(pg) && pb >= 0 && pg >= 0)
              << Where(what, u);
        }
      }
    }
}

// The unflipped sampler over its declared domain: every unit w with w.z > -1, grazing and from
// below the plane included; each normal is one that w sees (w.m >= 0, up to rounding where
// u.x = 0 puts it on the edge of the visible set, whose density is 0 there).
TEST(SamplerDomain, UnflippedBeckmannServesItsWholeDomain) {
  for (double a : {0.05, 0.3, 0.8, 2.5})
    for (double tv :
         {0.0, 30.0, 85.0, 89.99, 90.0, 90.01, 95.0, 120.0, 150.0, 170.0, 179.0, 179.99}) {
      const BeckmannDistribution<double> d(a);
      const Vec3<double> w = DirectionInPlane(tv * kDeg);
      for (Point2 u : EdgePoints()) {
        const std::string what = "alpha " + std::to_string(a) + " theta_w " + std::to_string(tv);
        const Vec3<double> m = d.SampleVisibleUnflipped(w, u);
        ExpectValidNormal(m, Where(what, u));
        EXPECT_GE(Dot(w, m), -1e-10) << Where(what, u);
      }
    }
}

// Draws through `sample`, counting non-finite normals instead of binning them.
struct Counted {
  long non_finite = 0;
};

template <typename Sampler, typename Pdf>
testing::Chi2Result Chi2OfNormals(const Sampler& sample, const Pdf& pdf, Counted* counted) {
  std::uniform_real_distribution<double> u(0, 1);
  Chi2Options opt;
  opt.n_samples = 200'000;
  return RunChi2(
      [&](std::mt19937_64& rng) -> std::optional<Vec3<double>> {
        const Vec3<double> m = sample(Point2{u(rng), u(rng)});
        if (!(std::isfinite(m.x) && std::isfinite(m.y) && std::isfinite(m.z))) {
          ++counted->non_finite;
          return std::nullopt;
        }
        return m;
      },
      pdf, opt);
}

// The visible-normal pdf is the density drawn, for each G1 option: the rational G1 (eq. 27)
// differs from the exact one by up to 0.35 %, which the pdf's total mass shows even where a
// chi-square of 200k samples could not.
TEST(SamplerDomain, BeckmannVisibleNormalPdfIsTheDrawnDensityForEachG1) {
  for (SmithG1 g1 : {SmithG1::kExact, SmithG1::kRational})
    for (double a : {0.3, 0.8})
      for (double tv : {60.0, 135.0}) {
        const BeckmannDistribution<double> d(a, g1);
        const Vec3<double> w = DirectionInPlane(tv * kDeg);
        Counted counted;
        const auto r =
            Chi2OfNormals([&](Point2 u) { return d.SampleVisibleWm(w, u); },
                          [&](const Vec3<double>& m) { return d.PdfVisibleWm(w, m); }, &counted);
        const std::string what = std::string(g1 == SmithG1::kExact ? "exact" : "rational") +
                                 " G1, alpha " + std::to_string(a) + " theta_v " +
                                 std::to_string(tv);
        EXPECT_EQ(counted.non_finite, 0) << what;
        EXPECT_TRUE(r.failure.empty()) << what << ": " << r.Describe();
        EXPECT_GT(r.p_value, kLevel) << what << ": " << r.Describe();
        EXPECT_NEAR(r.expected_mass, 1.0, 2e-4) << what << ": " << r.Describe();
      }
}

// Steeply from below the mean plane, where the erf-domain inversion ran out of precision (NaN
// for |cot theta| / alpha above about 4.7): the tail of the slopes, sampled exactly. The cases
// reach |cot theta| / alpha = 21, as far as the density itself is representable.
TEST(SamplerDomain, UnflippedBeckmannFollowsItsDensityFromSteeplyBelow) {
  for (const auto& [a, tv] : {std::pair{0.3, 150.0}, {0.3, 170.0}, {0.1, 150.0}, {0.1, 155.0}}) {
    const BeckmannDistribution<double> d(a);
    const Vec3<double> w = DirectionInPlane(tv * kDeg);
    Counted counted;
    const auto r =
        Chi2OfNormals([&](Point2 u) { return d.SampleVisibleUnflipped(w, u); },
                      [&](const Vec3<double>& m) { return d.PdfVisibleUnflipped(w, m); }, &counted);
    const std::string what = "alpha " + std::to_string(a) + " theta_w " + std::to_string(tv);
    EXPECT_EQ(counted.non_finite, 0) << what;
    EXPECT_TRUE(r.failure.empty()) << what << ": " << r.Describe();
    EXPECT_GT(r.p_value, kLevel) << what << ": " << r.Describe();
    EXPECT_NEAR(r.expected_mass, 1.0, 1e-3) << what << ": " << r.Describe();
  }
}

// Lambda where G1 is within rounding of 1: the stable form against the asymptotic expansion of
// erfc (Abramowitz and Stegun 7.1.23), erfc(a) = exp(-a^2) / (a sqrt(pi)) (1 + sum t_n) with
// t_n = (-1)^n (2n - 1)!! / (2a^2)^n, so Lambda = (exp(-a^2) / (a sqrt(pi)) - erfc(a)) / 2 =
// -exp(-a^2) / (a sqrt(pi)) sum t_n / 2.
TEST(SamplerDomain, BeckmannLambdaStaysAccurateWhereG1RoundsToOne) {
  for (double a : {8.0, 12.0, 20.0}) {
    const double lead = std::exp(-a * a) / (a * std::sqrt(kPi));
    double series = 0, term = 1;
    for (int n = 1; n < 8; ++n) {
      term *= -(2 * n - 1) / (2 * a * a);
      series -= term;  // erfc(a) = lead (1 + sum term_n): Lambda = -lead * sum(term_n) / 2
    }
    const double expected = 0.5 * lead * series;
    EXPECT_NEAR(SmithLambdaExactBeckmann(a) / expected, 1.0, 1e-6) << "a = " << a;
    EXPECT_EQ(1 / SmithG1ExactBeckmann(a) - 1, 0.0) << "the naive form cancels here";
  }
}

}  // namespace
}  // namespace gonio::optics
