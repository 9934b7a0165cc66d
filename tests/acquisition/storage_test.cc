// Storage (acquisition/storage.h): the schema's version and migrations, points committed
// atomically and never twice, the interrupted run found again, and the export read back by the
// fitter's own CSV reader.
#include <gtest/gtest.h>
#include <sqlite3.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "acquisition/exposure.h"
#include "acquisition/storage.h"
#include "config/instrument_config.h"
#include "fitting/samples_csv.h"
#include "tests/support/storage_fixture.h"

namespace gonio::acquisition {
namespace {

class StorageTest : public testing::StorageFixture {};

TEST_F(StorageTest, NewDatabaseIsMigratedToTheCurrentVersionAndANewerOneIsRefused) {
  {
    auto s = Storage::Open(path);
    ASSERT_TRUE(s.ok()) << s.error().message;
    EXPECT_EQ((*s)->schema_version(), kSchemaVersion);
  }
  {
    auto again = Storage::Open(path);  // reopening migrates nothing and keeps the data
    ASSERT_TRUE(again.ok());
    EXPECT_EQ((*again)->schema_version(), kSchemaVersion);
  }
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
  ASSERT_EQ(sqlite3_exec(db, "PRAGMA user_version=99", nullptr, nullptr, nullptr), SQLITE_OK);
  sqlite3_close(db);
  auto newer = Storage::Open(path);
  ASSERT_FALSE(newer.ok());
  EXPECT_NE(newer.error().message.find("schema version 99, newer than"), std::string::npos)
      << newer.error().message;
}

// An adaptive run's choices (#17) are appended after its last point, pending, with their plan,
// each with one 'chosen' event; they read back as they were stored.
TEST_F(StorageTest, ChosenPointsAreAppendedWithTheirPlanAndOneEventEach) {
  auto s = Storage::Open(path);
  ASSERT_TRUE(s.ok());
  const std::int64_t run = NewRun(**s, 3);
  PlannedPoint p;
  p.theta_l_deg = 30, p.theta_v_deg = -12.5;
  p.stage = {30, 197.5, 0};
  p.skipped = true, p.reason = "adaptive: a candidate, measured if chosen";
  p.planned_exposure_s = 0.75, p.predicted_s = 4.5;
  PlannedPoint q = p;
  q.theta_v_deg = -10, q.planned_exposure_s = 1.5, q.predicted_s = 7;
  auto added = (*s)->AddChosenPoints(run, {p, q}, {"the first reason", "the second reason"});
  ASSERT_TRUE(added.ok()) << added.error().message;
  EXPECT_EQ(*added, (std::vector<int>{3, 4}));
  auto pending = (*s)->Points(run, /*pending_only=*/true);
  ASSERT_TRUE(pending.ok());
  ASSERT_EQ(pending->size(), 5u);
  const PlannedPoint& back = (*pending)[4];
  EXPECT_EQ(back.index, 4);
  EXPECT_FALSE(back.skipped);
  EXPECT_EQ(back.reason, "");
  EXPECT_EQ(back.theta_v_deg, -10);
  ASSERT_TRUE(back.planned_exposure_s.has_value());
  EXPECT_EQ(*back.planned_exposure_s, 1.5);
  EXPECT_EQ(back.predicted_s, 7);
  EXPECT_FALSE((*pending)[0].planned_exposure_s.has_value());
  auto events = (*s)->Events(run);
  ASSERT_TRUE(events.ok());
  int chosen = 0;
  for (const RunEvent& e : *events)
    if (e.kind == "chosen") {
      ++chosen;
      EXPECT_TRUE(e.detail == "point 3: the first reason" ||
                  e.detail == "point 4: the second reason")
          << e.detail;
    }
  EXPECT_EQ(chosen, 2);
}

// Version 1 had no jobs table: a database written by that version keeps its runs and gains it.
TEST_F(StorageTest, AVersionOneDatabaseIsMigratedAndKeepsItsRuns) {
  std::int64_t run = 0;
  {
    auto s = Storage::Open(path);
    ASSERT_TRUE(s.ok());
    run = NewRun(**s, 3);
    ASSERT_TRUE((*s)->StoreMeasurement(run, M(1, 42)).ok());
  }
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
  // Back to version 1: without the jobs (2), the points' side (3), the runs' response and the
  // points' budget (4), the runs' estimate and the points' exposure (5), the chosen points'
  // plan (6), the measured backgrounds (7), the dark set's share of sigma_stat (8).
  ASSERT_EQ(sqlite3_exec(db,
                         "DROP INDEX jobs_by_state; DROP TABLE jobs; "
                         "ALTER TABLE plan_points DROP COLUMN planned_exposure_s; "
                         "ALTER TABLE plan_points DROP COLUMN predicted_s; "
                         "ALTER TABLE runs DROP COLUMN estimate_s; "
                         "ALTER TABLE runs DROP COLUMN estimate_exposure_s; "
                         "ALTER TABLE runs DROP COLUMN estimate_basis; "
                         "ALTER TABLE measurements DROP COLUMN exposed_s; "
                         "ALTER TABLE plan_points DROP COLUMN side; "
                         "ALTER TABLE runs DROP COLUMN response; "
                         "ALTER TABLE measurements DROP COLUMN sigma_stat; "
                         "ALTER TABLE measurements DROP COLUMN sigma_lamp; "
                         "ALTER TABLE measurements DROP COLUMN sigma_monitor; "
                         "ALTER TABLE measurements DROP COLUMN background; "
                         "ALTER TABLE measurements DROP COLUMN sigma_background; "
                         "ALTER TABLE measurements DROP COLUMN sigma_dark; "
                         "PRAGMA user_version=1",
                         nullptr, nullptr, nullptr),
            SQLITE_OK);
  sqlite3_close(db);
  auto s = Storage::Open(path);
  ASSERT_TRUE(s.ok()) << s.error().message;
  EXPECT_EQ((*s)->schema_version(), 8);
  auto rows = (*s)->Measurements(run);
  ASSERT_TRUE(rows.ok());
  ASSERT_EQ(rows->size(), 1u);
  EXPECT_EQ((*rows)[0].m.value, 42);
  // No background was measured for it (schema 7): none subtracted, none in sigma.
  EXPECT_FALSE((*rows)[0].m.background.has_value());
  EXPECT_EQ((*rows)[0].m.sigma_background, 0);
  EXPECT_EQ((*rows)[0].m.sigma_dark, 0);  // unknown for it (schema 8): none said shared
  // An older run has no estimate, and its points' exposure is unknown, not zero.
  auto info = (*s)->GetRun(run);
  ASSERT_TRUE(info.ok());
  EXPECT_FALSE(info->estimate.has_value());
  EXPECT_FALSE(info->exposed_s.has_value());
  EXPECT_FALSE((*rows)[0].point.reflection);  // the older runs were all transmission
  // The jobs table is back (the daemon's, daemon/service/job_store.h): a row goes in.
  ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
  EXPECT_EQ(sqlite3_exec(db,
                         "INSERT INTO jobs(name, plan, state, position) "
                         "VALUES('after.toml', 'sample = \"G1\"', 'queued', 1)",
                         nullptr, nullptr, nullptr),
            SQLITE_OK)
      << sqlite3_errmsg(db);
  sqlite3_close(db);
}

TEST_F(StorageTest, PointsAreStoredOnceAndTheRestStayPending) {
  auto s = Storage::Open(path);
  ASSERT_TRUE(s.ok());
  const auto run = NewRun(**s, 5, 1);
  ASSERT_TRUE((*s)->SetRunStatus(run, RunStatus::kRunning).ok());
  ASSERT_TRUE((*s)->StoreMeasurement(run, M(1, 10)).ok());
  ASSERT_TRUE((*s)->StoreMeasurement(run, M(2, 20)).ok());
  // Twice is refused, and the first value stays.
  const Status again = (*s)->StoreMeasurement(run, M(2, 99));
  ASSERT_FALSE(again.ok());
  // A skipped point is not measurable.
  EXPECT_FALSE((*s)->StoreMeasurement(run, M(0, 1)).ok());
  auto pending = (*s)->Points(run, true);
  ASSERT_TRUE(pending.ok());
  ASSERT_EQ(pending->size(), 2u);
  EXPECT_EQ((*pending)[0].index, 3);
  auto rows = (*s)->Measurements(run);
  ASSERT_EQ(rows->size(), 2u);
  EXPECT_EQ((*rows)[1].m.value, 20);
  auto info = (*s)->GetRun(run);
  EXPECT_EQ(info->points_done, 2);
  EXPECT_EQ(info->points_skipped, 1);
  auto unfinished = (*s)->UnfinishedRun();
  ASSERT_TRUE(unfinished.ok());
  ASSERT_TRUE(unfinished->has_value());
  EXPECT_EQ(**unfinished, run);
  ASSERT_TRUE((*s)->SetRunStatus(run, RunStatus::kDone).ok());
  EXPECT_FALSE((*s)->UnfinishedRun()->has_value());
}

// The engine re-estimates its pooled budget terms when a run ends (engine.h): the update changes
// sigma and those components and nothing else, and one naming a point the run has not stored is
// refused whole (the earlier points in it keep their budgets too).
TEST_F(StorageTest, ABudgetUpdateChangesTheSigmasOnlyAndAnUnknownPointChangesNothing) {
  auto s = Storage::Open(path);
  ASSERT_TRUE(s.ok());
  const auto run = NewRun(**s, 3, 0);
  ASSERT_TRUE((*s)->SetRunStatus(run, RunStatus::kRunning).ok());
  Measurement a = M(0, 10), b = M(1, 20);
  a.sigma_stat = b.sigma_stat = 0.1;
  ASSERT_TRUE((*s)->StoreMeasurement(run, a).ok());
  ASSERT_TRUE((*s)->StoreMeasurement(run, b).ok());
  const Status bad = (*s)->UpdateBudgets(run, {{.index = 0,
                                                .sigma = 0.5,
                                                .sigma_lamp = 0.4,
                                                .sigma_monitor = 0.3,
                                                .sigma_background = std::nullopt},
                                               {.index = 2,
                                                .sigma = 1,
                                                .sigma_lamp = 1,
                                                .sigma_monitor = 0,
                                                .sigma_background = std::nullopt}});
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.error().message.find("point 2 of run"), std::string::npos) << bad.error().message;
  auto rows = (*s)->Measurements(run);
  ASSERT_TRUE(rows.ok());
  EXPECT_EQ((*rows)[0].m.sigma, 0.1);
  EXPECT_EQ((*rows)[0].m.sigma_lamp, 0);
  ASSERT_TRUE((*s)->UpdateBudgets(run, {{.index = 1,
                                         .sigma = 0.5,
                                         .sigma_lamp = 0.4,
                                         .sigma_monitor = 0.3,
                                         .sigma_background = 0.02}})
                  .ok());
  rows = (*s)->Measurements(run);
  ASSERT_TRUE(rows.ok());
  const Measurement& m = (*rows)[1].m;
  EXPECT_EQ(m.value, 20);
  EXPECT_EQ(m.sigma_stat, 0.1);
  EXPECT_EQ(m.sigma, 0.5);
  EXPECT_EQ(m.sigma_lamp, 0.4);
  EXPECT_EQ(m.sigma_monitor, 0.3);
  EXPECT_EQ(m.sigma_background, 0.02);
  EXPECT_EQ((*rows)[0].m.sigma, 0.1);  // the other point untouched
}

// Issue #17: what the bench delivers, for estimates of specimens never measured, comes from a
// finished run with a chosen fit: the fit's scale and floor, and the counts per stored value
// (the median, so that one odd point does not decide).
TEST_F(StorageTest, TheBenchsThroughputComesFromAFinishedRunWithAChosenFit) {
  auto s = Storage::Open(path);
  ASSERT_TRUE(s.ok());
  Storage& db = **s;
  const auto run = NewRun(db, 3);
  DarkRecord d;
  d.exposure_s = 0.5;
  d.frames = 4;
  d.mean = 500;
  auto dark = db.StoreDark(d);
  ASSERT_TRUE(dark.ok());
  const double per_value[] = {3, 3.2, 30};  // ADU per second per unit of value; one stray point
  for (int k = 0; k < 3; ++k) {
    Measurement m = M(k, 10.0 * (k + 1));
    m.dark_id = *dark;
    m.rect_mean = 500 + m.value * per_value[k] * m.exposure_s;
    ASSERT_TRUE(db.StoreMeasurement(run, m).ok());
  }
  auto none = [&] {
    auto t = db.LatestThroughput();
    EXPECT_TRUE(t.ok());
    return t.ok() && !t->has_value();
  };
  EXPECT_TRUE(none()) << "no fit yet";
  ASSERT_TRUE(db.StoreFitResult(run, "ggx", R"({"scale": 7, "chosen": false})", "{}").ok());
  ASSERT_TRUE(
      db.StoreFitResult(run, "beckmann", R"({"scale": 5, "floor": 0.25, "chosen": true})", "{}")
          .ok());
  EXPECT_TRUE(none()) << "the run is not finished";
  ASSERT_TRUE(db.SetRunStatus(run, RunStatus::kDone).ok());
  auto t = db.LatestThroughput();
  ASSERT_TRUE(t.ok() && t->has_value());
  EXPECT_EQ((*t)->run, run);
  EXPECT_DOUBLE_EQ((*t)->scale, 5);  // the chosen fit's, not the other's
  EXPECT_DOUBLE_EQ((*t)->floor, 0.25);
  EXPECT_NEAR((*t)->adu_per_value, 3.2, 1e-9);
  EXPECT_DOUBLE_EQ((*t)->dark_adu, 500);
  // The points' sigmas calibrate the bench's noise per frame: each is 0.1 at 4 frames of 0.5 s
  // whatever its value, read noise alone: 0.1^2 x 4 frames x (0.5 s)^2.
  ASSERT_TRUE((*t)->noise.has_value());
  EXPECT_NEAR((*t)->noise->read, 0.01, 1e-9);
  EXPECT_NEAR((*t)->noise->shot, 0, 1e-9);
  EXPECT_NEAR((*t)->noise->lamp, 0, 1e-9);
}

TEST_F(StorageTest, ExportIsReadByTheFittersCsvReader) {
  auto s = Storage::Open(path);
  ASSERT_TRUE(s.ok());
  const auto run = NewRun(**s, 3);
  for (int k = 0; k < 3; ++k) ASSERT_TRUE((*s)->StoreMeasurement(run, M(k, 100 + k)).ok());
  const std::string csv = path + ".csv";
  ASSERT_TRUE((*s)->ExportCsv(run, csv).ok());
  auto samples = fitting::ReadSamplesCsv(csv);
  std::filesystem::remove(csv);
  ASSERT_TRUE(samples.ok()) << samples.error().message;
  ASSERT_EQ(samples->size(), 3u);
  EXPECT_EQ((*samples)[2].value, 102);
  EXPECT_EQ((*samples)[2].sigma, 0.1);
  EXPECT_FALSE((*samples)[2].background_subtracted);  // none measured: a floor may be fitted
}

// An export that fails leaves an earlier file of that name as it was, and nothing beside it: here
// a run that does not exist, as a typo in `gonio-acquire export RUN --out run.csv` would be.
TEST_F(StorageTest, AFailedExportLeavesAnEarlierFileUnchanged) {
  auto s = Storage::Open(path);
  ASSERT_TRUE(s.ok());
  const auto run = NewRun(**s, 2);
  for (int k = 0; k < 2; ++k) ASSERT_TRUE((*s)->StoreMeasurement(run, M(k, 100 + k)).ok());
  const std::string csv = path + ".csv";
  ASSERT_TRUE((*s)->ExportCsv(run, csv).ok());
  std::ifstream first(csv);
  const std::string before((std::istreambuf_iterator<char>(first)), {});
  ASSERT_NE(before.find("\n"), std::string::npos);
  const Status failed = (*s)->ExportCsv(run + 7, csv);
  EXPECT_FALSE(failed.ok());
  std::ifstream again(csv);
  const std::string after((std::istreambuf_iterator<char>(again)), {});
  EXPECT_EQ(after, before);
  EXPECT_FALSE(std::filesystem::exists(csv + ".partial"));
  std::filesystem::remove(csv);
}

// A measured background (schema 7) is stored with its sigma, read back, exported in its columns,
// and marks the fitter's samples as background-subtracted; a point without one exports empty.
TEST_F(StorageTest, AMeasuredBackgroundIsStoredExportedAndMarksTheSample) {
  auto s = Storage::Open(path);
  ASSERT_TRUE(s.ok());
  const auto run = NewRun(**s, 2);
  Measurement with = M(0, 100);
  with.background = 3.25;
  with.sigma_background = 0.0625;
  ASSERT_TRUE((*s)->StoreMeasurement(run, with).ok());
  ASSERT_TRUE((*s)->StoreMeasurement(run, M(1, 101)).ok());
  auto rows = (*s)->Measurements(run);
  ASSERT_TRUE(rows.ok());
  ASSERT_EQ(rows->size(), 2u);
  ASSERT_TRUE((*rows)[0].m.background.has_value());
  EXPECT_EQ(*(*rows)[0].m.background, 3.25);
  EXPECT_EQ((*rows)[0].m.sigma_background, 0.0625);
  EXPECT_FALSE((*rows)[1].m.background.has_value());
  std::ostringstream out;
  ASSERT_TRUE((*s)->ExportCsv(run, out).ok());
  const std::string text = out.str();
  EXPECT_NE(text.find(",background,sigma_background,dark_set,sigma_dark\n"), std::string::npos)
      << text;
  EXPECT_NE(text.find(",3.25,0.0625,,0\n"), std::string::npos) << text;
  auto samples = fitting::ParseSamplesCsv(text, "export");
  ASSERT_TRUE(samples.ok()) << samples.error().message;
  ASSERT_EQ(samples->size(), 2u);
  EXPECT_TRUE((*samples)[0].background_subtracted);
  EXPECT_FALSE((*samples)[1].background_subtracted);
}

// The dark set's share of sigma_stat (schema 8) is stored with the point and exported beside the
// set's id, so that the points that share it can be told: two points of one set carry its id.
TEST_F(StorageTest, TheDarkSetsShareOfSigmaIsStoredAndExportedWithTheSet) {
  auto s = Storage::Open(path);
  ASSERT_TRUE(s.ok());
  const auto run = NewRun(**s, 3);
  DarkRecord d;
  d.exposure_s = 0.5, d.frames = 4, d.mean = 510, d.pixel_var = 64;
  auto dark = (*s)->StoreDark(d);
  ASSERT_TRUE(dark.ok()) << dark.error().message;
  for (int k = 0; k < 2; ++k) {
    Measurement m = M(k, 100 + k);
    m.dark_id = *dark;
    m.sigma_stat = 0.1, m.sigma_dark = 0.046875;
    ASSERT_TRUE((*s)->StoreMeasurement(run, m).ok());
  }
  Measurement without = M(2, 102);  // no dark set
  without.monitor_w = 0.0017274321;
  ASSERT_TRUE((*s)->StoreMeasurement(run, without).ok());
  auto rows = (*s)->Measurements(run);
  ASSERT_TRUE(rows.ok());
  ASSERT_EQ(rows->size(), 3u);
  EXPECT_EQ((*rows)[1].m.sigma_dark, 0.046875);
  EXPECT_EQ((*rows)[1].m.dark_id, *dark);
  EXPECT_EQ((*rows)[2].m.sigma_dark, 0);
  std::ostringstream out;
  ASSERT_TRUE((*s)->ExportCsv(run, out).ok());
  const std::string text = out.str();
  const std::string shared = "," + std::to_string(*dark) + ",0.046875\n";
  std::size_t at = text.find(shared), count = 0;
  for (; at != std::string::npos; at = text.find(shared, at + 1)) ++count;
  EXPECT_EQ(count, 2u) << text;
  EXPECT_NE(text.find(",,0\n"), std::string::npos) << "the point without a set: " << text;
  EXPECT_NE(text.find(",0.0017274321,"), std::string::npos) << "the monitor's reading whole";
  auto samples = fitting::ParseSamplesCsv(text, "export");
  ASSERT_TRUE(samples.ok()) << samples.error().message;
  EXPECT_EQ(samples->size(), 3u);
}

}  // namespace
}  // namespace gonio::acquisition

namespace gonio::acquisition {
namespace {

// The demo's plan of the ground glass on the demo bench's axes.
struct DemoPlan {
  Plan plan;
  std::vector<PlannedPoint> points;
  std::vector<devices::AxisSettings> axes;
};
DemoPlan LoadDemoPlan() {
  PlanContext c;
  auto specimens = LoadSpecimens(GONIO_SOURCE_DIR "/config/samples.toml");
  EXPECT_TRUE(specimens.ok());
  if (specimens.ok()) c.specimens = *specimens;
  devices::AxisSettings sample{.name = "sample", .slave_id = 1};
  sample.min_deg = -90, sample.max_deg = 90;
  devices::AxisSettings arm{.name = "arm", .slave_id = 2};
  arm.min_deg = 0, arm.max_deg = 360;
  c.axes = {sample, arm};
  c.image_width = c.image_height = 512;
  auto plan = LoadPlan(GONIO_SOURCE_DIR "/config/plan_demo.toml", c);
  EXPECT_TRUE(plan.ok()) << (plan.ok() ? "" : plan.error().message);
  DemoPlan d{plan.ok() ? *plan : Plan{}, {}, c.axes};
  if (plan.ok()) d.points = ExpandPoints(*plan, c);
  return d;
}

// A new database has no run to price a plan on: its estimate says so and gives the motion only,
// never the plan's first exposure (where ranging starts: 90 times short on the demo). With the
// instrument config's [throughput] (config/instrument.toml's, read as goniod reads it) the
// exposures are priced from the specimen's expected lobe, far above that first exposure.
TEST_F(StorageTest, ANewDatabaseIsPricedFromTheConfiguredThroughputOrSaysWhyItCannotBe) {
  auto s = Storage::Open(path);
  ASSERT_TRUE(s.ok());
  const DemoPlan d = LoadDemoPlan();
  ASSERT_FALSE(d.points.empty());
  EstimateParts naive;
  EstimateSeconds(d.plan, d.points, d.axes, d.plan.exposure.initial_s, nullptr, nullptr, &naive);

  auto unpriced = EstimateRun(**s, d.plan, d.points, d.axes, 65000, 12);
  ASSERT_TRUE(unpriced.ok()) << unpriced.error().message;
  EXPECT_FALSE(unpriced->priced);
  EXPECT_EQ(unpriced->exposure_s, 0);
  EXPECT_NEAR(unpriced->total_s, naive.motion_s, 1e-9);
  EXPECT_NE(unpriced->basis.find("exposures not priced: this database has no finished run with "
                                 "a fit"),
            std::string::npos)
      << unpriced->basis;

  auto cfg = config::LoadInstrumentConfig(GONIO_SOURCE_DIR "/config/instrument.toml");
  ASSERT_TRUE(cfg.ok()) << cfg.error().message;
  ASSERT_TRUE(cfg->throughput.has_value()) << "config/instrument.toml states the bench's";
  const Throughput configured = ThroughputOf(*cfg->throughput);
  EXPECT_EQ(configured.run, 0);
  EXPECT_TRUE(configured.noise.has_value());
  auto priced = EstimateRun(**s, d.plan, d.points, d.axes, 65000, 12, configured);
  ASSERT_TRUE(priced.ok()) << priced.error().message;
  EXPECT_TRUE(priced->priced);
  EXPECT_EQ(priced->basis, "the expected lobe (Beckmann alpha 0.344) at the configured throughput");
  EXPECT_GT(priced->exposure_s, 10 * naive.exposure_s);
  EXPECT_NEAR(priced->total_s, priced->exposure_s + naive.motion_s, 0.05 * priced->total_s);

  // A specimen with no expected width cannot be forecast even so: said, not guessed.
  DemoPlan unknown = d;
  unknown.plan.specimen.expected_alpha.reset();
  auto no_width = EstimateRun(**s, unknown.plan, unknown.points, d.axes, 65000, 12, configured);
  ASSERT_TRUE(no_width.ok());
  EXPECT_FALSE(no_width->priced);
  EXPECT_NE(no_width->basis.find("gives it no expected_alpha"), std::string::npos)
      << no_width->basis;
}

}  // namespace
}  // namespace gonio::acquisition
