#include "sim/camera/cooler.h"

#include <algorithm>
#include <cmath>

namespace gonio::sim {

void Cooler::Retarget() {
  target_ =
      (enabled_ && !failed_) ? std::max(setpoint_, o_.ambient_c - o_.max_delta_c) : o_.ambient_c;
}

double Cooler::Temperature(double t) const {
  return target_ + (T0_ - target_) * std::exp(-std::max(0.0, t - t0_) / o_.time_constant_s);
}

double Cooler::PowerPercent(double t) const {
  if (!enabled_ || failed_) return 0;
  // Holding a temperature costs power in proportion to its distance below ambient; pulling down
  // toward a colder target saturates the drive.
  const double T = Temperature(t);
  if (T > target_ + 0.5) return 100;
  return std::clamp(100 * (o_.ambient_c - T) / o_.max_delta_c, 0.0, 100.0);
}

}  // namespace gonio::sim
