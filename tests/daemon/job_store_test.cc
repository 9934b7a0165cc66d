// The daemon's job store (daemon/service/job_store.h): the queue's order, each job's state, run,
// message and options kept in the run database's file, and job writes from API threads that never
// land inside the worker's point transaction on the shared connection.
#include "daemon/service/job_store.h"

#include <gtest/gtest.h>
#include <sqlite3.h>

#include <string>
#include <thread>
#include <vector>

#include "tests/support/storage_fixture.h"

namespace gonio::daemon {
namespace {

class JobStoreTest : public testing::StorageFixture {};

TEST_F(JobStoreTest, JobsKeepTheirQueueOrderStateAndOptions) {
  auto s = acquisition::Storage::Open(path);
  ASSERT_TRUE(s.ok());
  JobStore store(**s);
  std::vector<std::int64_t> ids;
  for (const char* name : {"a", "b", "c"}) {
    JobRecord j;
    j.name = name;
    j.plan_text = std::string("plan ") + name;
    j.state = JobState::kQueued;
    j.options_json = std::string(R"({"fit":[")") + name + R"("]})";
    auto id = store.Insert(j);
    ASSERT_TRUE(id.ok()) << id.error().message;
    ids.push_back(*id);
  }
  auto names = [&](int finished) {
    std::string out;
    auto jobs = store.Jobs(finished);
    EXPECT_TRUE(jobs.ok());
    for (const JobRecord& j : *jobs) out += j.name + ":" + ToString(j.state) + " ";
    return out;
  };
  EXPECT_EQ(names(10), "a:queued b:queued c:queued ");
  ASSERT_TRUE(store.SetQueueOrder({ids[2], ids[0], ids[1]}).ok());
  EXPECT_EQ(names(10), "c:queued a:queued b:queued ");
  const std::int64_t run = NewRun(**s, 2);
  JobRecord done;
  done.id = ids[0];
  done.state = JobState::kDone;
  done.run = run;
  done.message = "fine";
  done.options_json = R"({"fit":["ggx"]})";
  ASSERT_TRUE(store.Update(done).ok());
  EXPECT_EQ(names(10), "c:queued b:queued a:done ");  // finished ones after the queue
  EXPECT_EQ(names(0), "c:queued b:queued ");
  auto jobs = store.Jobs(10);
  ASSERT_TRUE(jobs.ok());
  const JobRecord& a = jobs->back();
  EXPECT_EQ(a.plan_text, "plan a");
  EXPECT_EQ(a.run, run);
  EXPECT_EQ(a.message, "fine");
  EXPECT_EQ(a.options_json, R"({"fit":["ggx"]})");
  done.id = 9999;
  const Status missing = store.Update(done);
  ASSERT_FALSE(missing.ok());
  EXPECT_EQ(missing.error().code, ErrorCode::kNotFound);
  // A state that is not a job state cannot be written through the store (JobState), and the
  // schema refuses one written by hand; nothing changes.
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
  EXPECT_NE(sqlite3_exec(
                db, ("UPDATE jobs SET state='sleeping' WHERE id=" + std::to_string(ids[1])).c_str(),
                nullptr, nullptr, nullptr),
            SQLITE_OK);
  sqlite3_close(db);
  EXPECT_EQ(names(0), "c:queued b:queued ");
}

// The daemon's worker stores points while its API threads store jobs, on one connection: each
// call's transaction must run alone (a second BEGIN inside the first fails).
TEST_F(JobStoreTest, ThreadsSharingTheConnectionDoNotShareATransaction) {
  auto s = acquisition::Storage::Open(path);
  ASSERT_TRUE(s.ok());
  JobStore store(**s);
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
    j.state = JobState::kQueued;
    auto id = store.Insert(j);
    if (!id.ok()) {
      ++job_failures;
      continue;
    }
    ids.insert(ids.begin(), *id);
    if (!store.SetQueueOrder(ids).ok()) ++job_failures;
  }
  points.join();
  EXPECT_EQ(point_failures, 0);
  EXPECT_EQ(job_failures, 0);
  auto rows = (*s)->Measurements(run);
  ASSERT_TRUE(rows.ok());
  EXPECT_EQ(static_cast<int>(rows->size()), kPoints);
  auto jobs = store.Jobs(0);
  ASSERT_TRUE(jobs.ok());
  ASSERT_EQ(jobs->size(), static_cast<std::size_t>(kPoints));
  EXPECT_EQ(jobs->front().name, "j" + std::to_string(kPoints - 1));  // the last put first
}

}  // namespace
}  // namespace gonio::daemon
