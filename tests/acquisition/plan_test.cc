// Plans (acquisition/plan.h): bad plans are refused with file:line before anything moves; the
// point order is a serpentine; unreachable geometries are skipped with a reason.
#include <gtest/gtest.h>

#include <string>

#include "acquisition/plan.h"

namespace gonio::acquisition {
namespace {

const std::string kData = GONIO_TEST_DATA;

PlanContext Context() {
  PlanContext c;
  auto specimens = LoadSpecimens(GONIO_SOURCE_DIR "/config/samples.toml");
  EXPECT_TRUE(specimens.ok());
  if (specimens.ok()) c.specimens = *specimens;
  drivers::AxisSettings sample{.name = "sample", .slave_id = 1};
  sample.min_deg = -80, sample.max_deg = 80;
  drivers::AxisSettings arm{.name = "arm", .slave_id = 2};
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
                      "ground-glass-G1, etched-glass-E1)"),
            std::string::npos)
      << Refusal("unknown_sample.toml");
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
  p->view_about = "refracted";
  const auto points = ExpandPoints(*p, Context());
  // theta_l 30 in glass of eta 1.51: theta_t = 19.34 deg, so offset 0 is theta_v = -19.34.
  EXPECT_NEAR(points[7].theta_v_deg, -19.3372, 1e-3);
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
