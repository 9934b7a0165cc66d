// Chi-square goodness-of-fit of every sampler against its density (Walter 2007 eq. 24, 28-40;
// Heitz 2018 for GGX visible normals): microfacet normals alone, then whole scattered directions,
// including grazing incidence and light from the glass side (total internal reflection).
#include <gtest/gtest.h>

#include <random>
#include <string>

#include "optics/microfacet.h"
#include "tests/fitting/chi2.h"

namespace gonio::optics {
namespace {

using testing::Chi2Options;
using testing::RunChi2;
using testing::SidakLevel;

constexpr double kDeg = kPi / 180;
constexpr double kEta = 1.51;

// Total number of chi-square tests in this file, for the multiple-test correction.
constexpr int kNumNormalTests = 3 + 3 + 3 + 4 + 8 + 4 + 1;
constexpr int kNumDirectionTests = 3 * 7 + 5 * 3;
const double kLevel = SidakLevel(kNumNormalTests + kNumDirectionTests);

enum class Family { kBeckmann, kGgx, kPhong };

std::string Name(Family f) {
  switch (f) {
    case Family::kBeckmann:
      return "Beckmann";
    case Family::kGgx:
      return "GGX";
    case Family::kPhong:
      return "Phong";
  }
  return "?";
}

// ---- Microfacet normals: m ~ p_m(m) -----------------------------------------------------------

template <typename Dist>
void ExpectNormalsFollowPdf(const Dist& d, const std::string& what) {
  std::uniform_real_distribution<double> u(0, 1);
  const auto r = RunChi2(
      [&](std::mt19937_64& rng) -> std::optional<Vec3<double>> {
        return d.SampleWm({u(rng), u(rng)});
      },
      [&](const Vec3<double>& m) { return d.PdfWm(m); });
  EXPECT_TRUE(r.failure.empty()) << what << ": " << r.Describe();
  EXPECT_GT(r.p_value, kLevel) << what << ": " << r.Describe();
  EXPECT_NEAR(r.expected_mass, 1.0, 1e-3) << what;
}

TEST(SampleNormals, BeckmannEq28FollowsDCos) {
  for (double a : {0.1, 0.344, 0.8})
    ExpectNormalsFollowPdf(BeckmannDistribution<double>(a), "Beckmann " + std::to_string(a));
}
TEST(SampleNormals, GgxEq35FollowsDCos) {
  for (double a : {0.1, 0.344, 0.8})
    ExpectNormalsFollowPdf(GgxDistribution<double>(a), "GGX " + std::to_string(a));
}
TEST(SampleNormals, PhongEq31FollowsDCos) {
  for (double e : {4.0, 14.9, 200.0})
    ExpectNormalsFollowPdf(PhongDistribution<double>(e), "Phong " + std::to_string(e));
}

TEST(SampleNormals, GgxVisibleNormalsFollowDvis) {
  std::uniform_real_distribution<double> u(0, 1);
  for (double tv : {0.0, 60.0, 85.0, 120.0}) {  // 120: seen from below
    GgxDistribution<double> d(0.344);
    const Vec3<double> v = DirectionInPlane(tv * kDeg);
    const auto r = RunChi2(
        [&](std::mt19937_64& rng) -> std::optional<Vec3<double>> {
          return d.SampleVisibleWm(v, {u(rng), u(rng)});
        },
        [&](const Vec3<double>& m) { return d.PdfVisibleWm(v, m); });
    EXPECT_GT(r.p_value, kLevel) << "theta_v " << tv << ": " << r.Describe();
    EXPECT_NEAR(r.expected_mass, 1.0, 1e-3);
  }
}

TEST(SampleNormals, BeckmannVisibleNormalsFollowDvis) {
  std::uniform_real_distribution<double> u(0, 1);
  for (double a : {0.1, 0.8})
    for (double tv : {0.0, 60.0, 85.0, 120.0}) {
      BeckmannDistribution<double> d(a);
      const Vec3<double> v = DirectionInPlane(tv * kDeg);
      const auto r = RunChi2(
          [&](std::mt19937_64& rng) -> std::optional<Vec3<double>> {
            return d.SampleVisibleWm(v, {u(rng), u(rng)});
          },
          [&](const Vec3<double>& m) { return d.PdfVisibleWm(v, m); });
      EXPECT_GT(r.p_value, kLevel) << "alpha " << a << " theta_v " << tv << ": " << r.Describe();
      EXPECT_NEAR(r.expected_mass, 1.0, 1e-3) << "alpha " << a << " theta_v " << tv;
    }
}

TEST(SampleNormals, BeckmannVisibleNormalsBelowTheHorizonFollowSmithsExtendedDvis) {
  // Mid-walk a ray may meet the surface from below the mean plane (Heitz et al. 2016): the
  // unflipped sampler and density, with the projected area |cos| Lambda(-w).
  std::uniform_real_distribution<double> u(0, 1);
  for (double tv : {30.0, 95.0, 120.0, 150.0}) {
    BeckmannDistribution<double> d(0.6);
    const Vec3<double> v = DirectionInPlane(tv * kDeg);
    const auto r = RunChi2(
        [&](std::mt19937_64& rng) -> std::optional<Vec3<double>> {
          return d.SampleVisibleUnflipped(v, {u(rng), u(rng)});
        },
        [&](const Vec3<double>& m) { return d.PdfVisibleUnflipped(v, m); });
    EXPECT_GT(r.p_value, kLevel) << "theta_v " << tv << ": " << r.Describe();
    EXPECT_NEAR(r.expected_mass, 1.0, 1e-3) << "theta_v " << tv;
  }
}

TEST(ErfInv, InvertsErfToDoublePrecision) {
  for (double x = -0.999999; x < 1; x += 0.0137) EXPECT_NEAR(std::erf(ErfInv(x)), x, 1e-15) << x;
  // Reference values from scipy.special.erfinv.
  EXPECT_NEAR(ErfInv(0.5), 0.4769362762044699, 1e-15);
  EXPECT_NEAR(ErfInv(-0.999999), -3.458910737275499, 1e-12);
  EXPECT_NEAR(ErfInv(1 - 1e-15), 5.675915739744713, 1e-9);
}

TEST(SampleNormals, WidenedBeckmannFollowsItsOwnDCos) {
  BeckmannDistribution<double> d(0.344);
  const Vec3<double> grazing = DirectionInPlane(89 * kDeg);
  ExpectNormalsFollowPdf(d.Widened(grazing), "widened Beckmann at 89 deg");
  EXPECT_NEAR(d.Widened(grazing).alpha(), (1.2 - 0.2 * std::sqrt(std::cos(89 * kDeg))) * 0.344,
              1e-15);
}

// ---- Scattered directions: o ~ p_o(o) given i (eq. 38-40) --------------------------------------

struct DirectionCase {
  Family family;
  double width;  // alpha, or Phong exponent
  NormalSampling how;
  double theta_i_deg;  // > 90: light arrives from the glass side
};

std::string Describe(const DirectionCase& c) {
  const char* how = c.how == NormalSampling::kDistribution ? "D"
                    : c.how == NormalSampling::kWidened    ? "widened"
                                                           : "visible";
  return Name(c.family) + " width " + std::to_string(c.width) + " sampling " + how + " theta_i " +
         std::to_string(c.theta_i_deg);
}

template <typename Dist>
testing::Chi2Result RunDirectionChi2(const Dist& d, const DirectionCase& c) {
  RoughDielectricBsdf<Dist> bsdf(d, kEta);
  const Vec3<double> wi = DirectionInPlane(c.theta_i_deg * kDeg);
  std::uniform_real_distribution<double> u(0, 1);
  Chi2Options opt;
  opt.seed = 1234 + static_cast<std::uint64_t>(c.theta_i_deg * 10);
  return RunChi2(
      [&](std::mt19937_64& rng) -> std::optional<Vec3<double>> {
        const double uc = u(rng);
        const Point2 uv{u(rng), u(rng)};
        auto s = bsdf.Sample(wi, uc, uv, c.how);
        if (!s) return std::nullopt;
        return s->wo;
      },
      [&](const Vec3<double>& wo) { return bsdf.Pdf(wi, wo, c.how); }, opt);
}

class SampleDirections : public ::testing::TestWithParam<DirectionCase> {};

TEST_P(SampleDirections, FollowTheirPdf) {
  const DirectionCase& c = GetParam();
  testing::Chi2Result r;
  switch (c.family) {
    case Family::kBeckmann:
      r = RunDirectionChi2(BeckmannDistribution<double>(c.width), c);
      break;
    case Family::kGgx:
      r = RunDirectionChi2(GgxDistribution<double>(c.width), c);
      break;
    case Family::kPhong:
      r = RunDirectionChi2(PhongDistribution<double>(c.width), c);
      break;
  }
  EXPECT_TRUE(r.failure.empty()) << Describe(c) << ": " << r.Describe();
  EXPECT_GT(r.p_value, kLevel) << Describe(c) << ": " << r.Describe();
  // The returned fraction equals the pdf's mass (what is declined is the pdf's missing mass).
  const double returned = double(r.returned) / 1e6;
  EXPECT_NEAR(returned, r.expected_mass, 5e-3) << Describe(c);
  EXPECT_LE(r.expected_mass, 1.0 + 1e-3) << Describe(c);
}

std::vector<DirectionCase> DirectionCases() {
  std::vector<DirectionCase> cases;
  // Every family with its own D sampling: normal, oblique, grazing (80, 89) from air, and from the
  // glass side below and beyond the critical angle (41.5 deg for eta 1.51).
  const double angles[] = {0.0, 45.0, 80.0, 89.0, 160.0, 130.0, 100.0};
  for (double t : angles) {
    cases.push_back({Family::kBeckmann, 0.344, NormalSampling::kDistribution, t});
    cases.push_back({Family::kGgx, 0.344, NormalSampling::kDistribution, t});
    cases.push_back({Family::kPhong, 14.9, NormalSampling::kDistribution, t});
  }
  // Widened and visible-normal sampling, a narrower and a wider lobe.
  for (double t : {0.0, 85.0, 130.0}) {
    cases.push_back({Family::kBeckmann, 0.344, NormalSampling::kWidened, t});
    cases.push_back({Family::kGgx, 0.344, NormalSampling::kVisible, t});
    cases.push_back({Family::kGgx, 0.1, NormalSampling::kVisible, t});
    cases.push_back({Family::kBeckmann, 0.8, NormalSampling::kWidened, t});
    cases.push_back({Family::kBeckmann, 0.344, NormalSampling::kVisible, t});
  }
  return cases;
}

INSTANTIATE_TEST_SUITE_P(Walter2007, SampleDirections, ::testing::ValuesIn(DirectionCases()));

TEST(SampleDirections, CaseCountMatchesTheCorrection) {
  EXPECT_EQ(static_cast<int>(DirectionCases().size()), kNumDirectionTests);
}

}  // namespace
}  // namespace gonio::optics
