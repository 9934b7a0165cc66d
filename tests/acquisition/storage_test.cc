// Storage (acquisition/storage.h): the schema's version and migrations, points committed
// atomically and never twice, the interrupted run found again, and the export read back by the
// fitter's own CSV reader.
#include <gtest/gtest.h>
#include <sqlite3.h>

#include <cstdio>
#include <filesystem>
#include <string>
#include <thread>

#include "acquisition/storage.h"
#include "fitting/samples_csv.h"

namespace gonio::acquisition {
namespace {

class StorageTest : public ::testing::Test {
 protected:
  void SetUp() override {
    path = (std::filesystem::temp_directory_path() /
            ("gonio_storage_" + std::to_string(::getpid()) + "_" +
             ::testing::UnitTest::GetInstance()->current_test_info()->name() + ".sqlite"))
               .string();
    std::filesystem::remove(path);
  }
  void TearDown() override {
    for (const char* ext : {"", "-wal", "-shm"}) std::filesystem::remove(path + ext);
  }
  std::int64_t NewRun(Storage& s, int n_points, int n_skipped = 0) {
    std::vector<PlannedPoint> pts;
    for (int k = 0; k < n_points; ++k) {
      PlannedPoint p;
      p.index = k;
      p.theta_l_deg = 30;
      p.theta_v_deg = -20 + k;
      p.stage = StageTargetsFor(30, p.theta_v_deg);
      p.skipped = k < n_skipped;
      p.reason = p.skipped ? "test" : "";
      pts.push_back(p);
    }
    auto sp = s.EnsureSpecimen({"G1", "glass", 6, 1.51});
    auto cfg = s.StoreConfig("[camera]\n");
    EXPECT_TRUE(sp.ok() && cfg.ok());
    auto run = s.CreateRun(*sp, *cfg, "plan text", pts);
    EXPECT_TRUE(run.ok()) << run.error().message;
    return *run;
  }
  Measurement M(int index, double value) {
    Measurement m;
    m.index = index;
    m.value = value;
    m.sigma = 0.1;
    m.frames = 4;
    m.exposure_s = 0.5;
    m.rect_pixels = 100;
    return m;
  }
  std::string path;
};

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
  // Back to version 1: without the jobs (2) and the points' side (3).
  ASSERT_EQ(sqlite3_exec(db,
                         "DROP INDEX jobs_by_state; DROP TABLE jobs; "
                         "ALTER TABLE plan_points DROP COLUMN side; PRAGMA user_version=1",
                         nullptr, nullptr, nullptr),
            SQLITE_OK);
  sqlite3_close(db);
  auto s = Storage::Open(path);
  ASSERT_TRUE(s.ok()) << s.error().message;
  EXPECT_EQ((*s)->schema_version(), 3);
  auto rows = (*s)->Measurements(run);
  ASSERT_TRUE(rows.ok());
  ASSERT_EQ(rows->size(), 1u);
  EXPECT_EQ((*rows)[0].m.value, 42);
  EXPECT_FALSE((*rows)[0].point.reflection);  // the older runs were all transmission
  JobRecord j;
  j.name = "after.toml";
  j.plan_text = "sample = \"G1\"\n";
  j.state = "queued";
  EXPECT_TRUE((*s)->InsertJob(j).ok());
}

TEST_F(StorageTest, JobsKeepTheirQueueOrderStateAndOptions) {
  auto s = Storage::Open(path);
  ASSERT_TRUE(s.ok());
  std::vector<std::int64_t> ids;
  for (const char* name : {"a", "b", "c"}) {
    JobRecord j;
    j.name = name;
    j.plan_text = std::string("plan ") + name;
    j.state = "queued";
    j.options_json = std::string(R"({"fit":[")") + name + R"("]})";
    auto id = (*s)->InsertJob(j);
    ASSERT_TRUE(id.ok()) << id.error().message;
    ids.push_back(*id);
  }
  auto names = [&](int finished) {
    std::string out;
    auto jobs = (*s)->Jobs(finished);
    EXPECT_TRUE(jobs.ok());
    for (const JobRecord& j : *jobs) out += j.name + ":" + j.state + " ";
    return out;
  };
  EXPECT_EQ(names(10), "a:queued b:queued c:queued ");
  ASSERT_TRUE((*s)->SetQueueOrder({ids[2], ids[0], ids[1]}).ok());
  EXPECT_EQ(names(10), "c:queued a:queued b:queued ");
  const std::int64_t run = NewRun(**s, 2);
  JobRecord done;
  done.id = ids[0];
  done.state = "done";
  done.run = run;
  done.message = "fine";
  done.options_json = R"({"fit":["ggx"]})";
  ASSERT_TRUE((*s)->UpdateJob(done).ok());
  EXPECT_EQ(names(10), "c:queued b:queued a:done ");  // finished ones after the queue
  EXPECT_EQ(names(0), "c:queued b:queued ");
  auto jobs = (*s)->Jobs(10);
  ASSERT_TRUE(jobs.ok());
  const JobRecord& a = jobs->back();
  EXPECT_EQ(a.plan_text, "plan a");
  EXPECT_EQ(a.run, run);
  EXPECT_EQ(a.message, "fine");
  EXPECT_EQ(a.options_json, R"({"fit":["ggx"]})");
  done.id = 9999;
  const Status missing = (*s)->UpdateJob(done);
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.error().code, ErrorCode::kNotFound);
  done.id = ids[1];
  done.state = "sleeping";  // not a job state: refused by the schema, nothing changed
  EXPECT_FALSE((*s)->UpdateJob(done).ok());
  EXPECT_EQ(names(0), "c:queued b:queued ");
}

// The daemon's worker stores points while its API threads store jobs, on one connection: each
// call's transaction must run alone (a second BEGIN inside the first fails).
TEST_F(StorageTest, ThreadsSharingTheConnectionDoNotShareATransaction) {
  auto s = Storage::Open(path);
  ASSERT_TRUE(s.ok());
  constexpr int kPoints = 200;
  const std::int64_t run = NewRun(**s, kPoints);
  std::vector<std::int64_t> ids;
  int point_failures = 0, job_failures = 0;
  std::thread points([&] {
    for (int k = 0; k < kPoints; ++k)
      if (!(*s)->StoreMeasurement(run, M(k, k)).ok()) ++point_failures;
  });
  for (int k = 0; k < kPoints; ++k) {
    JobRecord j;
    j.name = "j" + std::to_string(k);
    j.plan_text = "p";
    j.state = "queued";
    auto id = (*s)->InsertJob(j);
    if (!id.ok()) {
      ++job_failures;
      continue;
    }
    ids.insert(ids.begin(), *id);
    if (!(*s)->SetQueueOrder(ids).ok()) ++job_failures;
  }
  points.join();
  EXPECT_EQ(point_failures, 0);
  EXPECT_EQ(job_failures, 0);
  auto rows = (*s)->Measurements(run);
  ASSERT_TRUE(rows.ok());
  EXPECT_EQ(static_cast<int>(rows->size()), kPoints);
  auto jobs = (*s)->Jobs(0);
  ASSERT_TRUE(jobs.ok());
  ASSERT_EQ(jobs->size(), static_cast<std::size_t>(kPoints));
  EXPECT_EQ(jobs->front().name, "j" + std::to_string(kPoints - 1));  // the last put first
}

TEST_F(StorageTest, PointsAreStoredOnceAndTheRestStayPending) {
  auto s = Storage::Open(path);
  ASSERT_TRUE(s.ok());
  const auto run = NewRun(**s, 5, 1);
  ASSERT_TRUE((*s)->SetRunStatus(run, "running").ok());
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
  ASSERT_TRUE((*s)->SetRunStatus(run, "done").ok());
  EXPECT_FALSE((*s)->UnfinishedRun()->has_value());
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
}

}  // namespace
}  // namespace gonio::acquisition
