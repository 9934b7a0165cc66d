// Plans (acquisition/plan.h): bad plans are refused with file:line before anything moves; the
// point order is a serpentine; unreachable geometries are skipped with a reason.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <string>

#include "acquisition/exposure.h"
#include "acquisition/plan.h"
#include "fitting/model.h"

namespace gonio::acquisition {
namespace {

const std::string kData = GONIO_TEST_DATA;

PlanContext Context() {
  PlanContext c;
  auto specimens = LoadSpecimens(GONIO_SOURCE_DIR "/config/samples.toml");
  EXPECT_TRUE(specimens.ok());
  if (specimens.ok()) c.specimens = *specimens;
  devices::AxisSettings sample{.name = "sample", .slave_id = 1};
  sample.min_deg = -80, sample.max_deg = 80;
  devices::AxisSettings arm{.name = "arm", .slave_id = 2};
  arm.min_deg = 0, arm.max_deg = 360;
  c.axes = {sample, arm};
  c.image_width = c.image_height = 512;
  return c;
}

std::string Refusal(const std::string& file) {
  auto p = LoadPlan(kData + "/plans/" + file, Context());
  EXPECT_FALSE(p.ok()) << file << " was accepted";
  return p.ok() ? "" : p.error().message;
}

TEST(Plan, BadPlansAreRefusedWithFileAndLine) {
  EXPECT_NE(Refusal("beyond_limits.toml").find("beyond_limits.toml:4: incidence: sample at 85"),
            std::string::npos)
      << Refusal("beyond_limits.toml");
  EXPECT_NE(Refusal("zero_frames.toml").find("zero_frames.toml:5: 'frames' = 0 is outside"),
            std::string::npos)
      << Refusal("zero_frames.toml");
  EXPECT_NE(Refusal("rect_outside.toml")
                .find("rect_outside.toml:4: the rectangle 20x19 at (500, "
                      "240) is outside the 512x512 image"),
            std::string::npos)
      << Refusal("rect_outside.toml");
  EXPECT_NE(Refusal("unknown_sample.toml")
                .find("unknown_sample.toml:2: unknown sample 'frosted-F9' (the catalogue has: "
                      "ground-glass-G1, frosted-glass-F1, etched-glass-E1, antiglare-A1)"),
            std::string::npos)
      << Refusal("unknown_sample.toml");
  // A table that is missing has no line: the message says the whole file was searched.
  auto no_rect = LoadPlanText(
      "sample = \"ground-glass-G1\"\n[geometry]\nincidence_deg = [0]\nview_about = "
      "\"refracted\"\nview_from_deg = -5\nview_to_deg = 5\nview_step_deg = 5\n"
      "[exposure]\nframes = 2\n",
      "norect.toml", Context());
  ASSERT_FALSE(no_rect.ok());
  EXPECT_NE(no_rect.error().message.find("norect.toml: (whole file) the plan has no [rectangle]"),
            std::string::npos)
      << no_rect.error().message;
}

// Issue #19: a camera without a temperature sensor or a shutter is a camera (info, snap), but a
// run needs both (each point records the temperature; darks need the shutter): refused at once.
TEST(Plan, ARunIsRefusedForACameraWithoutWhatARunNeeds) {
  PlanContext c = Context();
  c.camera_missing = "no shutter for dark frames";
  auto p = LoadPlan(kData + "/plans/good.toml", c);
  ASSERT_FALSE(p.ok());
  EXPECT_NE(p.error().message.find("good.toml"), std::string::npos) << p.error().message;
  EXPECT_NE(p.error().message.find("its camera has no shutter"), std::string::npos)
      << p.error().message;
}

TEST(Plan, PointsRunASerpentineAndUnreachableOnesAreSkipped) {
  auto p = LoadPlan(kData + "/plans/good.toml", Context());
  ASSERT_TRUE(p.ok()) << p.error().message;
  const auto points = ExpandPoints(*p, Context());
  ASSERT_EQ(points.size(), 10u);
  // Incidence 0 sweeps up, incidence 30 sweeps back down: the arm never flies back.
  EXPECT_EQ(points[0].theta_v_deg, -10);
  EXPECT_EQ(points[4].theta_v_deg, 10);
  EXPECT_EQ(points[5].theta_l_deg, 30);
  EXPECT_EQ(points[5].theta_v_deg, 10);
  EXPECT_EQ(points[9].theta_v_deg, -10);
  // Straight through at normal incidence: arm 180.
  EXPECT_DOUBLE_EQ(points[2].stage.arm_deg, 180);
  for (const auto& pt : points) EXPECT_FALSE(pt.skipped) << pt.reason;
  // An arm limited to [0, 185] cannot reach theta_l 30 + theta_v 10 + 180 = 220: skipped, said why.
  PlanContext narrow = Context();
  narrow.axes[1].max_deg = 185;
  const auto limited = ExpandPoints(*p, narrow);
  EXPECT_TRUE(limited[5].skipped);
  EXPECT_NE(limited[5].reason.find("arm at 220 deg is outside its travel limits"),
            std::string::npos)
      << limited[5].reason;
  EXPECT_FALSE(limited[0].skipped);
}

TEST(Plan, RefractedViewsCentreEachIncidencesLobe) {
  auto p = LoadPlan(kData + "/plans/good.toml", Context());
  ASSERT_TRUE(p.ok());
  p->view_about = ViewAbout::kRefracted;
  const auto points = ExpandPoints(*p, Context());
  // theta_l 30 in glass of eta 1.51: theta_t = 19.34 deg, so offset 0 is theta_v = -19.34.
  EXPECT_NEAR(points[7].theta_v_deg, -19.3372, 1e-3);
}

// Reflection plans put the camera on the light side: arm = theta_l + theta_v, specular at
// theta_v = theta_l, and the view back along the beam (retro-reflection) is skipped, not taken.
TEST(Plan, ReflectionPlansSweepAboutTheSpecularDirectionAndSkipTheSourceBeam) {
  const std::string text =
      "sample = \"ground-glass-G1\"\n[geometry]\nside = \"reflection\"\n"
      "incidence_deg = [0, 40]\nview_about = \"specular\"\nview_from_deg = -10\n"
      "view_to_deg = 10\nview_step_deg = 10\n[rectangle]\nx = 253\ny = 246\nwidth = 6\n"
      "height = 19\n";
  auto p = LoadPlanText(text, "r.toml", Context());
  ASSERT_TRUE(p.ok()) << p.error().message;
  const auto points = ExpandPoints(*p, Context());
  ASSERT_EQ(points.size(), 6u);
  for (const auto& pt : points) EXPECT_TRUE(pt.reflection);
  // theta_l 0: views -10, 0, 10 about the specular direction 0; arm = theta_l + theta_v.
  EXPECT_DOUBLE_EQ(points[0].theta_v_deg, -10);
  EXPECT_DOUBLE_EQ(points[0].stage.arm_deg, 350);
  EXPECT_FALSE(points[0].skipped) << points[0].reason;
  // Normal incidence, normal view: the camera would sit in the source beam.
  EXPECT_TRUE(points[1].skipped);
  EXPECT_NE(points[1].reason.find("block the source beam"), std::string::npos) << points[1].reason;
  // theta_l 40 sweeps back: 50, 40 (specular, arm 80), 30.
  EXPECT_DOUBLE_EQ(points[3].theta_v_deg, 50);
  EXPECT_DOUBLE_EQ(points[4].theta_v_deg, 40);
  EXPECT_DOUBLE_EQ(points[4].stage.arm_deg, 80);
  EXPECT_FALSE(points[4].skipped);
  // The view about a refracted direction means nothing on the light side, and the reverse.
  auto bad = LoadPlanText(
      "sample = \"ground-glass-G1\"\n[geometry]\nside = \"reflection\"\n"
      "incidence_deg = [0]\nview_about = \"refracted\"\n",
      "r.toml", Context());
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.error().message.rfind("r.toml:5: view_about 'refracted' is for side = "
                                      "\"transmission\"",
                                      0),
            0u)
      << bad.error().message;
  // The example plans in config/ load, and the reflection example skips its retro views.
  auto example = LoadPlan(GONIO_SOURCE_DIR "/config/plan_reflection.toml", Context());
  ASSERT_TRUE(example.ok()) << example.error().message;
  int retro = 0;
  for (const auto& pt : ExpandPoints(*example, Context())) {
    EXPECT_TRUE(pt.reflection);
    if (pt.skipped) {
      ++retro;
      EXPECT_NEAR(pt.theta_v_deg, -pt.theta_l_deg, 4) << pt.reason;  // back along the beam
    }
  }
  EXPECT_EQ(retro, 1);  // theta_l 20, offset -40: theta_v -20, arm 0
  EXPECT_TRUE(LoadPlan(GONIO_SOURCE_DIR "/config/plan_ground_glass.toml", Context()).ok());
  auto sideways = LoadPlanText(
      "sample = \"ground-glass-G1\"\n[geometry]\nside = \"sideways\"\nincidence_deg = [0]\n",
      "s.toml", Context());
  ASSERT_FALSE(sideways.ok());
  EXPECT_NE(sideways.error().message.find("s.toml:3:"), std::string::npos)
      << sideways.error().message;
}

// [rectangle] auto: the largest rectangle whose spread of directions changes the expected lobe by
// at most tolerance x expected_sigma. Checked here against the response computed in the test: the
// chosen one is within the allowance and the next larger one is not; the narrow antiglare lobe
// gets a far smaller rectangle than ground glass (Walter: "smaller for less-diffusing samples").
double WorstChange(const Plan& plan, const PlanContext& ctx, double alpha) {
  fitting::ResponseSetup setup = *ctx.response;
  setup.rectangle.x = plan.rectangle.x;
  setup.rectangle.y = plan.rectangle.y;
  setup.rectangle.width = plan.rectangle.width;
  setup.rectangle.height = plan.rectangle.height;
  double worst = 0;
  for (const PlannedPoint& p : ExpandPoints(plan, ctx)) {
    auto r = fitting::ComputeResponse(setup, {p.stage.sample_deg, p.stage.arm_deg, 0}, 0);
    EXPECT_TRUE(r.ok());
    if (!r.ok()) return 1e9;
    double avg = 0;
    for (const auto& ray : r->rays)
      avg += ray.weight * fitting::MeasurementModel({}, ray.l, ray.v, alpha, 1.0, 1.51);
    avg /= r->pixels;
    const double point = fitting::MeasurementModel({}, r->l0, r->v0, alpha, 1.0, 1.51);
    // The lobe's peak at this incidence: the straight-through (refracted) view.
    const double tt = std::asin(std::sin(p.theta_l_deg * M_PI / 180) / 1.51);
    const optics::Vec3<double> snell{-std::sin(tt), 0, -std::cos(tt)};
    const double peak = fitting::MeasurementModel({}, r->l0, snell, alpha, 1.0, 1.51);
    if (point > 0.1 * peak) worst = std::max(worst, std::abs(avg / point - 1));
  }
  return worst;
}

TEST(Plan, AnAutoRectangleIsTheLargestThatKeepsTheExpectedLobe) {
  PlanContext ctx = Context();
  ctx.response = fitting::ResponseSetup{};
  ctx.response->bench.mm_per_pixel = 0.04;  // a finer pitch than the demo's, so both lobes fit
  auto load = [&](const std::string& sample, const std::string& views, const std::string& extra) {
    return LoadPlanText(
        "sample = \"" + sample +
            "\"\n[geometry]\nincidence_deg = [0, 30]\nview_about = \"refracted\"\n" + views +
            "\n[rectangle]\nauto = true\ntolerance = 1\n" + extra,
        "auto.toml", ctx);
  };
  const std::string glare_views = "view_from_deg = -1\nview_to_deg = 1\nview_step_deg = 0.25";
  auto ground =
      load("ground-glass-G1", "view_from_deg = -10\nview_to_deg = 10\nview_step_deg = 2.5", "");
  // A narrow lobe is measured with less precision per point (1 %) and a square rectangle.
  auto glare = load("antiglare-A1", glare_views, "aspect = 1\nexpected_sigma = 0.01\n");
  ASSERT_TRUE(ground.ok()) << ground.error().message;
  ASSERT_TRUE(glare.ok()) << glare.error().message;
  EXPECT_NE(ground->rectangle_reason.find("rectangle auto: "), std::string::npos);
  EXPECT_LT(glare->rectangle.width * glare->rectangle.height,
            ground->rectangle.width * ground->rectangle.height);
  std::printf("%s\n%s\n", ground->rectangle_reason.c_str(), glare->rectangle_reason.c_str());
  for (const auto& [plan, alpha] : {std::pair{&*ground, 0.344}, std::pair{&*glare, 0.023}}) {
    ASSERT_TRUE(plan->auto_rectangle.has_value());
    const AutoRectangle& a = *plan->auto_rectangle;
    const double allowed = a.tolerance * a.expected_sigma;
    EXPECT_EQ(plan->rectangle_reason.find("NOT within"), std::string::npos)
        << plan->rectangle_reason;
    EXPECT_LE(WorstChange(*plan, ctx, alpha), allowed * 1.05) << plan->rectangle_reason;
    Plan bigger = *plan;
    bigger.rectangle.width += 2;
    bigger.rectangle.height =
        2 * static_cast<int>(std::lround(a.aspect * bigger.rectangle.width / 2));
    bigger.rectangle.x = 256 - bigger.rectangle.width / 2;
    bigger.rectangle.y = 256 - bigger.rectangle.height / 2;
    EXPECT_GT(WorstChange(bigger, ctx, alpha), allowed * 0.95) << plan->rectangle_reason;
    // Centred on the image (even sizes: symmetric about its centre), of the plan's aspect.
    EXPECT_EQ(plan->rectangle.x, 256 - plan->rectangle.width / 2);
    EXPECT_EQ(plan->rectangle.width % 2, 0);
    EXPECT_EQ(plan->rectangle.height, 2 * std::lround(a.aspect * plan->rectangle.width / 2));
  }
  // On the demo's coarser pitch no rectangle keeps the antiglare lobe: the smallest is taken, and
  // the reason says so.
  ctx.response->bench.mm_per_pixel = 0.16;
  auto coarse = load("antiglare-A1", glare_views, "");
  ASSERT_TRUE(coarse.ok()) << coarse.error().message;
  EXPECT_EQ(coarse->rectangle.width, 2);
  EXPECT_NE(coarse->rectangle_reason.find("NOT within it"), std::string::npos)
      << coarse->rectangle_reason;
  // Without the bench's geometry, or a specimen without an expected width: refused by line.
  PlanContext bare = Context();
  auto no_bench = LoadPlanText(
      "sample = \"antiglare-A1\"\n[geometry]\nincidence_deg = [0]\n[rectangle]\nauto = true\n",
      "auto.toml", bare);
  ASSERT_FALSE(no_bench.ok());
  EXPECT_NE(no_bench.error().message.find("auto.toml:4: [rectangle] auto needs the bench's"),
            std::string::npos)
      << no_bench.error().message;
  ctx.specimens.push_back({"unknown-U1", "", 6, 1.51, std::nullopt});
  auto no_alpha = LoadPlanText(
      "sample = \"unknown-U1\"\n[geometry]\nincidence_deg = [0]\n[rectangle]\nauto = true\n",
      "auto.toml", ctx);
  ASSERT_FALSE(no_alpha.ok());
  EXPECT_NE(no_alpha.error().message.find("give 'unknown-U1' an expected_alpha"), std::string::npos)
      << no_alpha.error().message;
}

TEST(Plan, EstimateGrowsWithExposureAndMotion) {
  auto p = LoadPlan(kData + "/plans/good.toml", Context());
  ASSERT_TRUE(p.ok());
  const auto points = ExpandPoints(*p, Context());
  const double fast = EstimateSeconds(*p, points, Context().axes, 0.01);
  const double slow = EstimateSeconds(*p, points, Context().axes, 1.0);
  // 10 points of (4 frames + 1 ranging frame): 5 * 0.99 s more each.
  EXPECT_NEAR(slow - fast, 10 * 5 * 0.99, 1e-9);
  EXPECT_GT(fast, 10 * 5 * 0.01);  // the motion adds to the exposures
}

// Issue #16 item 3: a plan may measure each point's background with the beam block. It is refused,
// by file:line, on a bench without one and for a single frame (no scatter for its sigma); with
// one it takes the bench's flag, and each point's estimate gains its background frames (the
// plan's, else the point's) and the flag's move in.
TEST(Plan, AMeasuredBackgroundNeedsABeamBlockAndIsPricedInTheEstimate) {
  std::ifstream in(kData + "/plans/good.toml");
  std::stringstream good;
  good << in.rdbuf();
  const std::string with_background = good.str() + "\n[background]\nmeasure = true\n";
  auto refused = LoadPlanText(with_background, "bg.toml", Context());
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.error().message.find(
                "bg.toml:" +
                std::to_string(std::count(with_background.begin(), with_background.end(), '\n')) +
                ": [background] measure = true needs a beam block"),
            std::string::npos)
      << refused.error().message;

  PlanContext ctx = Context();
  devices::AxisSettings flag{.name = "beam_block", .slave_id = 4};
  flag.min_deg = 0, flag.max_deg = 180, flag.speed_deg_s = 90, flag.acceleration_deg_s2 = 900;
  ctx.axes.push_back(flag);
  ctx.beam_block = devices::BeamBlockSettings{0, 90};
  auto one = LoadPlanText(with_background + "frames = 1\n", "one.toml", ctx);
  ASSERT_FALSE(one.ok());
  EXPECT_NE(one.error().message.find("one.toml:"), std::string::npos);
  EXPECT_NE(one.error().message.find("at least 2"), std::string::npos) << one.error().message;

  auto plain = LoadPlanText(good.str(), "plain.toml", ctx);
  auto measured = LoadPlanText(with_background, "bg.toml", ctx);
  auto six = LoadPlanText(with_background + "frames = 6\n", "six.toml", ctx);
  ASSERT_TRUE(plain.ok() && measured.ok() && six.ok());
  EXPECT_TRUE(plain->beam_block.has_value());  // the engine keeps the flag out either way
  EXPECT_FALSE(plain->background.measure);
  EXPECT_EQ(BackgroundFrames(*plain), 0);
  EXPECT_EQ(BackgroundFrames(*measured), plain->exposure.frames);
  EXPECT_EQ(BackgroundFrames(*six), 6);
  const auto points = ExpandPoints(*plain, ctx);
  const int n = static_cast<int>(std::count_if(points.begin(), points.end(),
                                               [](const PlannedPoint& p) { return !p.skipped; }));
  const double t = 0.5;  // every point at this exposure (no history, no forecast)
  const double base = EstimateSeconds(*plain, points, ctx.axes, t);
  // The flag's 90 deg at 90 deg/s, 900 deg/s^2: 1 s + 0.1 s, per point.
  EXPECT_NEAR(EstimateSeconds(*measured, points, ctx.axes, t) - base,
              n * (plain->exposure.frames * t + 1.1), 1e-9);
  EXPECT_NEAR(EstimateSeconds(*six, points, ctx.axes, t) - base, n * (6 * t + 1.1), 1e-9);
}

// Issue #17: before any run of the specimen, each point is priced by the engine's ranging played
// on the expected lobe. A lobe bright enough that the first try (0.05 s, the plan's) saturates
// is cut to a quarter, then scaled to the target; a point the lobe does not reach ranges up to
// max_s. Checked against the rule written out here, not against the estimate's own code.
TEST(Plan, BeforeAnyRunPointsArePricedByTheEnginesRangingOnTheExpectedLobe) {
  auto p = LoadPlan(kData + "/plans/good.toml", Context());
  ASSERT_TRUE(p.ok());
  std::vector<PlannedPoint> points = ExpandPoints(*p, Context());
  // One point: light at 0, straight through.
  points.resize(1);
  points[0].theta_l_deg = 0;
  points[0].theta_v_deg = 0;
  LobeForecast f;
  f.alpha = 0.344;
  f.eta = 1.51;
  f.bench.adu_per_value = 1;
  f.bench.dark_adu = 535;
  f.linear_limit_adu = 65535;  // range 65000
  f.bench.scale = 1;
  const double peak_f = f.Rate(points[0]);
  ASSERT_GT(peak_f, 0.5);  // Beckmann 0.344 at the straight-through view: about 0.7 per sr
  // The first try is the plan's 0.05 s on the 8-per-decade ladder, rounded down: 10^(-11/8).
  const double t0 = std::pow(10.0, -11.0 / 8);
  // Scale so that it reaches 95 % of the range: too bright (past 90 %). Next: t0 * min(0.25,
  // 0.5 / 0.95) = 0.0105 s, on the ladder 10^(-16/8) = 0.01 s, which gives 22.5 % of the range:
  // above a quarter of the target (12.5 %), kept.
  f.bench.scale = 0.95 * 65000 / t0 / peak_f;
  EstimateParts e;
  const double motion = EstimateSeconds(*p, points, Context().axes, 0, nullptr, nullptr);
  const double total = EstimateSeconds(*p, points, Context().axes, 0, nullptr, &f, &e);
  EXPECT_EQ(e.from_forecast, 1);
  EXPECT_EQ(e.ranging_frames, 1);
  // Tries t0 and 0.01 s, each with its dark set (4 frames), then 3 more frames at 0.01 s.
  EXPECT_NEAR(e.exposure_s, 5 * t0 + 5 * 0.01 + 3 * 0.01, 1e-9);
  EXPECT_NEAR(e.dark_exposure_s, 4 * t0 + 4 * 0.01, 1e-9);
  EXPECT_NEAR(total, motion + e.exposure_s, 1e-9);
  // The lobe does not reach it: t0, then x100 (10^(5/8) = 4.22 s), then x100 again, cut to
  // max_s (20 s), where nothing more is gained: kept.
  f.bench.scale = 0;
  EstimateSeconds(*p, points, Context().axes, 0, nullptr, &f, &e);
  EXPECT_EQ(e.ranging_frames, 2);
  const double t1 = std::pow(10.0, 5.0 / 8);
  EXPECT_NEAR(e.exposure_s, 5 * t0 + 5 * t1 + 5 * 20 + 3 * 20, 1e-9);
  // Run 0 is no run: the throughput the instrument config states.
  EXPECT_EQ(DescribeEstimateBasis(nullptr, &f),
            "the expected lobe (Beckmann alpha 0.344) at the configured throughput");
  f.bench.run = 7;
  EXPECT_EQ(DescribeEstimateBasis(nullptr, &f),
            "the expected lobe (Beckmann alpha 0.344) at run 7's throughput");
}

// With an earlier run's exposures, points are priced at what they took then: here every point at
// theta_l = 0 took 2 s after 3 ranging tries; theta_l = 30 was not measured, so it keeps the plan's
// typical exposure. Default policy: 4 frames averaged, 4 dark frames.
TEST(Plan, EstimateUsesAnEarlierRunsExposuresWhereItHasThem) {
  auto p = LoadPlan(kData + "/plans/good.toml", Context());
  ASSERT_TRUE(p.ok());
  const auto points = ExpandPoints(*p, Context());
  ExposureHistory h;
  h.run = 7;
  for (double v : {-10.4, -5.2, 0.3, 4.9, 9.6})  // near, not at, the planned views
    h.entries.push_back({0, v, 0, 2.0, 3});
  const double motion = EstimateSeconds(*p, points, Context().axes, 0.0);
  const double typical = 0.05;
  const double estimate = EstimateSeconds(*p, points, Context().axes, typical, &h);
  // theta_l 0: 5 points x (4 + 3 - 1) frames x 2 s, and one dark set of 4 x 2 s;
  // theta_l 30: 5 points x (4 + 1) frames x 0.05 s.
  EXPECT_NEAR(estimate, motion + 5 * 6 * 2.0 + 4 * 2.0 + 5 * 5 * typical, 1e-9);
  // An incidence at 0.5 deg from a measured one still matches; 2 deg away does not.
  PlannedPoint q;
  q.theta_l_deg = 0.5;
  q.theta_v_deg = 1;
  ASSERT_TRUE(h.Near(q).has_value());
  EXPECT_EQ(h.Near(q)->theta_v_deg, 0.3);
  q.theta_l_deg = 2;
  EXPECT_FALSE(h.Near(q).has_value());
}

}  // namespace
}  // namespace gonio::acquisition
