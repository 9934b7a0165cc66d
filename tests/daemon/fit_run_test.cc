// Fitting a stored run (daemon/service/fit_run.h). A reflection run (the camera on the light
// side) is fitted with the BRDF (eq. 20): its side survives the database (plan_points.side), so
// this does not depend on the plan text.
#include "daemon/service/fit_run.h"

#include <gtest/gtest.h>

#include <sqlite3.h>
#include <unistd.h>
#include <algorithm>
#include <cmath>
#include <filesystem>

#include "fitting/model.h"

namespace gonio::daemon {
namespace {

TEST(FitRun, AReflectionRunIsFittedWithTheBrdfAndSun2008IsRefusedStoringNothing) {
  const std::string path = (std::filesystem::temp_directory_path() /
                            ("gonio_fit_run_" + std::to_string(::getpid()) + ".sqlite"))
                               .string();
  std::filesystem::remove(path);
  {
    auto db = acquisition::Storage::Open(path);
    ASSERT_TRUE(db.ok()) << db.error().message;
    std::vector<acquisition::PlannedPoint> pts;
    for (int k = 0; k < 12; ++k) {
      acquisition::PlannedPoint p;
      p.index = k;
      p.theta_l_deg = 30;
      p.theta_v_deg = 10 + 3 * k;
      p.reflection = true;
      p.stage = StageTargetsForReflection(30, p.theta_v_deg);
      pts.push_back(p);
    }
    auto sp = (*db)->EnsureSpecimen({"G1", "glass", 6, 1.51, std::nullopt});
    auto cfg = (*db)->StoreConfig("[camera]\n");
    ASSERT_TRUE(sp.ok() && cfg.ok());
    auto run = (*db)->CreateRun(*sp, *cfg, "side = \"reflection\"", pts);
    ASSERT_TRUE(run.ok()) << run.error().message;
    for (const auto& p : pts) {
      // The directions from the stages, as the bench places them (response.h's conventions): the
      // source at polar angle s, the camera at s - arm in the plane of incidence.
      const double s_rad = p.stage.sample_deg * M_PI / 180;
      const double c_rad = (p.stage.sample_deg - p.stage.arm_deg) * M_PI / 180;
      const optics::Vec3<double> l{std::sin(s_rad), 0, std::cos(s_rad)};
      const optics::Vec3<double> v{std::sin(c_rad), 0, std::cos(c_rad)};
      acquisition::Measurement m;
      m.index = p.index;
      m.value = fitting::MeasurementModel(fitting::ModelSpec{}, l, v, 0.344, 1000.0, 1.51);
      m.sigma = 0.01 * m.value;
      m.frames = 4;
      m.exposure_s = 1;
      m.rect_pixels = 100;
      ASSERT_TRUE((*db)->StoreMeasurement(*run, m).ok());
    }
    auto sun = FitRun(**db, *run, {"beckmann", "sun2008"});
    ASSERT_FALSE(sun.ok());
    EXPECT_NE(sun.error().message.find("sun2008 is a transmission model"), std::string::npos)
        << sun.error().message;
    auto stored = (*db)->FitResults(*run);
    ASSERT_TRUE(stored.ok());
    EXPECT_TRUE(stored->empty());
    std::vector<std::string> told;
    auto fits = FitRun(**db, *run, {"beckmann", "ggx"},
                       [&told](const std::string& m) { told.push_back(m); });
    ASSERT_TRUE(fits.ok()) << fits.error().message;
    ASSERT_EQ(fits->size(), 2u);
    // The progress names each model and each solve's end.
    for (const char* model : {"beckmann", "ggx"})
      EXPECT_TRUE(std::any_of(told.begin(), told.end(),
                              [model](const std::string& m) {
                                return m.rfind(model, 0) == 0 &&
                                       m.find("solved") != std::string::npos;
                              }))
          << model << ": " << (told.empty() ? "nothing told" : told.back());
    EXPECT_EQ((*fits)[0].summary.status, fitting::FitStatus::kConverged);
    EXPECT_NEAR((*fits)[0].summary.width.value, 0.344, 1e-4);
    EXPECT_NEAR((*fits)[0].summary.scale.value, 1000, 0.1);
    stored = (*db)->FitResults(*run);
    ASSERT_TRUE(stored.ok());
    EXPECT_EQ(stored->size(), 2u);
  }
  for (const char* ext : {"", "-wal", "-shm"}) std::filesystem::remove(path + ext);
}

// A fit's progress as goniod's events: the first message, then at most one each interval.
TEST(FitRun, ProgressEventsAreThrottledAndNameTheRun) {
  EventLog events;
  auto slow = FitProgressEvents(events, 7, std::chrono::hours(1));
  for (const char* m : {"first", "second", "third"}) slow(m);
  auto all = events.After(0, std::chrono::milliseconds(0));
  ASSERT_EQ(all.size(), 1u);
  EXPECT_EQ(all[0].type, "fit_progress");
  EXPECT_EQ(all[0].data.at("run"), 7);
  EXPECT_EQ(all[0].data.at("message"), "first");
  EXPECT_GE(all[0].data.at("seconds").get<double>(), 0);
  auto each = FitProgressEvents(events, 8, std::chrono::milliseconds(0));
  for (const char* m : {"a", "b", "c"}) each(m);
  EXPECT_EQ(events.After(all[0].seq, std::chrono::milliseconds(0)).size(), 3u);
}

// A run stored with its instrument response is fitted through it; the same run with the stored
// response corrupted is refused naming the run, and nothing stored is changed.
TEST(FitRun, ARunsStoredResponseIsUsedAndACorruptOneIsRefusedChangingNothing) {
  const std::string path = (std::filesystem::temp_directory_path() /
                            ("gonio_fit_response_" + std::to_string(::getpid()) + ".sqlite"))
                               .string();
  std::filesystem::remove(path);
  {
    auto db = acquisition::Storage::Open(path);
    ASSERT_TRUE(db.ok()) << db.error().message;
    fitting::ResponseSetup setup;  // the default bench, a 1 x 3 mm rectangle at the pole
    setup.rectangle = {0, 0, 1, 1, 253, 246, 6, 19};
    std::vector<acquisition::PlannedPoint> pts;
    const double tt = std::asin(std::sin(30 * M_PI / 180) / 1.51) * 180 / M_PI;
    for (int k = 0; k < 15; ++k) {
      acquisition::PlannedPoint p;
      p.index = k;
      p.theta_l_deg = 30;
      p.theta_v_deg = -tt - 14 + 2 * k;
      p.stage = StageTargetsFor(30, p.theta_v_deg);
      pts.push_back(p);
    }
    acquisition::Plan plan;
    plan.specimen = {"G1", "glass", 6, 1.51, std::nullopt};
    plan.text = "sample = \"G1\"";
    auto run = (*db)->NewRun(plan, "[camera]\n", pts, setup.ToJson());
    ASSERT_TRUE(run.ok()) << run.error().message;
    for (const auto& p : pts) {
      const auto s = fitting::SampleFromBenchAngles(30, 0, p.theta_v_deg, 0, 0, 0);
      acquisition::Measurement m;
      m.index = p.index;
      m.sample_read_deg = p.stage.sample_deg;
      m.arm_read_deg = p.stage.arm_deg;
      m.value = fitting::MeasurementModel(fitting::ModelSpec{}, s.light, s.view, 0.3, 1000.0, 1.51);
      m.sigma = m.sigma_stat = 0.01 * m.value + 0.01;
      m.frames = 4;
      m.exposure_s = 1;
      m.rect_pixels = 114;
      ASSERT_TRUE((*db)->StoreMeasurement(*run, m).ok());
    }
    auto fits = FitRun(**db, *run, {"beckmann"});
    ASSERT_TRUE(fits.ok()) << fits.error().message;
    ASSERT_EQ(fits->size(), 1u);
    EXPECT_EQ((*fits)[0].summary.response.samples_with_response, 15);
    auto stored = (*db)->FitResults(*run);
    ASSERT_TRUE(stored.ok());
    ASSERT_EQ(stored->size(), 1u);
    auto before = (*db)->Measurements(*run);
    ASSERT_TRUE(before.ok());

    // The stored fit at every point (the console's dashed line): through the data it was fitted to.
    auto predicted = PredictRun(**db, *run, (*stored)[0].id);
    ASSERT_TRUE(predicted.ok()) << predicted.error().message;
    ASSERT_EQ(predicted->size(), before->size());
    for (std::size_t i = 0; i < before->size(); ++i) {
      EXPECT_EQ((*predicted)[i].index, (*before)[i].point.index);
      EXPECT_NEAR((*predicted)[i].theta_v_deg, (*before)[i].point.theta_v_deg, 1e-9);
      EXPECT_NEAR((*predicted)[i].value / (*before)[i].m.value, 1, 0.05) << i;
    }
    auto unknown = PredictRun(**db, *run, (*stored)[0].id + 100);
    ASSERT_FALSE(unknown.ok());
    EXPECT_EQ(unknown.error().code, ErrorCode::kNotFound);

    sqlite3* raw = nullptr;
    ASSERT_EQ(sqlite3_open(path.c_str(), &raw), SQLITE_OK);
    // A stored fit whose parameters do not parse is named, not drawn as some number.
    ASSERT_EQ(sqlite3_exec(raw, "UPDATE fit_results SET parameters='{\"width\": \"x\"}'", nullptr,
                           nullptr, nullptr),
              SQLITE_OK);
    auto damaged = PredictRun(**db, *run, (*stored)[0].id);
    ASSERT_FALSE(damaged.ok());
    EXPECT_EQ(damaged.error().code, ErrorCode::kFailedPrecondition);
    EXPECT_NE(damaged.error().message.find("\"width\""), std::string::npos)
        << damaged.error().message;
    ASSERT_EQ(
        sqlite3_exec(raw, "UPDATE runs SET response='{\"bench\": 3}'", nullptr, nullptr, nullptr),
        SQLITE_OK);
    sqlite3_close(raw);
    auto again = FitRun(**db, *run, {"beckmann"});
    ASSERT_FALSE(again.ok());
    EXPECT_EQ(again.error().code, ErrorCode::kFailedPrecondition);
    EXPECT_NE(again.error().message.find("stored instrument response is corrupt"),
              std::string::npos)
        << again.error().message;
    EXPECT_NE(again.error().message.find("run " + std::to_string(*run)), std::string::npos);
    auto stored_after = (*db)->FitResults(*run);
    auto after = (*db)->Measurements(*run);
    ASSERT_TRUE(stored_after.ok() && after.ok());
    EXPECT_EQ(stored_after->size(), 1u);
    ASSERT_EQ(after->size(), before->size());
    for (std::size_t i = 0; i < after->size(); ++i)
      EXPECT_EQ((*after)[i].m.value, (*before)[i].m.value);
  }
  for (const char* ext : {"", "-wal", "-shm"}) std::filesystem::remove(path + ext);
}

}  // namespace
}  // namespace gonio::daemon
