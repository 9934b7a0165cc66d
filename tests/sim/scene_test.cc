// The bench's scene: stage angles to directions, the traced pixels, what the image shows.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <utility>
#include <vector>

#include "common/bench_angles.h"
#include "sim/scene/scene.h"
#include "sim/sim_config.h"
#include "sim/truth/ground_truth.h"

namespace gonio::sim {
namespace {

constexpr double kDeg = M_PI / 180;

TEST(SceneTest, StageAnglesForSnellPutTheCameraOnTheRefractedDirection) {
  for (double ti : {0.0, 30.0, 60.0, 80.0}) {
    const double tt = std::asin(std::sin(ti * kDeg) / 1.51) / kDeg;
    const NominalGeometry g = Nominal(BenchGeometry{}, StageAnglesFor(ti, -tt));
    EXPECT_NEAR(g.l.x, std::sin(ti * kDeg), 1e-12);
    EXPECT_NEAR(g.l.z, std::cos(ti * kDeg), 1e-12);
    // Snell's law between the light and view directions (eta_above sin = eta_below sin).
    EXPECT_NEAR(std::hypot(g.l.x, g.l.y), 1.51 * std::hypot(g.v.x, g.v.y), 1e-12);
    EXPECT_LT(g.v.x * g.l.x, 1e-15);  // the other side of the normal
    EXPECT_TRUE(g.transmission);
  }
}

// The sample stage turned by d (the arm still) moves the transmitted lobe by
// (1 - cos theta_l / (eta cos theta_t)) d in the arm's angle: the sample frame turns by d and
// the refraction angle by d cos theta_l / (eta cos theta_t) within it (with eta = 1 the beam
// would go straight through whatever the sample does). So the scene's slope along the sample
// stage is minus that lever times its slope along the arm, on antiglare's flanks: why the
// sample stage's settling (+-0.5 step) moves a sweep's lobe by at most 0.6 of it
// (docs/measurement.md, antiglare's coverage).
TEST(SceneTest, TheSampleStageMovesTheRefractedLobeByItsLever) {
  const Scene scene(BenchGeometry{}, MicrofacetTruth("beckmann", 0.023, 1.51));
  const ImageRegion r;
  for (double ti : {0.0, 30.0, 60.0}) {
    const double tt = std::asin(std::sin(ti * kDeg) / 1.51) / kDeg;
    const double lever = 1 - std::cos(ti * kDeg) / (1.51 * std::cos(tt * kDeg));
    for (double off : {-0.5, -0.3, 0.3, 0.5}) {
      const StageAngles a = StageAnglesFor(ti, -tt + off);
      const double h = 1e-3;
      auto rate = [&](double d_sample, double d_arm) {
        StageAngles m = a;
        m.sample_deg += d_sample;
        m.arm_deg += d_arm;
        return scene.PixelRate(m, r, 256, 256);
      };
      const double along_sample = rate(h, 0) - rate(-h, 0);
      const double along_arm = rate(0, h) - rate(0, -h);
      // The lever is the peak's; off it the lobe's shape changes with the incidence too (at 60
      // degrees 0.54-0.65 against 0.59 here).
      EXPECT_NEAR(along_sample / along_arm, -lever, ti < 45 ? 0.015 : 0.07) << ti << ", " << off;
    }
  }
}

TEST(SceneTest, RayThroughTheCentreSeesTheNominalDirections) {
  const Scene scene(BenchGeometry{}, MicrofacetTruth("beckmann", 0.3, 1.51));
  const StageAngles a = StageAnglesFor(30, -10);
  const NominalGeometry g = Nominal(scene.bench(), a);
  const auto ray = scene.Trace(a, 0, 0);
  ASSERT_TRUE(ray.has_value());
  EXPECT_NEAR(Dot(ray->v, g.v), 1.0, 1e-12);  // through O: no refraction at the sphere
  EXPECT_NEAR(Dot(ray->l, g.l), 1.0, 1e-12);  // hit point at O for a 6 mm sample
  EXPECT_NEAR(ray->exit_transmittance, 1.0, 1e-12);
}

// A reflection geometry: the camera on the light side sees the rough face directly, the centre
// pixel along the nominal directions, and the image follows the truth's BRDF * cos theta_l from
// view to view (eq. 20), peaking at the specular direction. The expected ratio is computed here
// from D and eq. 20's 1/|o.n| alone; F and G change by under 2 % over these views, inside the
// tolerance.
TEST(SceneTest, ReflectionViewsSeeTheRoughFaceWithTheTruthsBrdf) {
  const Scene scene(BenchGeometry{}, MicrofacetTruth("beckmann", 0.3, 1.51));
  const ImageRegion region;
  auto at = [](double tl, double tv) {
    const StageTargets t = StageTargetsForReflection(tl, tv);
    return StageAngles{t.sample_deg, t.arm_deg, 0};
  };
  const StageAngles specular = at(30, 30);
  const NominalGeometry g = Nominal(scene.bench(), specular);
  EXPECT_FALSE(g.transmission);
  const auto ray = scene.Trace(specular, 0, 0);
  ASSERT_TRUE(ray.has_value());
  EXPECT_NEAR(ray->v.x, -std::sin(30 * kDeg), 1e-12);  // mirror of l = (sin 30, 0, cos 30)
  EXPECT_NEAR(ray->v.z, std::cos(30 * kDeg), 1e-12);
  EXPECT_NEAR(Dot(ray->l, g.l), 1.0, 1e-12);
  auto centre = [&](double tv) { return scene.PixelRate(at(30, tv), region, 256, 256); };
  const double peak = centre(30);
  EXPECT_GT(peak, 5 * centre(-20));  // a lobe about the specular direction
  // (Beyond the specular direction the rate still rises a little: eq. 20's 1/|o.n|, the
  // off-specular peak of rough surfaces, which the ratios below include.)
  // Beckmann D at the half vector between l (30 deg) and v (theta_v), over eq. 20's |o.n|,
  // relative to the peak.
  auto d_ratio = [](double tv) {
    const double half = (tv - 30) / 2 * kDeg;  // the half vector's polar angle
    const double t = std::tan(half);
    return std::exp(-t * t / (0.3 * 0.3)) / std::pow(std::cos(half), 4) * std::cos(30 * kDeg) /
           std::cos(tv * kDeg);
  };
  for (double tv : {20.0, 40.0}) {
    const double stray = scene.options().stray_lens_e_per_s;
    EXPECT_NEAR((centre(tv) - stray) / (peak - stray), d_ratio(tv), 0.05 * d_ratio(tv))
        << "theta_v " << tv;
  }
  // A truth that holds transmission only shows stray light in reflection, never a made-up lobe.
  BtdfTable empty;
  const Scene tabulated(BenchGeometry{}, std::make_shared<TabulatedTruth>("table", empty));
  EXPECT_DOUBLE_EQ(tabulated.PixelRate(specular, region, 256, 256),
                   tabulated.options().stray_lens_e_per_s);
}

TEST(SceneTest, CentreOffsetMovesTheHitPointNotTheViewDirection) {
  BenchGeometry thick;
  thick.sample_thickness_mm = 9;  // centre 3 mm inside the glass
  const Scene scene(thick, MicrofacetTruth("beckmann", 0.3, 1.51));
  const StageAngles a = StageAnglesFor(0, 40);
  const auto ray = scene.Trace(a, 0, 0);
  ASSERT_TRUE(ray.has_value());
  EXPECT_NEAR(Dot(ray->v, Nominal(thick, a).v), 1.0, 1e-12);
  // The central ray leaves the rough surface 3 mm * tan(40 deg) from the axis.
  EXPECT_NEAR(std::abs(ray->hit_mm.x), 3 * std::tan(40 * kDeg), 1e-9);
  // ... so the light arrives from a slightly different direction (610 mm away).
  EXPECT_GT(std::acos(Dot(ray->l, Nominal(thick, a).l)), 1e-3);
}

TEST(SceneTest, OffAxisRayRefractsAtTheSphereBySnellsLaw) {
  const Scene scene(BenchGeometry{}, MicrofacetTruth("beckmann", 0.3, 1.51));
  const StageAngles a = StageAnglesFor(0, 0);
  const double u = 10;  // mm from the axis, on the object plane
  const auto ray = scene.Trace(a, u, 0);
  ASSERT_TRUE(ray.has_value());
  // Exact in the plane: the ray leaves the pinhole at gamma = atan(u / D); its distance from O
  // is p = D sin(gamma), so it meets the sphere at incidence i = asin(p / R), where the normal
  // is alpha = i - gamma off the axis, and refracts to r = asin(sin(i) / eta): in the glass it
  // runs at alpha - r to the axis.
  const double gamma = std::atan(u / 885), i = std::asin(885 * std::sin(gamma) / 37.5);
  const double deviation = (i - gamma) - std::asin(std::sin(i) / 1.51);
  const double polar = std::acos(-ray->v.z);
  EXPECT_NEAR(polar, deviation, 1e-9);
}

TEST(SceneTest, ImageIsDarkBesideTheLensAndUnderTheArmShadow) {
  SceneOptions o;
  const Scene scene(BenchGeometry{}, MicrofacetTruth("beckmann", 0.3, 1.51), o);
  ImageRegion r;
  EXPECT_EQ(scene.PixelRate(StageAnglesFor(0, 0), r, 0, 0), o.stray_background_e_per_s);
  EXPECT_GT(scene.PixelRate(StageAnglesFor(0, 0), r, 256, 256), 100 * o.stray_lens_e_per_s);
  // Reflection side: the camera beside the source (arm at 2 deg) shadows it.
  const StageAngles retro{20, 2, 0};
  EXPECT_TRUE(Nominal(scene.bench(), retro).arm_shadows_source);
  EXPECT_EQ(scene.PixelRate(retro, r, 256, 256), o.stray_lens_e_per_s);
}

// The beam block (#16 item 3): its flag covers the source beam from 45 to 135 deg, read from
// the axis's steps as the camera reads the stages; in the beam, every pixel sees the stray light
// alone, whatever the lobe, and the image is the stray light's wherever the lens is in view.
TEST(SceneTest, TheBeamBlockLeavesTheStrayLightAlone) {
  const SimConfig c = DefaultSimConfig();
  ASSERT_EQ(c.axes.back().role, "beam_block");
  std::vector<double> steps(c.axes.size(), 0.0);
  steps[1] = 0;  // the arm at 180 deg: straight through
  for (const auto& [deg, blocked] : std::vector<std::pair<double, bool>>{
           {0, false}, {44.9, false}, {45, true}, {90, true}, {135, true}, {135.1, false}}) {
    steps.back() = deg * c.axes.back().steps_per_degree;
    EXPECT_EQ(AnglesFromSteps(c.axes, steps).beam_blocked, blocked) << deg << " deg";
  }
  SceneOptions o;
  const Scene scene(BenchGeometry{}, MicrofacetTruth("beckmann", 0.3, 1.51), o);
  ImageRegion r;
  StageAngles a = StageAnglesFor(0, 0);
  EXPECT_GT(scene.PixelRate(a, r, 256, 256), 100 * o.stray_lens_e_per_s);
  a.beam_blocked = true;
  EXPECT_TRUE(Nominal(scene.bench(), a).source_hidden);
  EXPECT_EQ(scene.PixelRate(a, r, 256, 256), o.stray_lens_e_per_s);
  EXPECT_EQ(scene.PixelRate(a, r, 0, 0), o.stray_background_e_per_s);
  r.offset_x = 240, r.offset_y = 240, r.width = r.height = 32;
  const cv::Mat1d img = scene.Render(a, r);
  double lo = 0, hi = 0;
  cv::minMaxLoc(img, &lo, &hi);
  EXPECT_EQ(lo, o.stray_lens_e_per_s);
  EXPECT_EQ(hi, o.stray_lens_e_per_s);
}

TEST(SceneTest, BinnedPixelSumsItsSensorPixels) {
  const Scene scene(BenchGeometry{}, MicrofacetTruth("beckmann", 0.3, 1.51));
  const StageAngles a = StageAnglesFor(30, -5);
  ImageRegion r;
  r.offset_x = 250;
  r.offset_y = 240;
  r.width = r.height = 4;
  r.binning_h = r.binning_v = 2;
  const cv::Mat1d img = scene.Render(a, r);
  const double sum = scene.PixelRate(a, r, 252, 242) + scene.PixelRate(a, r, 253, 242) +
                     scene.PixelRate(a, r, 252, 243) + scene.PixelRate(a, r, 253, 243);
  // Render interpolates a wide lobe's aperture factor (within 1e-5, below); PixelRate averages.
  EXPECT_NEAR(img(1, 1), sum, 2e-5 * sum);
}

// docs/scene.md: the fixed rectangle's spread of directions biases the sample; small rectangles
// read the nominal value. Here the bias pinned for ground glass at normal incidence.
TEST(SceneTest, LargeRectangleReadsTheNarrowPeakLow) {
  const Scene scene(BenchGeometry{}, MicrofacetTruth("beckmann", 0.344, 1.51));
  const StageAngles a = StageAnglesFor(0, 0);
  auto ratio = [&](double w_mm, double h_mm) {
    ImageRegion r;
    r.sensor_width = r.sensor_height = 1024;
    r.mm_per_pixel = 0.1;
    r.width = static_cast<int>(w_mm / 0.1);
    r.height = static_cast<int>(h_mm / 0.1);
    r.offset_x = 512 - r.width / 2;
    r.offset_y = 512 - r.height / 2;
    const NominalGeometry g = Nominal(scene.bench(), a);
    return (cv::mean(scene.Render(a, r))[0] - scene.options().stray_lens_e_per_s) /
           (scene.options().electrons_per_s_per_unit * scene.truth().BtdfCos(g.l, g.v));
  };
  EXPECT_NEAR(ratio(0.4, 0.4), 1.0, 0.002);
  const double big = ratio(3, 10);
  EXPECT_LT(big, 0.985);
  EXPECT_GT(big, 0.95);
}

// A wide lobe's aperture factor is rendered on a grid of every 8th pixel and interpolated; the
// demo's 1 x 3 mm rectangle then reads within 1e-5 of averaging each of its pixels (PixelRate),
// on the peak, the flanks and the tails of three incidences.
TEST(SceneTest, ApertureFactorGridMatchesEveryPixel) {
  const Scene scene(BenchGeometry{}, MicrofacetTruth("beckmann", 0.344, 1.51));
  const ImageRegion region;
  double worst = 0;
  for (double ti : {0.0, 30.0, 60.0})
    for (double dv : {0.0, 5.0, -7.5, 15.0}) {
      const double tt = std::asin(std::sin(ti * kDeg) / 1.51) / kDeg;
      const StageAngles a = StageAnglesFor(ti, -tt + dv);
      const cv::Mat1d img = scene.Render(a, region);
      double grid = 0, each = 0;
      for (int row = 246; row < 246 + 19; ++row)
        for (int col = 253; col < 253 + 6; ++col) {
          grid += img(row, col);
          each += scene.PixelRate(a, region, col, row);
        }
      worst = std::max(worst, std::abs(grid / each - 1));
    }
  EXPECT_LT(worst, 1e-5);
  std::printf("worst relative difference %.2g\n", worst);
}

// A narrow lobe's cones are averaged over the whole rectangle even where they change its nominal
// pixel by nothing: on the ring where the lobe's curvature changes sign (antiglare at 60 deg,
// about 1 deg off its peak) the rest of the rectangle still needs them. Deciding at the nominal
// pixel alone read the demo's auto rectangle (2 x 6 px) 4.7 sigma off and 3 x 10 mm 30 sigma.
TEST(SceneTest, ANarrowLobesConesAreAveragedWhereTheyChangeOnlyTheNominalPixelByNothing) {
  const auto truth = MicrofacetTruth("beckmann", 0.023, 1.51);
  SceneOptions o;
  o.stray_lens_e_per_s = o.stray_background_e_per_s = 0;
  SceneOptions always = o;
  always.aperture_tolerance = 0;  // every lit frame averaged: the reference
  const Scene scene(BenchGeometry{}, truth, o), reference(BenchGeometry{}, truth, always);
  // The ring: where the cones change the nominal pair least, on the lobe's near flank.
  const double tt = std::asin(std::sin(60 * kDeg) / 1.51) / kDeg;
  StageAngles ring{};
  double least = 1;
  for (double dv = -1.5; dv <= -0.5; dv += 0.002) {
    const StageAngles a = StageAnglesFor(60, -tt + dv);
    const NominalGeometry g = Nominal(scene.bench(), a);
    const double change = ApertureMatters(*truth, g.l, g.v, o.apertures, 0).relative_change;
    if (change < least) least = change, ring = a;
  }
  ASSERT_LT(least, o.aperture_tolerance) << "no ring found: the test would not test the case";
  for (auto [w, h] : {std::pair{2, 6}, std::pair{19, 62}}) {
    ImageRegion r;
    r.offset_x = 256 - w / 2;
    r.offset_y = 256 - h / 2;
    r.width = w;
    r.height = h;
    const double got = cv::mean(scene.Render(ring, r))[0] / o.electrons_per_s_per_unit;
    const double want = cv::mean(reference.Render(ring, r))[0] / o.electrons_per_s_per_unit;
    // The demo's sigma: 0.05 % of the value and 0.002 absolute.
    EXPECT_LT(std::abs(got - want), 0.05 * std::hypot(5e-4 * want, 2e-3))
        << w << " x " << h << " px: " << got << " against " << want;
  }
}

}  // namespace
}  // namespace gonio::sim
