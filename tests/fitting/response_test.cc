// The instrument response (fitting/response.h) against the simulated scene's rendering of the
// same rectangle (sim/scene/scene.h traces every pixel on its own path), and fits that use it.
#include <gtest/gtest.h>

#include <cmath>
#include <iostream>
#include <random>
#include <tuple>

#include "common/bench_angles.h"
#include "fitting/fitter.h"
#include "fitting/response.h"
#include "fitting/samples_csv.h"
#include "sim/scene/aperture.h"
#include "sim/scene/scene.h"
#include "sim/truth/ground_truth.h"

namespace gonio {
namespace {

constexpr double kDeg = M_PI / 180;

// A rectangle of w x h mm centred on the pole of a 512 x 512 sensor at 0.16 mm per pixel.
fitting::ResponseSetup CentredSetup(double w_mm, double h_mm, double thickness_mm) {
  fitting::ResponseSetup s;
  s.thickness_mm = thickness_mm;
  const int w = std::max(1, static_cast<int>(std::lround(w_mm / 0.16)));
  const int h = std::max(1, static_cast<int>(std::lround(h_mm / 0.16)));
  s.rectangle.x = 256 - w / 2;
  s.rectangle.y = 256 - h / 2;
  s.rectangle.width = w;
  s.rectangle.height = h;
  return s;
}

double Snell(double ti) { return std::asin(std::sin(ti * kDeg) / 1.51) / kDeg; }

fitting::StagePosition At(double ti, double view_offset) {
  const StageTargets t = StageTargetsFor(ti, -Snell(ti) + view_offset);
  return {t.sample_deg, t.arm_deg, t.azimuth_deg};
}

// The scene's rectangle mean (stray light off, apertures off) per unit of k.
double SceneRectangle(const sim::GroundTruth& truth, const fitting::ResponseSetup& s,
                      const fitting::StagePosition& at) {
  sim::BenchGeometry bench;
  bench.sample_thickness_mm = s.thickness_mm;
  sim::SceneOptions o;
  o.stray_lens_e_per_s = 0;
  o.stray_background_e_per_s = 0;
  o.aperture_tolerance = 1e9;
  const sim::Scene scene(bench, std::shared_ptr<const sim::GroundTruth>(&truth, [](auto*) {}), o);
  sim::ImageRegion region;
  region.offset_x = s.rectangle.x;
  region.offset_y = s.rectangle.y;
  region.width = s.rectangle.width;
  region.height = s.rectangle.height;
  const cv::Mat1d img = scene.Render({at.sample_deg, at.arm_deg, at.azimuth_deg}, region);
  return cv::mean(img)[0] / o.electrons_per_s_per_unit;
}

double ResponseRectangle(const sim::GroundTruth& truth, const fitting::Response& r) {
  double sum = 0;
  for (const auto& ray : r.rays) sum += ray.weight * truth.BtdfCos(ray.l, ray.v);
  return sum / r.pixels;
}

TEST(ResponseTest, TheRectangleMatchesTheScenesRenderingWithinATenthOfAPercent) {
  const auto truth = sim::MicrofacetTruth("beckmann", 0.344, 1.51);
  struct Case {
    double w, h, thickness, ti, offset;
  };
  const Case cases[] = {{3, 10, 6, 0, 0},   {10, 3, 6, 0, 10}, {3, 10, 3, 60, 10},
                        {10, 3, 9, 60, 10}, {1, 3, 6, 30, -5}, {3, 10, 9, 80, -5}};
  double largest_effect = 0;
  for (const Case& c : cases) {
    const auto setup = CentredSetup(c.w, c.h, c.thickness);
    const auto at = At(c.ti, c.offset);
    auto r = fitting::ComputeResponse(setup, at, /*max_rays=*/0);
    ASSERT_TRUE(r.ok()) << r.error().message;
    const double scene = SceneRectangle(*truth, setup, at);
    const double response = ResponseRectangle(*truth, *r);
    ASSERT_GT(scene, 0);
    EXPECT_NEAR(response / scene, 1.0, 1e-3)
        << c.w << "x" << c.h << " mm, " << c.thickness << " mm, ti " << c.ti << ", +" << c.offset;
    const double nominal = truth->BtdfCos(r->l0, r->v0);
    largest_effect = std::max(largest_effect, std::abs(scene / nominal - 1));
  }
  // The cases are ones where the rectangle matters: the point model is off by percents.
  EXPECT_GT(largest_effect, 0.02);
}

TEST(ResponseTest, BlocksOfPixelsApproximateEveryPixel) {
  const auto truth = sim::MicrofacetTruth("beckmann", 0.344, 1.51);
  const auto setup = CentredSetup(10, 10, 6);  // 62 x 62 pixels
  const auto at = At(30, 8);
  auto all = fitting::ComputeResponse(setup, at, 0);
  auto some = fitting::ComputeResponse(setup, at, 64);
  ASSERT_TRUE(all.ok() && some.ok());
  EXPECT_LE(some->rays.size(), 64u);
  EXPECT_GT(all->rays.size(), 3000u);
  EXPECT_NEAR(ResponseRectangle(*truth, *some) / ResponseRectangle(*truth, *all), 1.0, 3e-3);
}

TEST(ResponseTest, TheAperturesOfANarrowLobeMatchAFineQuadrature) {
  // Antiglare (alpha 0.023): the cones change the peak by a fifth (docs/scene.md).
  const auto truth = sim::MicrofacetTruth("beckmann", 0.023, 1.51);
  const auto setup = CentredSetup(0.16, 0.16, 6);  // one pixel at the pole
  for (double offset : {0.0, 0.3}) {
    const auto at = At(0, offset);
    auto r = fitting::ComputeResponseWithApertures(setup, at);
    ASSERT_TRUE(r.ok()) << r.error().message;
    // The one pixel's own ray (its centre is 0.08 mm off the pole), averaged finely.
    auto base = fitting::ComputeResponse(setup, at);
    ASSERT_TRUE(base.ok() && base->rays.size() == 1u);
    const auto& ray = base->rays[0];
    const double fine =
        ray.weight * sim::ApertureAveragedBtdfCos(*truth, ray.l, ray.v, sim::Apertures{}, 256);
    const double point = ray.weight * truth->BtdfCos(ray.l, ray.v);
    EXPECT_GT(std::abs(fine / point - 1), 0.05) << offset;  // the apertures matter here
    EXPECT_NEAR(ResponseRectangle(*truth, *r) / fine, 1.0, 0.01) << offset;
  }
}

TEST(ResponseTest, TheConeQuadratureIsExactForPolynomialsOfItsOrder) {
  // The mean of cos^a over a cone of half-angle h (uniform in solid angle, so in cos theta on
  // [cos h, 1]) is (1 - c^(a+1)) / ((a + 1)(1 - c)); the two cones are independent. Rings at the
  // Gauss-Legendre nodes of cos theta get these exactly up to a + b = 2 rings - 1 each.
  const optics::Vec3<double> l{0, 0, 1};
  const optics::Vec3<double> v = Normalize(optics::Vec3<double>{0.3, -0.2, -0.9});
  const double hl = 0.05, hv = 0.03;
  auto cone_mean = [](double h, int a) {
    const double c = std::cos(h);
    return (1 - std::pow(c, a + 1)) / ((a + 1) * (1 - c));
  };
  for (int rings : {1, 2, 3, 5}) {
    const auto rays = fitting::ApertureCones(l, v, 2.5, hl, hv, rings, 7, 0.4);
    ASSERT_EQ(rays.size(), static_cast<std::size_t>(rings * 7 * rings * 7));
    for (int a = 0; a < 2 * rings; ++a)
      for (int b = 0; b < 2 * rings; b += 2 * rings - 1) {
        double sum = 0;
        for (const auto& r : rays)
          sum += r.weight * std::pow(Dot(r.l, l), a) * std::pow(Dot(r.v, v), b);
        EXPECT_NEAR(sum / 2.5, cone_mean(hl, a) * cone_mean(hv, b), 1e-13)
            << rings << " rings, a " << a << ", b " << b;
      }
    // The azimuths: the mean of a direction's tilt toward x (1st harmonic) is 0, its square
    // (2nd harmonic) half the mean of sin^2 theta (of degree 2 in cos theta: 2 rings or more).
    double x = 0, x2 = 0;
    for (const auto& r : rays) {
      x += r.weight * r.l.x;
      x2 += r.weight * r.l.x * r.l.x;
    }
    EXPECT_NEAR(x / 2.5, 0, 1e-15);
    if (rings >= 2) {
      EXPECT_NEAR(x2 / 2.5, (1 - cone_mean(hl, 2)) / 2, 1e-13) << rings;
    }
  }
}

TEST(ResponseTest, EachApertureLevelsChangeBoundsItsOwnError) {
  // The fitter refines a point's cones until the next level changes its value by less than a
  // fraction of sigma, trusting that change as the error. On antiglare's flank, levels that
  // refined the azimuth alone on one midpoint ring agreed to 10^-4 while both were 3.6 % low.
  // Against the scene's own cone averaging at 320 directions per cone (independent code):
  const auto truth = sim::MicrofacetTruth("beckmann", 0.023, 1.51);
  const auto setup = CentredSetup(0.16, 0.16, 6);  // one pixel at the pole
  for (double offset : {0.0, 0.7, 1.4, 2.0}) {
    const auto at = At(0, offset);
    auto base = fitting::ComputeResponse(setup, at);
    ASSERT_TRUE(base.ok() && base->rays.size() == 1u);
    const auto& ray = base->rays[0];
    const double fine =
        ray.weight * sim::ApertureAveragedBtdfCos(*truth, ray.l, ray.v, sim::Apertures{}, 320);
    std::vector<double> value;
    for (int level = 0;; ++level) {
      const auto lv = fitting::ApertureLevel(level, 0);
      if (!lv) break;
      auto r = fitting::ComputeAtLevel(setup, at, *lv);
      ASSERT_TRUE(r.ok()) << r.error().message;
      value.push_back(ResponseRectangle(*truth, *r) / fine);
    }
    ASSERT_GE(value.size(), 4u);
    for (std::size_t level = 0; level + 1 < value.size(); ++level)
      EXPECT_LE(std::abs(value[level] - 1), 2 * std::abs(value[level + 1] - value[level]) + 2e-5)
          << offset << " deg off the peak, level " << level;
    EXPECT_NEAR(value.back(), 1.0, 2e-5) << offset;
    EXPECT_NEAR(value[2], 1.0, 2e-3) << offset;  // 3 rings of 8
  }
}

TEST(ResponseTest, AStoredSetupRoundTripsAndBadOnesAreNamed) {
  const auto setup = CentredSetup(1, 3, 9);
  auto back = fitting::ResponseSetup::FromJson(setup.ToJson());
  ASSERT_TRUE(back.ok()) << back.error().message;
  EXPECT_EQ(back->ToJson(), setup.ToJson());
  auto corrupt = fitting::ResponseSetup::FromJson("{\"bench\": {");
  ASSERT_FALSE(corrupt.ok());
  EXPECT_NE(corrupt.error().message.find("not a JSON object"), std::string::npos);
  std::string text = setup.ToJson();
  text.replace(text.find("\"mm_per_pixel\""), 14, "\"mm_per_pixelX\"");
  auto missing = fitting::ResponseSetup::FromJson(text);
  ASSERT_FALSE(missing.ok());
  EXPECT_NE(missing.error().message.find("bench.mm_per_pixel"), std::string::npos)
      << missing.error().message;
  // The optical axis's position (a calibration) round-trips; off the sensor it is refused.
  auto aligned = setup;
  aligned.bench.axis_x_px = -1.25;
  aligned.bench.axis_y_px = 0.5;
  auto axis_back = fitting::ResponseSetup::FromJson(aligned.ToJson());
  ASSERT_TRUE(axis_back.ok()) << axis_back.error().message;
  EXPECT_EQ(axis_back->bench.axis_x_px, -1.25);
  EXPECT_EQ(axis_back->bench.axis_y_px, 0.5);
  aligned.bench.axis_y_px = 600;
  auto off_sensor = fitting::ResponseSetup::FromJson(aligned.ToJson());
  ASSERT_FALSE(off_sensor.ok());
  EXPECT_NE(off_sensor.error().message.find("bench.axis_x_px and axis_y_px"), std::string::npos)
      << off_sensor.error().message;
  auto outside = setup;
  outside.rectangle.x = 510;
  auto r = fitting::ResponseSetup::FromJson(outside.ToJson());
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.error().message.find("beyond the 512 x 512 sensor"), std::string::npos);
  // A camera in the sample's plane sees neither face.
  auto edge_on = fitting::ComputeResponse(setup, {0, 90, 0});
  ASSERT_FALSE(edge_on.ok());
  EXPECT_NE(edge_on.error().message.find("sees neither face"), std::string::npos)
      << edge_on.error().message;
}

// Reflection: the camera on the light side sees the rough face directly. The scene renders it on
// its own path (Scene::TraceReflection) with the same k as transmission, which puts eta^2 / T_pole
// on its reflection rate (docs/scene.md); the response leaves that to k (w = 1 at the centre), so
// the test divides it out.
TEST(ResponseTest, AReflectionRectangleMatchesTheScenesRenderingWithinATenthOfAPercent) {
  const auto truth = sim::MicrofacetTruth("beckmann", 0.344, 1.51);
  const double r0 = (1.51 - 1) / (1.51 + 1);
  const double exit = 1.51 * 1.51 / (1 - r0 * r0);
  struct Case {
    double w, h, thickness, ti, tv;
  };
  const Case cases[] = {{3, 10, 6, 30, 30}, {10, 3, 6, 30, 45}, {3, 10, 3, 60, 50},
                        {10, 3, 9, 60, 75}, {1, 3, 6, 20, 5},   {3, 10, 9, 40, -20}};
  double largest_effect = 0;
  for (const Case& c : cases) {
    const auto setup = CentredSetup(c.w, c.h, c.thickness);
    const StageTargets t = StageTargetsForReflection(c.ti, c.tv);
    const fitting::StagePosition at{t.sample_deg, t.arm_deg, 0};
    auto r = fitting::ComputeResponse(setup, at, /*max_rays=*/0);
    ASSERT_TRUE(r.ok()) << r.error().message;
    ASSERT_GT(r->v0.z, 0);
    const double scene = SceneRectangle(*truth, setup, at) / exit;
    double response = 0;
    for (const auto& ray : r->rays) response += ray.weight * *truth->BrdfCos(ray.l, ray.v);
    response /= r->pixels;
    ASSERT_GT(scene, 0);
    EXPECT_NEAR(response / scene, 1.0, 1e-3)
        << c.w << "x" << c.h << " mm, " << c.thickness << " mm, ti " << c.ti << ", tv " << c.tv;
    const double nominal = *truth->BrdfCos(r->l0, r->v0);
    largest_effect = std::max(largest_effect, std::abs(scene / nominal - 1));
    // The nominal pair is the plan's: theta_v from +n, away from the light.
    const auto s = fitting::SampleFromReflectionAngles(c.ti, 0, c.tv, 0, 1, 1);
    EXPECT_NEAR(optics::Dot(s.view, r->v0), 1.0, 1e-12);
    EXPECT_NEAR(optics::Dot(s.light, r->l0), 1.0, 1e-12);
  }
  EXPECT_GT(largest_effect, 0.01);  // the rectangle matters in reflection as well
}

// Samples made with a 1 x 3 mm rectangle's response, with 0.2 % noise, at Walter's incidences.
// The apertures are points here (the generator does not average over them).
std::vector<fitting::Sample> RectangleSamples(const sim::GroundTruth& truth, double k,
                                              double thickness, std::uint64_t seed) {
  auto setup = std::make_shared<fitting::ResponseSetup>(CentredSetup(1, 3, thickness));
  setup->bench.source_sr = setup->bench.receiver_sr = 0;
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> noise(0, 1);
  std::vector<fitting::Sample> out;
  for (double ti : {0.0, 30.0, 60.0}) {
    for (double off = -20; off <= 20; off += 2.5) {
      const auto at = At(ti, off);
      auto r = fitting::ComputeResponse(*setup, at);
      if (!r.ok()) continue;
      fitting::Sample s;
      s.light = r->l0;
      s.view = r->v0;
      const double clean = k * ResponseRectangle(truth, *r);
      s.sigma = 0.002 * clean + 1e-4 * k;
      s.value = clean + s.sigma * noise(rng);
      s.response = fitting::PointResponse{setup, at};
      out.push_back(s);
    }
  }
  return out;
}

TEST(ResponseTest, AFitThroughTheResponseRecoversTheTruthAndThePointModelIsBiased) {
  const auto truth = sim::MicrofacetTruth("beckmann", 0.344, 1.51);
  const auto samples = RectangleSamples(*truth, 1000, 3, 7);
  fitting::FitOptions o;
  auto with = fitting::Fit(samples, o);
  ASSERT_TRUE(with.ok()) << with.error().message;
  EXPECT_EQ(with->status, fitting::FitStatus::kConverged) << with->message;
  EXPECT_LT(std::abs(with->width.value - 0.344), 2 * with->width.sigma)
      << with->width.value << " +- " << with->width.sigma;
  EXPECT_LT(with->reduced_chi2, 1.6);
  EXPECT_EQ(with->response.samples_with_response, static_cast<int>(samples.size()));
  EXPECT_GT(with->response.rectangle, static_cast<int>(samples.size()) / 2);
  // Every sample left to the point model is one whose response changes it by at most a tenth
  // of its sigma at the solution.
  int beyond = 0;
  for (const auto& s : samples) {
    auto r = fitting::ComputeResponse(*s.response->setup, s.response->at);
    ASSERT_TRUE(r.ok());
    const double point =
        with->scale.value *
        fitting::MeasurementModel(o.model, r->l0, r->v0, with->width.value, 1.0, 1.51);
    double resp = 0;
    for (const auto& ray : r->rays)
      resp += ray.weight * fitting::MeasurementModel(o.model, ray.l, ray.v, with->width.value,
                                                     with->scale.value, 1.51);
    resp /= r->pixels;
    beyond += std::abs(resp - point) > 0.1 * s.sigma;
  }
  EXPECT_NEAR(with->response.rectangle, beyond, 1);

  o.use_response = false;
  auto point = fitting::Fit(samples, o);
  ASSERT_TRUE(point.ok());
  EXPECT_EQ(point->response.rectangle, 0);
  EXPECT_GT(point->reduced_chi2, 4 * with->reduced_chi2);  // the point model cannot fit them
}

// Antiglare (Beckmann 0.023) under a 3 x 10 mm rectangle, rendered by the scene with its
// apertures (64 directions per cone) and no stray light: a point 2 deg off the peak takes its
// value from the rectangle's edge nearest the lobe, where the cones reach into it (the apertures
// add 0.019 of its 0.025 there, 9 sigma) while at its nominal pair they add 1e-4 (0.06 sigma).
// The fit judged the apertures at the nominal pair alone and modelled such points without them,
// then kept the models it had built at the start's width when only their levels changed: alpha
// came out 2 sigma low with a floor invented for the tails.
TEST(ResponseTest, ANarrowLobesTailUnderALargeRectangleTakesTheAperturesFromItsEdge) {
  const auto truth = sim::MicrofacetTruth("beckmann", 0.023, 1.51);
  auto setup = std::make_shared<fitting::ResponseSetup>(CentredSetup(3, 10, 6));
  sim::BenchGeometry bench;
  sim::SceneOptions so;
  so.stray_lens_e_per_s = so.stray_background_e_per_s = 0;
  so.aperture_points = 64;
  const sim::Scene scene(bench, truth, so);
  sim::ImageRegion region;
  region.offset_x = setup->rectangle.x;
  region.offset_y = setup->rectangle.y;
  region.width = setup->rectangle.width;
  region.height = setup->rectangle.height;
  std::vector<fitting::Sample> samples;
  for (double ti : {0.0, 30.0})
    for (double off = -2; off <= 2 + 1e-9; off += 0.5) {
      const auto at = At(ti, off);
      fitting::Sample s;
      std::tie(s.light, s.view) = fitting::NominalDirections(at);
      s.value = cv::mean(scene.Render({at.sample_deg, at.arm_deg, at.azimuth_deg}, region))[0] /
                so.electrons_per_s_per_unit;
      s.sigma = s.sigma_stat = std::hypot(5e-4 * s.value, 2e-3);
      s.response = fitting::PointResponse{setup, at};
      samples.push_back(s);
    }
  fitting::FitOptions o;
  auto f = fitting::Fit(samples, o);
  ASSERT_TRUE(f.ok()) << f.error().message;
  ASSERT_EQ(f->status, fitting::FitStatus::kConverged) << f->message;
  // Noise-free data: the model is the scene's to a small part of sigma at every point.
  for (std::size_t i = 0; i < samples.size(); ++i)
    EXPECT_LT(std::abs(f->residuals[i]), 0.3) << "sample " << i << " value " << samples[i].value;
  EXPECT_NEAR(f->width.value, 0.023, 2e-5);
  EXPECT_EQ(f->response.apertures, static_cast<int>(samples.size()));
}

// A level's streamed mean (what the fitter evaluates past its ray budget) is the mean over the
// rays ComputeAtLevel holds, and the bound known before tracing is never below their count.
TEST(ResponseTest, ALevelsStreamedMeanIsItsRaysMeanAndItsBoundHoldsThem) {
  const auto truth = sim::MicrofacetTruth("beckmann", 0.023, 1.51);
  const auto setup = CentredSetup(3, 10, 6);  // 19 x 62 pixels
  const auto at = At(30, 1.2);
  const auto f = [&](const fitting::ResponseRay& r) { return truth->BtdfCos(r.l, r.v); };
  for (const auto& level : {*fitting::RectangleLevel(0), *fitting::RectangleLevel(3),
                            *fitting::ApertureLevel(0, 1), *fitting::ApertureLevel(1, 3)}) {
    auto held = fitting::ComputeAtLevel(setup, at, level);
    ASSERT_TRUE(held.ok()) << held.error().message;
    auto streamed = fitting::MeanOverLevel(setup, at, level, f);
    ASSERT_TRUE(streamed.ok()) << streamed.error().message;
    const double mean = ResponseRectangle(*truth, *held);
    ASSERT_GT(mean, 0);
    EXPECT_NEAR(*streamed / mean, 1.0, 1e-12) << level.max_rays << " " << level.cone_rings;
    const long bound = fitting::MaxRaysAtLevel(setup, level);
    EXPECT_LE(static_cast<long>(held->rays.size()), bound);
    EXPECT_GT(static_cast<long>(held->rays.size()), bound * 9 / 10);  // a bound, not a guess
  }
  // A stage position that sees nothing is refused as ComputeResponse refuses it.
  EXPECT_FALSE(fitting::MeanOverLevel(setup, {0, 90, 0}, *fitting::RectangleLevel(0), f).ok());
}

// Antiglare under 1 x 3 mm with the apertures, noise-free values from a fine level: with a ray
// budget below what the tolerance asks for, the fit models the held samples at a coarser level
// whose error is real (more than a sample's own sigma somewhere) and is carried in their sigma,
// so alpha still covers the truth, with a wider sigma than the fit that had the rays.
TEST(ResponseTest, AModelHeldToTheRayBudgetIsCorrectedAndCarriesItsErrorInSigma) {
  const auto truth = sim::MicrofacetTruth("beckmann", 0.023, 1.51);
  auto setup = std::make_shared<fitting::ResponseSetup>(CentredSetup(1, 3, 6));
  std::vector<fitting::Sample> samples;
  for (double ti : {0.0, 30.0})
    for (double off = -1.5; off <= 1.5 + 1e-9; off += 0.25) {
      const auto at = At(ti, off);
      auto fine = fitting::MeanOverLevel(
          *setup, at, *fitting::ApertureLevel(4, 3),
          [&](const fitting::ResponseRay& r) { return truth->BtdfCos(r.l, r.v); });
      ASSERT_TRUE(fine.ok()) << fine.error().message;
      fitting::Sample s;
      std::tie(s.light, s.view) = fitting::NominalDirections(at);
      s.value = 1000 * *fine;
      s.sigma = s.sigma_stat = std::hypot(5e-4 * s.value, 2e-3);
      s.response = fitting::PointResponse{setup, at};
      samples.push_back(s);
    }
  fitting::FitOptions o;
  o.max_response_rays = 1L << 22;  // room for every level this rectangle has
  auto full = fitting::Fit(samples, o);
  ASSERT_TRUE(full.ok()) << full.error().message;
  ASSERT_EQ(full->status, fitting::FitStatus::kConverged) << full->message;
  EXPECT_EQ(full->response.capped, 0);
  EXPECT_LT(std::abs(full->width.value - 0.023), 2 * full->width.sigma) << full->width.value;

  o.max_response_rays = 600;  // a coarse rectangle's rays with few cone directions
  o.held_error = fitting::HeldError::kNextChange;
  auto held = fitting::Fit(samples, o);
  ASSERT_TRUE(held.ok()) << held.error().message;
  ASSERT_NE(held->status, fitting::FitStatus::kFailed) << held->message;
  EXPECT_GT(held->response.capped, static_cast<int>(samples.size()) / 2);
  EXPECT_GT(held->response.capped_largest, 1.0);  // the coarse model's error is real
  EXPECT_EQ(held->response.traced, 0);
  EXPECT_LE(held->response.rays, 600L * static_cast<long>(samples.size()));
  EXPECT_LT(std::abs(held->width.value - 0.023), 2 * held->width.sigma)
      << held->width.value << " +- " << held->width.sigma;
  EXPECT_GT(held->width.sigma, full->width.sigma);
  for (std::size_t i = 0; i < samples.size(); ++i)
    EXPECT_LT(std::abs(held->residuals[i]), 3) << "sample " << i;

  // Traced one level finer at the solution: the corrected model's own error, smaller than the
  // change that brought it there, and still as large as the model's distance from the values
  // (made at the finest level): every residual stays within 3 of the tighter sigma. The model
  // carries its correction's slope in the width: held fixed, the correction gave the fit the
  // coarse cones' sharper lobe, and alpha came out 3.3 of a sigma 20 % too small off.
  o.held_error = fitting::HeldError::kTraced;
  auto traced = fitting::Fit(samples, o);
  ASSERT_TRUE(traced.ok()) << traced.error().message;
  ASSERT_NE(traced->status, fitting::FitStatus::kFailed) << traced->message;
  EXPECT_EQ(traced->response.capped, held->response.capped);
  EXPECT_GT(traced->response.traced, 0);
  EXPECT_LT(traced->response.capped_largest, 0.5 * traced->response.capped_untraced_largest);
  EXPECT_LT(traced->width.sigma, held->width.sigma);
  EXPECT_LT(std::abs(traced->width.value - 0.023), 2 * traced->width.sigma)
      << traced->width.value << " +- " << traced->width.sigma;
  for (std::size_t i = 0; i < samples.size(); ++i)
    EXPECT_LT(std::abs(traced->residuals[i]), 3) << "sample " << i;
}

// Samples of a 1 x 3 mm rectangle made on a bench that differs from the one the samples state:
// the values come from `made` at stage angles moved by N(0, jitter_deg) each, while the samples
// carry `stated` and the nominal angles. 0.2 % noise, incidences 0, 30, 60.
// `jitter_deg`: the stages' errors against their read-back, as on the bench: the arm's drawn per
// point, the sample stage's once per incidence (its sweep moves the arm alone); the sample
// stage's draws are appended to `sample_errors` when given.
std::vector<fitting::Sample> MisstatedSamples(const sim::GroundTruth& truth,
                                              const fitting::ResponseSetup& made,
                                              const fitting::ResponseSetup& stated,
                                              double jitter_deg, std::uint64_t seed,
                                              std::vector<double> incidences = {0, 30, 60},
                                              double step_deg = 2.5,
                                              std::vector<double>* sample_errors = nullptr) {
  auto setup = std::make_shared<const fitting::ResponseSetup>(stated);
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> noise(0, 1);
  std::vector<fitting::Sample> out;
  for (double ti : incidences) {
    const double sample_error = jitter_deg * noise(rng);
    if (sample_errors) sample_errors->push_back(sample_error);
    for (double off = -20; off <= 20; off += step_deg) {
      const auto at = At(ti, off);
      auto true_at = at;
      true_at.sample_deg += sample_error;
      true_at.arm_deg += jitter_deg * noise(rng);
      auto r = fitting::ComputeResponse(made, true_at);
      if (!r.ok()) continue;
      fitting::Sample s;
      std::tie(s.light, s.view) = fitting::NominalDirections(at);
      const double clean = 1000 * ResponseRectangle(truth, *r);
      s.sigma = s.sigma_stat = 0.002 * clean + 0.1;
      s.value = clean + s.sigma * noise(rng);
      s.response = fitting::PointResponse{setup, at};
      out.push_back(s);
    }
  }
  return out;
}

// The centred setup without apertures as made, and as stated with the stages' read-back to
// `angle_sigma_deg`.
std::pair<fitting::ResponseSetup, fitting::ResponseSetup> AngleStated(double angle_sigma_deg) {
  auto made = CentredSetup(1, 3, 6);
  made.bench.source_sr = made.bench.receiver_sr = 0;
  auto stated = made;
  stated.bench.angle_sigma_deg = angle_sigma_deg;
  return {made, stated};
}

// The angle read-back: values measured at angles 0.05 deg off the read-back ones scatter by the
// slope times 0.05 deg, several times the 0.2 % noise on ground glass's flanks. Not stated, the
// fit calls the true model poor; stated, chi-square is honest again and alpha's interval covers
// the truth.
TEST(ResponseTest, TheAngleReadBackEntersEachSamplesSigmaThroughTheSlope) {
  const auto truth = sim::MicrofacetTruth("beckmann", 0.344, 1.51);
  const auto [made, stated] = AngleStated(0.05);
  fitting::FitOptions o;
  int covered = 0;
  for (std::uint64_t seed : {21, 22, 23, 24, 25}) {
    auto blind = fitting::Fit(MisstatedSamples(*truth, made, made, 0.05, seed), o);
    auto told = fitting::Fit(MisstatedSamples(*truth, made, stated, 0.05, seed), o);
    ASSERT_TRUE(blind.ok() && told.ok());
    EXPECT_GT(blind->reduced_chi2, 2) << seed;
    EXPECT_FALSE(blind->geometry.angle_in_fit);
    EXPECT_TRUE(told->geometry.angle_in_fit) << told->geometry.note;
    EXPECT_GT(told->geometry.angle_max_fraction, 1) << told->geometry.note;
    EXPECT_LT(told->reduced_chi2, 1.6) << seed << ": " << told->geometry.note;
    EXPECT_GT(told->width.sigma_geometry, 0);
    covered += std::abs(told->width.value - 0.344) < 2 * told->width.sigma;
  }
  EXPECT_GE(covered, 4);
}

// The sample stage's error is common to an incidence's sweep (the arm moves, the sample stage does
// not), so it moves the sweep's points together: one offset per incidence, a parameter of the fit
// with the stated sigma as its prior, not a term of each point's sigma. Over 60 draws of three
// incidences, 0.1 deg errors on both stages (the flanks' slope times 0.1 deg is several times the
// noise): chi-square is chi-square with n - 2 degrees of freedom, the offsets found match the
// errors drawn within their sigmas, and alpha's pulls have unit spread.
TEST(ResponseTest, TheSampleStagesErrorIsOneOffsetPerIncidenceSweep) {
  const auto truth = sim::MicrofacetTruth("beckmann", 0.344, 1.51);
  const auto [made, stated] = AngleStated(0.1);
  fitting::FitOptions o;
  constexpr int kDraws = 60;
  double chi2_dof = 0, width_pull2 = 0, offset_pull2 = 0, offset_sigma = 0;
  int n = 0, offsets = 0;
  for (int seed = 0; seed < kDraws; ++seed) {
    std::vector<double> errors;
    const auto data =
        MisstatedSamples(*truth, made, stated, 0.1, 3000 + seed, {0, 30, 60}, 2.5, &errors);
    auto f = fitting::Fit(data, o);
    ASSERT_TRUE(f.ok()) << f.error().message;
    if (!f->ok()) continue;
    ++n;
    ASSERT_TRUE(f->geometry.angle_in_fit) << f->geometry.note;
    const auto& stage = f->geometry.sample_stage;
    ASSERT_EQ(stage.size(), 3u) << f->geometry.note;
    for (std::size_t g = 0; g < 3; ++g) {
      EXPECT_EQ(stage[g].points, 17);
      EXPECT_GT(stage[g].sigma_deg, 0);
      EXPECT_LT(stage[g].sigma_deg, 0.1);
      offset_pull2 += std::pow((stage[g].offset_deg - errors[g]) / stage[g].sigma_deg, 2);
      offset_sigma += stage[g].sigma_deg;
      ++offsets;
    }
    // chi2 counts the offsets' priors and no degree of freedom for them.
    EXPECT_NEAR(f->reduced_chi2, f->chi2 / (f->n_points - f->n_params - f->n_nuisance), 1e-12);
    chi2_dof += f->reduced_chi2;
    width_pull2 += std::pow((f->width.value - 0.344) / f->width.sigma, 2);
  }
  ASSERT_GE(n, kDraws * 9 / 10);
  chi2_dof /= n;
  const double width_rms = std::sqrt(width_pull2 / n);
  const double offset_rms = std::sqrt(offset_pull2 / offsets);
  std::cout << "[ info ] " << n << " draws: chi2/dof " << chi2_dof << ", alpha's pull rms "
            << width_rms << "; the sample stage's offsets: sigma " << offset_sigma / offsets
            << " deg (prior 0.1), pull rms " << offset_rms << "\n";
  // The mean of chi2/nu over 60 draws of 49 dof has a standard deviation of about 0.03.
  EXPECT_NEAR(chi2_dof, 1.0, 0.1);
  EXPECT_GT(width_rms, 0.7);
  EXPECT_LT(width_rms, 1.3);
  EXPECT_GT(offset_rms, 0.75);
  EXPECT_LT(offset_rms, 1.25);
  // The data know the offsets better than the prior: the sweep's flanks see them.
  EXPECT_LT(offset_sigma / offsets, 0.09);
}

// The thickness (common to the run): a plate 0.6 mm thicker than stated moves every point the
// same way. It is a nuisance parameter with the stated sigma as its prior: these data (0.2 %
// noise, three incidences) know it to a fifth of that, so the fit finds the true thickness within
// its sigma and moves alpha to where a fit told the true thickness puts it. (It is small: on
// ground glass under a 3 x 10 mm rectangle 0.6 mm moves alpha by about 1e-5, a third of the
// statistical sigma.)
TEST(ResponseTest, TheThicknessAndTheRectanglesPositionAreNuisanceParametersOfTheFit) {
  const auto truth = sim::MicrofacetTruth("beckmann", 0.344, 1.51);
  auto made = CentredSetup(3, 10, 9.6);
  made.bench.source_sr = made.bench.receiver_sr = 0;
  auto stated = made;
  stated.thickness_mm = 9.0;
  stated.bench.thickness_sigma_mm = 0.6;
  const auto samples = MisstatedSamples(*truth, made, stated, 0, 31);
  fitting::FitOptions o;
  auto fit = fitting::Fit(samples, o);
  ASSERT_TRUE(fit.ok()) << fit.error().message;
  const auto& t = fit->geometry.thickness;
  EXPECT_TRUE(fit->geometry.stated);
  ASSERT_TRUE(t.fitted) << fit->geometry.note;
  EXPECT_LT(t.offset_sigma, 0.6 / 2) << fit->geometry.note;
  EXPECT_LT(std::abs(t.offset - 0.6), 2 * t.offset_sigma) << fit->geometry.note;
  EXPECT_EQ(fit->geometry.width_thickness, t.width_sigma);
  // The same data fitted with the true thickness stated, independently of the budget.
  auto right = made;
  const auto at_truth = MisstatedSamples(*truth, made, right, 0, 31);
  auto exact = fitting::Fit(at_truth, o);
  ASSERT_TRUE(exact.ok());
  const double unmoved = fit->width.value - t.width_shift;
  const double error_unmoved = std::abs(unmoved - exact->width.value);
  EXPECT_LT(std::abs(fit->width.value - exact->width.value), 0.3 * error_unmoved)
      << fit->geometry.note << "; the true thickness puts alpha at " << exact->width.value;
  EXPECT_LT(t.width_sigma, 0.5 * error_unmoved) << fit->geometry.note;
  EXPECT_LT(std::abs(fit->width.value - 0.344), 2 * fit->width.sigma) << fit->geometry.note;
  std::cout << "[ info ] alpha " << fit->width.value << " +- " << fit->width.sigma << " (geometry "
            << fit->width.sigma_geometry << "; at the stated thickness " << unmoved
            << "); at the true thickness " << exact->width.value << " +- " << exact->width.sigma
            << "; " << fit->geometry.note << "\n";
  EXPECT_GE(fit->width.sigma_geometry, fit->geometry.width_thickness);
  // The rectangle's position: stated, it adds its refit; not stated, the note says so.
  stated.bench.rectangle_sigma_px = 1;
  auto with_rect = fitting::Fit(MisstatedSamples(*truth, made, stated, 0, 31), o);
  ASSERT_TRUE(with_rect.ok());
  EXPECT_GT(with_rect->geometry.width_rectangle, 0);
  EXPECT_GT(with_rect->width.sigma_geometry, fit->width.sigma_geometry);
  EXPECT_NE(fit->geometry.note.find("rectangle position: not stated"), std::string::npos)
      << fit->geometry.note;
  // Samples without a response say that the geometry is not known.
  auto bare = samples;
  for (auto& s : bare) s.response.reset();
  auto unknown = fitting::Fit(bare, o);
  ASSERT_TRUE(unknown.ok());
  EXPECT_FALSE(unknown->geometry.stated);
  EXPECT_EQ(unknown->width.sigma_geometry, 0);
  EXPECT_NE(unknown->geometry.note.find("not known"), std::string::npos);
}

// A 1 x 3 mm rectangle on a 6 mm plate (no apertures) that is `off_px` left of the optical axis,
// and the setup that states it on the axis to +-1 px.
std::pair<fitting::ResponseSetup, fitting::ResponseSetup> RectangleOffAxis(double off_px) {
  auto made = CentredSetup(1, 3, 6);
  made.bench.source_sr = made.bench.receiver_sr = 0;
  made.bench.axis_x_px = off_px;
  auto stated = made;
  stated.bench.axis_x_px = 0;
  stated.bench.rectangle_sigma_px = 1;
  return {made, stated};
}

// The rectangle's position against the optical axis (common to the run), 0.8 px off what
// the configuration says. Not stated, the fit takes the stated position as exact and alpha's
// 2-sigma interval misses the truth (even with sigma inflated by chi-square); stated (1 px), the
// data find the offset, as a nuisance parameter, to a fraction of that pixel and alpha's interval
// covers the truth again. The sweeps are in the plane of incidence, so the data know little of the
// position across it (y): it keeps its prior there, and finds no offset.
TEST(ResponseTest, TheRectanglesPositionIsTakenFromTheDataAndAlphaWithIt) {
  const auto truth = sim::MicrofacetTruth("beckmann", 0.344, 1.51);
  auto made = CentredSetup(1, 3, 6);
  made.bench.source_sr = made.bench.receiver_sr = 0;
  made.bench.axis_x_px = 0.8;  // the rectangle is 0.8 px left of the axis
  auto stated = made;
  stated.bench.axis_x_px = 0;
  fitting::FitOptions o;
  auto blind = fitting::Fit(MisstatedSamples(*truth, made, stated, 0, 41), o);
  stated.bench.rectangle_sigma_px = 1;
  auto told = fitting::Fit(MisstatedSamples(*truth, made, stated, 0, 41), o);
  ASSERT_TRUE(blind.ok() && told.ok());
  std::cout << "[ info ] not stated: alpha " << blind->width.value << " +- " << blind->width.sigma
            << "; stated: " << told->width.value << " +- " << told->width.sigma << "; "
            << told->geometry.note << "\n";
  EXPECT_GT(std::abs(blind->width.value - 0.344), 2 * blind->width.sigma);
  const auto& x = told->geometry.rectangle_x;
  ASSERT_TRUE(x.fitted) << told->geometry.note;
  EXPECT_LT(x.offset_sigma, 0.25) << told->geometry.note;
  EXPECT_LT(std::abs(x.offset + 0.8), 2 * x.offset_sigma) << told->geometry.note;
  EXPECT_LT(std::abs(told->width.value - 0.344), 2 * told->width.sigma) << told->geometry.note;
  EXPECT_LT(told->width.sigma, 0.5 * std::abs(blind->width.value - 0.344));
  // Refitted at the rectangle the data found, chi-square is honest again, and Predict models the
  // same geometry: the residuals it gives are the fit's.
  EXPECT_NE(told->geometry.note.find("refitted at that geometry"), std::string::npos);
  EXPECT_GT(blind->reduced_chi2, 2) << blind->geometry.note;
  EXPECT_LT(told->reduced_chi2, 1.6);
  const auto data = MisstatedSamples(*truth, made, stated, 0, 41);
  ASSERT_EQ(told->residuals.size(), data.size());
  for (std::size_t i = 0; i < data.size(); ++i)
    EXPECT_NEAR((fitting::Predict(*told, data[i]) - data[i].value) / data[i].sigma,
                told->residuals[i], 1e-6)
        << i;
  const auto& y = told->geometry.rectangle_y;
  // y is profiled together with x (at the x found its curvature is the data's, not flattened by
  // the misfit the stated x leaves): the data halve its prior at most.
  EXPECT_GT(y.offset_sigma, 0.4) << told->geometry.note;
  EXPECT_LE(y.offset_sigma, 1.0) << told->geometry.note;
  EXPECT_LT(std::abs(y.offset), 2 * y.offset_sigma) << told->geometry.note;
  EXPECT_NEAR(told->geometry.width_rectangle, std::hypot(x.width_sigma, y.width_sigma), 1e-15);
}

// chi2/dof of a fit whose geometry the data found counts the nuisance parameters it fixed. Nine
// points at normal incidence, the width and k fitted, the rectangle 0.8 px off along x (stated to
// 1 px; the data find it to about 0.03 px): chi2 has 9 - 2 - 1 degrees of freedom, not 7, and
// over many draws chi2/dof averages 1 only when the rectangle counts (6/7 when it does not). The
// offset found scatters about the truth as its sigma says: the profile once scaled chi-square by
// the unmoved fit's chi2/dof, which the offset itself inflated 30 times, and stopped at -0.73 +-
// 0.29 px with chi2/dof 1.8.
TEST(ResponseTest, ChiSquaresDegreesOfFreedomCountTheGeometryTheDataFixed) {
  const auto truth = sim::MicrofacetTruth("beckmann", 0.344, 1.51);
  const auto [made, stated] = RectangleOffAxis(0.8);
  fitting::FitOptions o;
  o.floor = fitting::Floor::kOff;
  constexpr int kDraws = 200;
  double counted = 0, uncounted = 0, nu = 0, pull2 = 0, sigma_x = 0;
  int n = 0;
  for (int seed = 0; seed < kDraws; ++seed) {
    const auto data = MisstatedSamples(*truth, made, stated, 0, 1000 + seed, {0.0}, 5.0);
    auto f = fitting::Fit(data, o);
    ASSERT_TRUE(f.ok()) << f.error().message;
    ASSERT_EQ(f->n_points, 9);
    if (!f->ok()) continue;
    ++n;
    counted += f->reduced_chi2;
    uncounted += f->chi2 / (f->n_points - f->n_params);
    nu += f->n_nuisance;
    const auto& x = f->geometry.rectangle_x;
    ASSERT_TRUE(x.fitted) << seed << ": " << f->geometry.note;
    pull2 += std::pow((x.offset + 0.8) / x.offset_sigma, 2);
    sigma_x += x.offset_sigma;
    EXPECT_NEAR(f->reduced_chi2, f->chi2 / (f->n_points - f->n_params - f->n_nuisance), 1e-12);
    EXPECT_NEAR(f->bic, f->chi2 + (f->n_params + f->n_nuisance) * std::log(9.0), 1e-9);
  }
  ASSERT_GE(n, kDraws * 9 / 10);
  counted /= n;
  uncounted /= n;
  nu /= n;
  const double pull_rms = std::sqrt(pull2 / n);
  std::cout << "[ info ] " << n << " draws: chi2/dof " << counted << " counting " << nu
            << " nuisance parameters, " << uncounted << " without; rectangle x's sigma "
            << sigma_x / n << " px, its pulls' rms " << pull_rms << "\n";
  EXPECT_LT(sigma_x / n, 0.1);
  EXPECT_GT(pull_rms, 0.8);
  EXPECT_LT(pull_rms, 1.2);
  EXPECT_GT(nu, 0.9);
  EXPECT_LT(nu, 1.5);  // y: the data at normal incidence know little of it
  // The mean of chi2/nu over 200 draws has a standard deviation of about 0.04 at 6 dof.
  EXPECT_NEAR(counted, 1.0, 0.1);
}

// The thickness and the rectangle's x both move an oblique sweep's lobe: profiled one at a time,
// each took the shift the other made, and the fit moved to both (on antiglare a 3-sigma x and a
// 5-sigma thickness absorbed one sample-stage error between them). Profiled together, with their
// cross term: a plate 0.4 mm thicker than stated (+-0.6) and a rectangle 0.5 px off (+-1), on a
// 3 x 3 mm rectangle at three incidences, over 20 draws. Both are found within their sigmas
// (pull rms within 0.6-1.5) and alpha covers the truth; the thickness's sigma is the marginal
// one, larger than where x is known exactly (then not stated).
TEST(ResponseTest, TheThicknessAndTheRectangleAreProfiledTogether) {
  const auto truth = sim::MicrofacetTruth("beckmann", 0.344, 1.51);
  auto made = CentredSetup(3, 3, 6.4);
  made.bench.source_sr = made.bench.receiver_sr = 0;
  made.bench.axis_x_px = 0.5;
  auto stated = made;
  stated.thickness_mm = 6.0;
  stated.bench.thickness_sigma_mm = 0.6;
  auto x_known = stated;  // the true x, not stated as uncertain
  stated.bench.axis_x_px = 0;
  stated.bench.rectangle_sigma_px = 1;
  fitting::FitOptions o;
  constexpr int kDraws = 20;
  double t_pull2 = 0, x_pull2 = 0, w_pull2 = 0, t_sigma = 0, t_sigma_known = 0;
  int n = 0;
  for (int seed = 0; seed < kDraws; ++seed) {
    auto f = fitting::Fit(MisstatedSamples(*truth, made, stated, 0, 500 + seed), o);
    auto k = fitting::Fit(MisstatedSamples(*truth, made, x_known, 0, 500 + seed), o);
    ASSERT_TRUE(f.ok() && k.ok());
    if (!f->ok() || !k->ok()) continue;
    const auto& t = f->geometry.thickness;
    const auto& x = f->geometry.rectangle_x;
    ASSERT_TRUE(t.fitted && x.fitted) << seed << ": " << f->geometry.note;
    ++n;
    t_pull2 += std::pow((t.offset - 0.4) / t.offset_sigma, 2);
    x_pull2 += std::pow((x.offset + 0.5) / x.offset_sigma, 2);
    w_pull2 += std::pow((f->width.value - 0.344) / f->width.sigma, 2);
    t_sigma += t.offset_sigma;
    t_sigma_known += k->geometry.thickness.offset_sigma;
    if (seed == 0) std::cout << "[ info ] " << f->geometry.note << "\n";
  }
  ASSERT_GE(n, kDraws * 9 / 10);
  const double t_rms = std::sqrt(t_pull2 / n), x_rms = std::sqrt(x_pull2 / n),
               w_rms = std::sqrt(w_pull2 / n);
  std::cout << "[ info ] " << n << " draws: pull rms thickness " << t_rms << ", x " << x_rms
            << ", alpha " << w_rms << "; thickness sigma " << t_sigma / n
            << " mm (x known: " << t_sigma_known / n << ")\n";
  EXPECT_GT(t_rms, 0.6);
  EXPECT_LT(t_rms, 1.5);
  EXPECT_GT(x_rms, 0.6);
  EXPECT_LT(x_rms, 1.5);
  EXPECT_LT(w_rms, 1.5);
  EXPECT_GT(t_sigma, 1.05 * t_sigma_known);
}

// A rectangle 3 px from where the configuration says, stated to 1 px: the data's parabola puts it
// beyond the probes, where it is not trusted. The fit keeps the prior and tells the operator to
// check the stated position, rather than follow an extrapolation.
TEST(ResponseTest, ARectangleFarFromItsStatedPositionIsNamedNotFollowed) {
  const auto truth = sim::MicrofacetTruth("beckmann", 0.344, 1.51);
  const auto [made, stated] = RectangleOffAxis(3);
  auto fit = fitting::Fit(MisstatedSamples(*truth, made, stated, 0, 43), fitting::FitOptions{});
  ASSERT_TRUE(fit.ok()) << fit.error().message;
  const auto& x = fit->geometry.rectangle_x;
  EXPECT_FALSE(x.fitted) << fit->geometry.note;
  EXPECT_EQ(x.offset, 0);
  EXPECT_EQ(x.offset_sigma, 1);
  EXPECT_NE(fit->geometry.note.find("beyond the probes: check the stated value"), std::string::npos)
      << fit->geometry.note;
}

TEST(ResponseTest, TheFloorIsKeptOnlyWhenTheDataNeedIt) {
  const auto truth = sim::MicrofacetTruth("beckmann", 0.344, 1.51);
  auto samples = RectangleSamples(*truth, 1000, 6, 11);
  fitting::FitOptions o;
  o.floor = fitting::Floor::kAuto;
  auto clean = fitting::Fit(samples, o);
  ASSERT_TRUE(clean.ok());
  EXPECT_FALSE(clean->floor_fitted) << clean->floor_choice;
  // A stray-light floor of 2 (about a ten-thousandth of the peak, 20 sigma of the tails).
  for (auto& s : samples) s.value += 2.0;
  auto floored = fitting::Fit(samples, o);
  ASSERT_TRUE(floored.ok());
  EXPECT_TRUE(floored->floor_fitted) << floored->floor_choice;
  EXPECT_NEAR(floored->floor.value, 2.0, 3 * floored->floor.sigma + 1e-9);
  EXPECT_LT(std::abs(floored->width.value - 0.344), 2 * floored->width.sigma);
}

// Where BIC cannot show the floor, the floor-fitted width's distance from the other is in sigma
// (fitter.h, Floor::kAuto), and stays there after the refit at the geometry the data found: that
// refit keeps the floor's choice, and once dropped what the choice had put in sigma.
TEST(ResponseTest, TheFloorsMoveStaysInSigmaThroughTheRefitAtTheGeometryFound) {
  const auto truth = sim::MicrofacetTruth("beckmann", 0.344, 1.51);
  auto made = CentredSetup(3, 10, 9.6);
  made.bench.source_sr = made.bench.receiver_sr = 0;
  auto stated = made;
  stated.bench.thickness_sigma_mm = 0.6;
  const auto samples = MisstatedSamples(*truth, made, stated, 0, 31);
  fitting::FitOptions o;
  o.floor = fitting::Floor::kAuto;
  auto chosen = fitting::Fit(samples, o);
  ASSERT_TRUE(chosen.ok()) << chosen.error().message;
  ASSERT_TRUE(chosen->geometry.thickness.fitted) << chosen->geometry.note;
  ASSERT_NE(chosen->geometry.note.find("refitted at that geometry"), std::string::npos)
      << chosen->geometry.note;
  // Whichever way the choice went (on these data the floor is kept for a move of 0.6 sigma),
  // BIC did not make it.
  EXPECT_NE(chosen->floor_choice.find("which is in sigma"), std::string::npos)
      << chosen->floor_choice;
  // The same fit with the floor's choice imposed, which has no move to add.
  o.floor = chosen->floor_fitted ? fitting::Floor::kFit : fitting::Floor::kOff;
  auto imposed = fitting::Fit(samples, o);
  ASSERT_TRUE(imposed.ok());
  EXPECT_GT(std::abs(chosen->floor_width_shift), 0.1 * imposed->width.sigma) << "weak test";
  EXPECT_EQ(chosen->width.sigma_floor, std::abs(chosen->floor_width_shift));
  EXPECT_EQ(imposed->width.sigma_floor, 0);
  EXPECT_NEAR(chosen->width.value, imposed->width.value, 1e-9 * imposed->width.sigma);
  EXPECT_NEAR(chosen->width.sigma, std::hypot(imposed->width.sigma, chosen->floor_width_shift),
              1e-9 * imposed->width.sigma);
}

TEST(ResponseTest, AnExportsResponseLineIsReadBackAndABadOneIsNamedByLine) {
  const auto setup = CentredSetup(1, 3, 6);
  const std::string header =
      "theta_l_deg,theta_v_deg,value,sigma,sample_read_deg,arm_read_deg,azimuth_read_deg\n";
  const std::string row = "0,2.5,10,0.1,0,182.5,0\n";
  auto good = fitting::ParseSamplesCsv(
      "# run 1\n# response: " + setup.ToJson() + "\n" + header + row, "run1.csv");
  ASSERT_TRUE(good.ok()) << good.error().message;
  ASSERT_TRUE((*good)[0].response.has_value());
  EXPECT_DOUBLE_EQ((*good)[0].response->at.arm_deg, 182.5);
  auto bare = fitting::ParseSamplesCsv(header + row, "bare.csv");
  ASSERT_TRUE(bare.ok());
  EXPECT_FALSE((*bare)[0].response.has_value());  // the point model for files without one
  auto bad =
      fitting::ParseSamplesCsv("# run 1\n# response: {\"bench\": 1}\n" + header + row, "run1.csv");
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("run1.csv:2: response:"), std::string::npos)
      << bad.error().message;
  auto no_columns = fitting::ParseSamplesCsv(
      "# response: " + setup.ToJson() + "\ntheta_l_deg,theta_v_deg,value,sigma\n0,2.5,10,0.1\n",
      "run1.csv");
  ASSERT_FALSE(no_columns.ok());
  EXPECT_NE(no_columns.error().message.find("run1.csv:3:"), std::string::npos)
      << no_columns.error().message;
}

}  // namespace
}  // namespace gonio
