// A trapezoidal motion profile (or a triangle, when the move is too short to reach full speed),
// in steps and seconds: what a stepper/servo controller executes for one positioning move.
#pragma once

namespace gonio::sim {

class TrapezoidalMove {
 public:
  TrapezoidalMove() = default;
  // From `start` to `target` (steps) beginning at time t0 (s), peak speed v (steps/s, > 0),
  // acceleration a and deceleration d (steps/s^2, > 0).
  TrapezoidalMove(double t0, double start, double target, double v, double a, double d);

  double PositionAt(double t) const;
  double VelocityAt(double t) const;  // signed, steps/s
  double EndTime() const { return t0_ + t_acc_ + t_flat_ + t_dec_; }
  double target() const { return target_; }
  // A controlled stop from time t: decelerate at d to rest (a new profile from where it is).
  TrapezoidalMove StoppedAt(double t) const;

 private:
  double t0_ = 0, start_ = 0, target_ = 0, dir_ = 1;
  double v_peak_ = 0, a_ = 1, d_ = 1;
  double t_acc_ = 0, t_flat_ = 0, t_dec_ = 0;
};

}  // namespace gonio::sim
