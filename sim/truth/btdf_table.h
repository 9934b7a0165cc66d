// A transmitted BTDF tabulated over view directions, with its Monte Carlo standard error: what
// the Monte Carlo ground truths produce and what the scene reads (sim/).
#pragma once

#include <cmath>
#include <cstdint>
#include <vector>

#include "optics/vecmath.h"

namespace gonio::sim {

struct BtdfTable {
  // Light from above at theta_i_deg (phi = 0); the medium above has index n_above, below n_below.
  double theta_i_deg = 0, n_above = 1, n_below = 1.5;
  // Bins over the view direction below the surface: theta_o from -z in [0, 90) degrees, phi_o in
  // [0, 360) degrees, uniform.
  int n_theta = 45, n_phi = 24;
  // Per bin: the |cos theta_o|-weighted average of f_t over the bin (so that
  // sum f * CosSolidAngle = transmitted fraction), and its standard error.
  std::vector<double> f, f_se;
  // Fractions of the incident flux transmitted (below) and reflected (above), with standard
  // errors; what Russian roulette or the depth cap dropped is in neither (expected ~0).
  double transmitted = 0, transmitted_se = 0, reflected = 0, reflected_se = 0;
  std::int64_t rays = 0;
  double seconds = 0;

  int Index(int a, int b) const { return a * n_phi + b; }
  double ThetaLo(int a) const { return 90.0 * a / n_theta; }
  double ThetaHi(int a) const { return 90.0 * (a + 1) / n_theta; }
  double PhiLo(int b) const { return 360.0 * b / n_phi; }
  double PhiHi(int b) const { return 360.0 * (b + 1) / n_phi; }
  // integral of |cos theta| d omega over a bin of row a: (sin^2 t1 - sin^2 t0) / 2 * dphi.
  double CosSolidAngle(int a) const {
    const double d = optics::kPi / 180;
    const double s0 = std::sin(ThetaLo(a) * d), s1 = std::sin(ThetaHi(a) * d);
    return 0.5 * (s1 * s1 - s0 * s0) * (2 * optics::kPi / n_phi);
  }
  // The bin holding a view direction below the surface (z < 0), or -1.
  int BinOf(const optics::Vec3<double>& v) const {
    if (!(v.z < 0)) return -1;
    const double theta = std::acos(std::min(1.0, -v.z)) * 180 / optics::kPi;
    double phi = std::atan2(v.y, v.x) * 180 / optics::kPi;
    if (phi < 0) phi += 360;
    const int a = std::min(n_theta - 1, static_cast<int>(theta / 90 * n_theta));
    const int b = std::min(n_phi - 1, static_cast<int>(phi / 360 * n_phi));
    return Index(a, b);
  }
};

// Accumulates weights by batch and turns them into a table with standard errors across batches.
class BtdfAccumulator {
 public:
  BtdfAccumulator(const BtdfTable& shape, int batches);
  // Adds transmitted weight w along v (z < 0) or reflected weight, for batch b.
  void Transmit(int batch, const optics::Vec3<double>& v, double w);
  void Reflect(int batch, double w) { reflected_[batch] += w; }
  // Merges another accumulator's batches (same shape).
  void Merge(const BtdfAccumulator& other);
  // rays_per_batch: rays launched in each batch.
  BtdfTable Finish(std::int64_t rays_per_batch) const;

 private:
  BtdfTable shape_;
  int batches_;
  std::vector<std::vector<double>> bins_;  // [batch][bin]
  std::vector<double> reflected_, transmitted_;
};

}  // namespace gonio::sim
