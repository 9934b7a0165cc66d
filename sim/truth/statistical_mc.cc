// Statistical Monte Carlo after Sun 2008 section 4, in the random-walk form of Heitz et al. 2016.
#include <chrono>
#include <cmath>
#include <random>
#include <thread>

#include "optics/distribution.h"
#include "optics/fresnel.h"
#include "sim/truth/monte_carlo.h"
#include "sim/truth/parallel.h"
#include "sim/truth/scattering.h"

namespace gonio::sim {
namespace {

using optics::Vec3;

class Walker {
 public:
  Walker(double alpha, double n_above, double n_below, const MonteCarloOptions& o,
         BtdfAccumulator* acc, int batch, std::mt19937_64* rng)
      : dist_(alpha),
        n_above_(n_above),
        n_below_(n_below),
        o_(o),
        acc_(acc),
        batch_(batch),
        rng_(rng) {}

  // A ray travelling along wr from a point whose height has C1 = c (in the frame of the surface
  // seen from above); outside: in the medium above.
  void Walk(Vec3<double> wr, double c, bool outside, double w, int depth) {
    for (;; ++depth) {
      if (depth >= o_.max_depth) return;  // dropped: counted in neither R nor T
      // Next intersection. Inside, the surface is seen from below: flip direction and height.
      bool hit;
      if (outside) {
        hit = NextHit(wr, &c);
      } else {
        double c_in = 1 - c;
        hit = NextHit(-wr, &c_in);
        c = 1 - c_in;
      }
      if (!hit) {
        if (outside)
          acc_->Reflect(batch_, w);
        else
          acc_->Transmit(batch_, wr, w);
        return;
      }
      // The facet the ray meets: a visible normal for the direction it came from.
      const Vec3<double> wi = -wr;
      const optics::Point2 u{U(), U()};
      // Unflipped: the ray may arrive from below the mean plane (wi.z < 0 outside).
      const Vec3<double> wm =
          outside ? dist_.SampleVisibleUnflipped(wi, u) : -dist_.SampleVisibleUnflipped(-wi, u);
      const double cos_i = Dot(wi, wm);
      if (!(cos_i > 0)) return;  // degenerate facet (probability zero)
      const double eta = outside ? n_below_ / n_above_ : n_above_ / n_below_;  // entered / left
      const double F = optics::FresnelDielectric(cos_i, eta);
      double w_r = w * F, w_t = w * (1 - F);
      const bool go_t = F < 1 && SurviveBranch(&w_t, o_.split_threshold, *rng_);
      const bool go_r = SurviveBranch(&w_r, o_.split_threshold, *rng_);
      if (go_t) {
        Walk(Refract(wi, wm, cos_i, eta), c, !outside, w_t, depth + 1);
      }
      if (!go_r) return;
      wr = wm * (2 * cos_i) - wi;  // reflection about the facet
      w = w_r;
    }
  }

 private:
  double U() { return std::uniform_real_distribution<double>(0, 1)(*rng_); }

  // Smith's uncorrelated height sampling (Heitz et al. 2016, sampleHeight) in C1-space:
  // c = C1(h) of the current point; returns false if the ray leaves the surface, else sets c to
  // the next hit's C1. Lambda(w) for a downward w is -1 - Lambda(-w).
  bool NextHit(const Vec3<double>& wr, double* c) {
    const double u = U();
    if (wr.z > 0.9999999) return false;
    if (wr.z < -0.9999999) {
      *c *= u;
      return true;
    }
    if (std::abs(wr.z) < 1e-9) return true;
    const double lambda = wr.z > 0 ? dist_.Lambda(wr) : -1 - dist_.Lambda(-wr);
    const double escape = wr.z > 0 ? std::pow(*c, lambda) : 0;
    if (u > 1 - escape) return false;
    *c /= std::pow(1 - u, 1 / lambda);
    return *c < 1;  // rounding at the top: a hit above every height is an escape
  }

  optics::BeckmannDistribution<double> dist_;
  double n_above_, n_below_;
  const MonteCarloOptions& o_;
  BtdfAccumulator* acc_;
  int batch_;
  std::mt19937_64* rng_;
};

}  // namespace

BtdfTable StatisticalMonteCarlo(double s, double n_above, double n_below, double theta_i_deg,
                                const MonteCarloOptions& o) {
  const auto t0 = std::chrono::steady_clock::now();
  const BtdfTable shape = TableShape(n_above, n_below, theta_i_deg, o);
  const std::int64_t per_batch = o.rays / o.batches;
  const double ti = theta_i_deg * optics::kPi / 180;
  const Vec3<double> light{std::sin(ti), 0, std::cos(ti)};
  BtdfTable t = RunBatches(shape, o, [&](int batch, BtdfAccumulator* acc) {
    std::mt19937_64 rng(o.seed * 1000003 + batch);
    Walker walker(PredictedAlpha(s), n_above, n_below, o, acc, batch, &rng);
    for (std::int64_t r = 0; r < per_batch; ++r) walker.Walk(-light, 1.0, true, 1.0, 0);
  });
  t.rays = per_batch * o.batches;
  t.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return t;
}

}  // namespace gonio::sim
