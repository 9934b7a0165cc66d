// Simulated time (docs/design.md): devices read one injectable clock, so tests run fast and
// deterministic (ManualClock), and the demo runs in real time or faster (ScaledClock), with all
// devices consistent with each other either way.
#pragma once

#include <atomic>
#include <chrono>

namespace gonio::sim {

class Clock {
 public:
  virtual ~Clock() = default;
  // Seconds of simulated time since the clock's start; never decreases.
  virtual double Now() const = 0;
};

// Advanced only by the test.
class ManualClock final : public Clock {
 public:
  double Now() const override { return now_.load(); }
  // Precondition: seconds >= 0.
  void Advance(double seconds) { now_.store(now_.load() + seconds); }

 private:
  std::atomic<double> now_{0.0};
};

// Real time multiplied by `speed` (1 for the demo and operators, larger for soak runs).
class ScaledClock final : public Clock {
 public:
  explicit ScaledClock(double speed = 1.0)
      : speed_(speed), start_(std::chrono::steady_clock::now()) {}
  double Now() const override {
    return speed_ *
           std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  }

 private:
  double speed_;
  std::chrono::steady_clock::time_point start_;
};

}  // namespace gonio::sim
