// Explicit Gaussian rough surfaces, ray traced exactly (Sun 2008's future work).
#include <array>
#include <chrono>
#include <cmath>
#include <limits>
#include <opencv2/core.hpp>
#include <optional>
#include <random>

#include "optics/fresnel.h"
#include "sim/truth/monte_carlo.h"
#include "sim/truth/parallel.h"
#include "sim/truth/scattering.h"

namespace gonio::sim {
namespace {

using optics::Vec3;

// A periodic height field on an n x n grid of spacing dx, as a triangle mesh (each cell split
// along its (i+1, j)-(i, j+1) diagonal).
class HeightField {
 public:
  // Gaussian heights of RMS sigma with Gaussian correlation exp(-r^2/tau^2): white noise filtered
  // by the square root of the spectrum, exp(-k^2 tau^2 / 8). Scaled by the ensemble variance
  // (1/N^2) sum G_k^2, not by the patch's own RMS: a finite patch lacks some low frequencies, and
  // renormalising to its sample RMS would inflate the slopes (by 3-8 % at 25 tau).
  static HeightField Gaussian(int n, double dx, double sigma, double tau, std::uint64_t seed) {
    cv::Mat noise(n, n, CV_64F);
    cv::RNG rng(seed);
    rng.fill(noise, cv::RNG::NORMAL, 0.0, 1.0);
    cv::Mat spec;
    cv::dft(noise, spec, cv::DFT_COMPLEX_OUTPUT);
    const double dk = 2 * optics::kPi / (n * dx);
    double sum_g2 = 0;
    for (int a = 0; a < n; ++a)
      for (int b = 0; b < n; ++b) {
        const double kx = dk * (a <= n / 2 ? a : a - n), ky = dk * (b <= n / 2 ? b : b - n);
        const double g = std::exp(-(kx * kx + ky * ky) * tau * tau / 8);
        spec.at<cv::Vec2d>(a, b) *= g;
        sum_g2 += g * g;
      }
    cv::Mat h;
    cv::idft(spec, h, cv::DFT_REAL_OUTPUT | cv::DFT_SCALE);
    const double scale = sigma / std::sqrt(sum_g2 / (double(n) * n));
    const double mean = cv::mean(h)[0];
    HeightField f;
    f.n_ = n;
    f.dx_ = dx;
    f.h_.resize(static_cast<std::size_t>(n) * n);
    f.zmin_ = std::numeric_limits<double>::infinity();
    f.zmax_ = -f.zmin_;
    for (int a = 0; a < n; ++a)
      for (int b = 0; b < n; ++b) {
        const double z = (h.at<double>(a, b) - mean) * scale;
        f.h_[static_cast<std::size_t>(a) * n + b] = z;
        f.zmin_ = std::min(f.zmin_, z);
        f.zmax_ = std::max(f.zmax_, z);
      }
    return f;
  }

  double size() const { return n_ * dx_; }
  double zmin() const { return zmin_; }
  double zmax() const { return zmax_; }
  double H(long i, long j) const {
    const long n = n_;
    return h_[static_cast<std::size_t>(((i % n) + n) % n) * n_ +
              static_cast<std::size_t>(((j % n) + n) % n)];
  }

  struct Hit {
    double t;
    Vec3<double> normal;  // unit, upward (z > 0)
  };

  // Nearest hit of o + t d, t > 0, or nullopt when the ray leaves the slab [zmin, zmax] (or
  // travels max_cells cells without a hit: a ray parallel to the mean plane).
  std::optional<Hit> Intersect(const Vec3<double>& o, const Vec3<double>& d) const {
    const double inf = std::numeric_limits<double>::infinity();
    double x = o.x / dx_, y = o.y / dx_;
    long i = static_cast<long>(std::floor(x)), j = static_cast<long>(std::floor(y));
    const int si = d.x > 0 ? 1 : -1, sj = d.y > 0 ? 1 : -1;
    double t_max_x = d.x != 0 ? ((i + (d.x > 0)) - x) * dx_ / d.x : inf;
    double t_max_y = d.y != 0 ? ((j + (d.y > 0)) - y) * dx_ / d.y : inf;
    const double t_dx = d.x != 0 ? dx_ / std::abs(d.x) : inf;
    const double t_dy = d.y != 0 ? dx_ / std::abs(d.y) : inf;
    double t_enter = 0;
    const long max_cells = 64L * n_;
    for (long step = 0; step < max_cells; ++step) {
      const double t_exit = std::min(t_max_x, t_max_y);
      const double z0 = o.z + d.z * t_enter;
      const double z1 = o.z + d.z * std::min(t_exit, 1e300);
      const double h00 = H(i, j), h10 = H(i + 1, j), h01 = H(i, j + 1), h11 = H(i + 1, j + 1);
      const double cmin = std::min(std::min(h00, h10), std::min(h01, h11));
      const double cmax = std::max(std::max(h00, h10), std::max(h01, h11));
      if (std::max(z0, z1) >= cmin && std::min(z0, z1) <= cmax) {
        const Vec3<double> p00{i * dx_, j * dx_, h00}, p10{(i + 1) * dx_, j * dx_, h10},
            p01{i * dx_, (j + 1) * dx_, h01}, p11{(i + 1) * dx_, (j + 1) * dx_, h11};
        std::optional<Hit> best;
        for (const auto& tri : {std::array{p00, p10, p01}, std::array{p11, p01, p10}}) {
          auto t = IntersectTriangle(o, d, tri[0], tri[1], tri[2]);
          if (t && *t > 0 && (!best || *t < best->t)) {
            Vec3<double> nrm = Normalize(Cross(tri[1] - tri[0], tri[2] - tri[0]));
            if (nrm.z < 0) nrm = -nrm;
            best = Hit{*t, nrm};
          }
        }
        if (best) return best;
      }
      if ((d.z > 0 && z1 > zmax_) || (d.z < 0 && z1 < zmin_)) return std::nullopt;
      if (t_max_x < t_max_y) {
        i += si;
        t_enter = t_max_x;
        t_max_x += t_dx;
      } else {
        j += sj;
        t_enter = t_max_y;
        t_max_y += t_dy;
      }
    }
    return std::nullopt;
  }

 private:
  // Moller-Trumbore; edges are closed (a tiny negative tolerance) so no ray slips between the
  // two triangles of a cell or between cells.
  static std::optional<double> IntersectTriangle(const Vec3<double>& o, const Vec3<double>& d,
                                                 const Vec3<double>& v0, const Vec3<double>& v1,
                                                 const Vec3<double>& v2) {
    const Vec3<double> e1 = v1 - v0, e2 = v2 - v0, p = Cross(d, e2);
    const double det = Dot(e1, p);
    if (std::abs(det) < 1e-300) return std::nullopt;
    const double inv = 1 / det;
    const Vec3<double> tv = o - v0;
    const double u = Dot(tv, p) * inv;
    if (u < -1e-12 || u > 1 + 1e-12) return std::nullopt;
    const Vec3<double> q = Cross(tv, e1);
    const double v = Dot(d, q) * inv;
    if (v < -1e-12 || u + v > 1 + 1e-12) return std::nullopt;
    return Dot(e2, q) * inv;
  }

  int n_ = 0;
  double dx_ = 1;
  std::vector<double> h_;
  double zmin_ = 0, zmax_ = 0;
};

class Tracer {
 public:
  Tracer(const HeightField& f, double n_above, double n_below, const MonteCarloOptions& o,
         BtdfAccumulator* acc, int batch, std::mt19937_64* rng)
      : f_(f), n_above_(n_above), n_below_(n_below), o_(o), acc_(acc), batch_(batch), rng_(rng) {}

  void Trace(Vec3<double> p, Vec3<double> d, bool above, double w, int depth) {
    const double eps = 1e-9 * f_.size();
    for (;; ++depth) {
      if (depth >= o_.max_depth) return;  // dropped
      const auto hit = f_.Intersect(p, d);
      if (!hit) {
        // Leaving the slab: upward from the medium above is reflection, downward from below is
        // transmission. Anything else slipped through the mesh (rounding) and is dropped.
        if (above && d.z > 0) acc_->Reflect(batch_, w);
        if (!above && d.z < 0) acc_->Transmit(batch_, d, w);
        return;
      }
      const Vec3<double> x = p + d * hit->t;
      above = Dot(d, hit->normal) < 0;  // the side it arrives from (geometry decides)
      const Vec3<double> facing = above ? hit->normal : -hit->normal;  // toward the ray's side
      const double cos_i = -Dot(d, facing);
      const double eta = above ? n_below_ / n_above_ : n_above_ / n_below_;
      const double F = optics::FresnelDielectric(cos_i, eta);
      double w_r = w * F, w_t = w * (1 - F);
      const bool go_t = F < 1 && SurviveBranch(&w_t, o_.split_threshold, *rng_);
      const bool go_r = SurviveBranch(&w_r, o_.split_threshold, *rng_);
      if (go_t) {
        Trace(x - facing * eps, Refract(-d, facing, cos_i, eta), !above, w_t, depth + 1);
      }
      if (!go_r) return;
      d = d + facing * (2 * cos_i);
      p = x + facing * eps;
      w = w_r;
    }
  }

 private:
  const HeightField& f_;
  double n_above_, n_below_;
  const MonteCarloOptions& o_;
  BtdfAccumulator* acc_;
  int batch_;
  std::mt19937_64* rng_;
};

}  // namespace

SurfaceStats MeasureSurface(double s, const SurfaceOptions& so, std::uint64_t seed) {
  const double tau = s, dx = tau / so.samples_per_tau;
  const HeightField f = HeightField::Gaussian(so.grid, dx, 1.0, tau, seed * 7919);
  const long n = so.grid, lag = std::lround(so.samples_per_tau);
  double h2 = 0, sx2 = 0, sy2 = 0, c = 0;
  for (long i = 0; i < n; ++i)
    for (long j = 0; j < n; ++j) {
      const double h = f.H(i, j);
      h2 += h * h;
      sx2 += std::pow((f.H(i + 1, j) - h) / dx, 2);
      sy2 += std::pow((f.H(i, j + 1) - h) / dx, 2);
      c += h * f.H(i + lag, j);
    }
  const double m = static_cast<double>(n * n);
  SurfaceStats st;
  st.rms_height = std::sqrt(h2 / m);
  st.rms_slope_x = std::sqrt(sx2 / m);
  st.rms_slope_y = std::sqrt(sy2 / m);
  st.correlation_at_tau = (c / m) / (h2 / m);
  return st;
}

double PredictedAlpha(double s) { return 2.0 / s; }

double PredictedAlphaOfMesh(double s, double samples_per_tau) {
  // Per-axis slope variance of the mesh: 2 sigma^2 (1 - C(dx)) / dx^2 = alpha^2 / 2.
  return 2.0 / s * samples_per_tau *
         std::sqrt(-std::expm1(-1 / (samples_per_tau * samples_per_tau)));
}

BtdfTable ExplicitSurfaceMonteCarlo(double s, double n_above, double n_below, double theta_i_deg,
                                    const MonteCarloOptions& o, const SurfaceOptions& so) {
  const auto t0 = std::chrono::steady_clock::now();
  const double sigma = 1, tau = s * sigma, dx = tau / so.samples_per_tau;
  std::vector<HeightField> fields;
  for (int r = 0; r < so.realisations; ++r)
    fields.push_back(HeightField::Gaussian(so.grid, dx, sigma, tau, o.seed * 7919 + r));
  const BtdfTable shape = TableShape(n_above, n_below, theta_i_deg, o);
  const std::int64_t per_batch = o.rays / o.batches;
  const double ti = theta_i_deg * optics::kPi / 180;
  const Vec3<double> down{-std::sin(ti), 0, -std::cos(ti)};  // travel direction of the light
  BtdfTable t = RunBatches(shape, o, [&](int batch, BtdfAccumulator* acc) {
    std::mt19937_64 rng(o.seed * 1000003 + batch);
    const HeightField& f = fields[batch % fields.size()];
    Tracer tracer(f, n_above, n_below, o, acc, batch, &rng);
    std::uniform_real_distribution<double> u(0, f.size());
    for (std::int64_t r = 0; r < per_batch; ++r) {
      // A parallel beam: uniform over the mean plane, starting just above the highest point.
      const Vec3<double> start{u(rng), u(rng), f.zmax() + 1e-6 * f.size()};
      tracer.Trace(start, down, true, 1.0, 0);
    }
  });
  t.rays = per_batch * o.batches;
  t.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return t;
}

}  // namespace gonio::sim
