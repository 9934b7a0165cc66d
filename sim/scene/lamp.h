// The DC-regulated fibre illuminator: nominal output with a slow drift and a small flicker,
// deterministic under a seed. The same Output(t) scales the scene's illumination (the camera) and
// the power that the source monitor reads, so monitor normalisation has something real to correct.
#pragma once

#include <array>
#include <cstdint>

namespace gonio::sim {

struct LampOptions {
  double nominal_w = 1.2e-3;        // power at the monitor's sensor
  double drift_per_hour = 0.01;     // linear, relative
  double wander_amplitude = 0.005;  // slow sinusoidal wander, relative
  double wander_period_s = 1800;
  double flicker_rms = 0.002;  // fast, relative (a few incommensurate tones)
  double warmup_s = 0;         // exponential rise from 90 % over this time constant
};

class Lamp {
 public:
  explicit Lamp(LampOptions options = {}, std::uint64_t seed = 1);
  // Output relative to nominal at simulated time t (s).
  double Relative(double t) const;
  double PowerW(double t) const { return o_.nominal_w * Relative(t); }
  double NominalW() const { return o_.nominal_w; }
  // Mean of Relative over [t0, t1] (an exposure); the midpoint rule with the flicker averaged out
  // for exposures longer than its periods.
  double MeanRelative(double t0, double t1) const;

 private:
  double Slow(double t) const;
  LampOptions o_;
  std::array<double, 3> flicker_hz_{}, flicker_phase_{};
};

}  // namespace gonio::sim
