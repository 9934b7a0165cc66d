// The daemon's event log: every state change, job change and measured point, numbered, kept in
// a bounded ring for clients that follow the live stream (GET /api/v1/events) and catch up after
// a reconnect by the last number they saw.
#pragma once

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <mutex>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

namespace gonio::daemon {

struct Event {
  std::int64_t seq = 0;
  std::string type;     // "state", "job", "progress", "suspend", "fit", "fit_progress", "log"
  nlohmann::json data;  // the event's body
};

class EventLog {
 public:
  explicit EventLog(std::size_t capacity = 2000) : capacity_(capacity) {}

  std::int64_t Publish(const std::string& type, nlohmann::json data) {
    std::lock_guard lock(mu_);
    events_.push_back(Event{++last_, type, std::move(data)});
    if (events_.size() > capacity_) events_.pop_front();
    cv_.notify_all();
    return last_;
  }

  // Events numbered above `after`, waiting up to `timeout` for the first one; empty on timeout
  // or after Close(). Events that fell out of the ring are gone: the first returned may be later
  // than after + 1 (clients see the gap in the numbers).
  std::vector<Event> After(std::int64_t after, std::chrono::milliseconds timeout) {
    std::unique_lock lock(mu_);
    cv_.wait_for(lock, timeout, [&] { return closed_ || last_ > after; });
    std::vector<Event> out;
    for (const Event& e : events_)
      if (e.seq > after) out.push_back(e);
    return out;
  }

  std::int64_t Last() const {
    std::lock_guard lock(mu_);
    return last_;
  }

  // Wakes every waiting reader for good (shutdown).
  void Close() {
    std::lock_guard lock(mu_);
    closed_ = true;
    cv_.notify_all();
  }
  bool closed() const {
    std::lock_guard lock(mu_);
    return closed_;
  }

 private:
  mutable std::mutex mu_;
  std::condition_variable cv_;
  std::deque<Event> events_;
  std::size_t capacity_;
  std::int64_t last_ = 0;
  bool closed_ = false;
};

}  // namespace gonio::daemon
