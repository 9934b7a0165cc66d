#include "sim/scene/lamp.h"

#include <cmath>
#include <numbers>
#include <random>

namespace gonio::sim {

Lamp::Lamp(LampOptions options, std::uint64_t seed) : o_(options) {
  std::mt19937_64 rng(seed ^ 0x4c414d50ull);
  std::uniform_real_distribution<double> u(0, 1);
  for (int k = 0; k < 3; ++k) {
    flicker_hz_[k] = 3.0 * (k + 1) + u(rng);  // a few Hz, incommensurate
    flicker_phase_[k] = 2 * std::numbers::pi * u(rng);
  }
}

double Lamp::Slow(double t) const {
  double r = 1 + o_.drift_per_hour * t / 3600 +
             o_.wander_amplitude * std::sin(2 * std::numbers::pi * t / o_.wander_period_s);
  if (o_.warmup_s > 0) r *= 1 - 0.1 * std::exp(-t / o_.warmup_s);
  return r;
}

double Lamp::Relative(double t) const {
  // Three equal tones of rms a/sqrt(2) each give an rms of flicker_rms in total.
  double f = 0;
  for (int k = 0; k < 3; ++k)
    f += std::sin(2 * std::numbers::pi * flicker_hz_[k] * t + flicker_phase_[k]);
  return Slow(t) * (1 + o_.flicker_rms * std::sqrt(2.0 / 3.0) * f);
}

double Lamp::MeanRelative(double t0, double t1) const {
  if (t1 - t0 < 1.0) {  // short: sample the flicker too (16-point midpoint rule)
    double s = 0;
    for (int k = 0; k < 16; ++k) s += Relative(t0 + (k + 0.5) * (t1 - t0) / 16);
    return s / 16;
  }
  return Slow(0.5 * (t0 + t1));
}

}  // namespace gonio::sim
