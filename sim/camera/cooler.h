// The CCD's thermoelectric cooler: a first-order approach to the setpoint, limited by the power
// that can hold the sensor at most max_delta_c below ambient. DeviceTemperature reads it; dark
// current follows it (sensor.h). A failed cooler (fault plan) lets the sensor drift to ambient.
#pragma once

namespace gonio::sim {

struct CoolerOptions {
  double ambient_c = 20;
  double max_delta_c = 45;      // deepest cooling below ambient at full power
  double time_constant_s = 60;  // of the approach to the target
};

class Cooler {
 public:
  explicit Cooler(CoolerOptions options = {}, double t0 = 0)
      : o_(options), t0_(t0), T0_(options.ambient_c), target_(options.ambient_c) {}

  // All take the simulated time t (s, non-decreasing) at which the change happens.
  void SetEnabled(bool on, double t) { Rebase(t), enabled_ = on, Retarget(); }
  void SetSetpoint(double celsius, double t) { Rebase(t), setpoint_ = celsius, Retarget(); }
  void SetFailed(bool failed, double t) { Rebase(t), failed_ = failed, Retarget(); }

  double Temperature(double t) const;
  // Fraction of full power (0..100 %) the controller drives at time t.
  double PowerPercent(double t) const;

 private:
  void Rebase(double t) { T0_ = Temperature(t), t0_ = t; }
  void Retarget();

  CoolerOptions o_;
  double t0_, T0_, target_;
  double setpoint_ = -20;
  bool enabled_ = false, failed_ = false;
};

}  // namespace gonio::sim
