#include "sim/stage/motion.h"

#include <algorithm>
#include <cmath>

namespace gonio::sim {

TrapezoidalMove::TrapezoidalMove(double t0, double start, double target, double v, double a,
                                 double d)
    : t0_(t0), start_(start), target_(target), a_(a), d_(d) {
  const double dist = std::abs(target - start);
  dir_ = target >= start ? 1 : -1;
  // Full speed needs v^2/2a + v^2/2d of distance; otherwise the peak is lower (a triangle).
  const double needed = v * v / (2 * a) + v * v / (2 * d);
  v_peak_ = needed <= dist ? v : std::sqrt(2 * dist * a * d / (a + d));
  t_acc_ = v_peak_ / a;
  t_dec_ = v_peak_ / d;
  const double cruise = dist - v_peak_ * v_peak_ / (2 * a) - v_peak_ * v_peak_ / (2 * d);
  t_flat_ = v_peak_ > 0 ? std::max(0.0, cruise) / v_peak_ : 0;
}

double TrapezoidalMove::PositionAt(double t) const {
  const double s = std::max(0.0, t - t0_);
  double x;
  if (s < t_acc_) {
    x = 0.5 * a_ * s * s;
  } else if (s < t_acc_ + t_flat_) {
    x = 0.5 * a_ * t_acc_ * t_acc_ + v_peak_ * (s - t_acc_);
  } else if (s < t_acc_ + t_flat_ + t_dec_) {
    const double r = t_acc_ + t_flat_ + t_dec_ - s;  // time left
    x = std::abs(target_ - start_) - 0.5 * d_ * r * r;
  } else {
    return target_;
  }
  return start_ + dir_ * x;
}

double TrapezoidalMove::VelocityAt(double t) const {
  const double s = t - t0_;
  if (s < 0 || s >= t_acc_ + t_flat_ + t_dec_) return 0;
  if (s < t_acc_) return dir_ * a_ * s;
  if (s < t_acc_ + t_flat_) return dir_ * v_peak_;
  return dir_ * d_ * (t_acc_ + t_flat_ + t_dec_ - s);
}

TrapezoidalMove TrapezoidalMove::StoppedAt(double t) const {
  const double x = PositionAt(t), v = std::abs(VelocityAt(t));
  if (v <= 0) return TrapezoidalMove(t, x, x, 1, a_, d_);
  // Decelerating from v at d covers v^2 / 2d: a move that starts at full speed is equivalent to
  // a triangle whose acceleration phase ended exactly now; build it as a pure deceleration.
  TrapezoidalMove m;
  m.t0_ = t;
  m.start_ = x;
  m.dir_ = dir_;
  m.target_ = x + dir_ * v * v / (2 * d_);
  m.v_peak_ = v;
  m.a_ = a_;
  m.d_ = d_;
  m.t_acc_ = 0;
  m.t_flat_ = 0;
  m.t_dec_ = v / d_;
  return m;
}

}  // namespace gonio::sim
