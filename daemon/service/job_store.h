// The daemon's job queue as stored: the `jobs` table in the run database's file (schema
// migration 2, acquisition/storage.cc), so that the queue in its order, and each job's schedule
// options, survive a restart. It shares Storage's connection and lock, so a job written by an API
// thread never lands inside the worker's point transaction.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "acquisition/storage.h"
#include "common/result.h"

namespace gonio::daemon {

// A job's state, stored and sent as text ("queued", ...).
enum class JobState { kQueued, kRunning, kPaused, kDone, kAborted, kFailed, kCancelled };
const char* ToString(JobState s);
std::optional<JobState> ParseJobState(std::string_view text);
// Queued, running or paused: the job still has work to do.
inline bool Unfinished(JobState s) {
  return s == JobState::kQueued || s == JobState::kRunning || s == JobState::kPaused;
}

struct JobRecord {
  std::int64_t id = 0;
  std::string name, plan_text;
  JobState state = JobState::kQueued;
  std::optional<std::int64_t> run;
  std::string message;
  std::string options_json = "{}";  // the controller's schedule options, opaque here
  std::int64_t position = 0;        // order among queued jobs, ascending
};

class JobStore {
 public:
  // The storage must outlive the store.
  explicit JobStore(acquisition::Storage& db) : db_(db) {}

  // Places the job after every other (its position) and returns its id.
  Result<std::int64_t> Insert(const JobRecord& j);
  // Stores state, run, message and options. kNotFound for an unknown id.
  Status Update(const JobRecord& j);
  // Renumbers the given jobs' positions in that order, in one transaction.
  Status SetQueueOrder(const std::vector<std::int64_t>& ids);
  // Unfinished jobs (queued, running, paused) in queue order, then the newest `finished_limit`
  // finished ones, oldest first. A row whose state is not a job state is an error (kIo) naming it.
  Result<std::vector<JobRecord>> Jobs(int finished_limit);

 private:
  acquisition::Storage& db_;
};

}  // namespace gonio::daemon
