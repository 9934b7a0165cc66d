// Chi-square goodness-of-fit test of a direction sampler against its density, in the manner of
// pbrt-v4's and Mitsuba 3's BSDF tests: histogram the samples over (theta, phi) cells of the whole
// sphere, integrate the density over each cell, pool cells with low expected counts, and compare.
#pragma once

#include <algorithm>
#include <boost/math/special_functions/gamma.hpp>
#include <cmath>
#include <optional>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "optics/vecmath.h"
#include "tests/fitting/sphere_quadrature.h"

namespace gonio::optics::testing {

struct Chi2Options {
  int n_theta = 48;  // cells over [0, pi]; even, so that the horizon is a cell boundary
  int n_phi = 96;    // cells over [0, 2 pi)
  long n_samples = 1'000'000;
  double min_expected = 5;  // cells expected to hold fewer samples are pooled
  std::uint64_t seed = 7;
};

struct Chi2Result {
  double statistic = 0;
  int dof = 0;
  double p_value = 0;
  long returned = 0;         // samples the sampler returned (it may decline some draws)
  double expected_mass = 0;  // integral of the pdf over the sphere
  std::string failure;       // non-empty when a sample fell where the pdf is zero
  std::string Describe() const {
    std::ostringstream os;
    os << "chi2=" << statistic << " dof=" << dof << " p=" << p_value << " returned=" << returned
       << " pdf mass=" << expected_mass << (failure.empty() ? "" : " ") << failure;
    return os.str();
  }
};

// sample(rng) -> std::optional<Vec3<double>>; pdf(w) -> density over solid angle.
template <typename Sample, typename Pdf>
Chi2Result RunChi2(const Sample& sample, const Pdf& pdf, const Chi2Options& opt = {}) {
  const int nt = opt.n_theta, np = opt.n_phi;
  auto cell_of = [&](const Vec3<double>& w) {
    const double theta = std::acos(std::clamp(w.z, -1.0, 1.0));
    double phi = std::atan2(w.y, w.x);
    if (phi < 0) phi += 2 * kPi;
    const int a = std::min(nt - 1, int(theta / kPi * nt));
    const int b = std::min(np - 1, int(phi / (2 * kPi) * np));
    return a * np + b;
  };

  std::vector<double> observed(nt * np, 0.0), expected(nt * np, 0.0);
  std::mt19937_64 rng(opt.seed);
  Chi2Result r;
  for (long k = 0; k < opt.n_samples; ++k) {
    if (auto w = sample(rng)) {
      observed[cell_of(*w)] += 1;
      ++r.returned;
    }
  }
  for (int a = 0; a < nt; ++a)
    for (int b = 0; b < np; ++b) {
      const double m = IntegrateCell(pdf, kPi * a / nt, kPi * (a + 1) / nt, 2 * kPi * b / np,
                                     2 * kPi * (b + 1) / np);
      expected[a * np + b] = m * double(opt.n_samples);
      r.expected_mass += m;
    }

  // Pool cells, least expected first, until each pooled group expects >= min_expected.
  std::vector<int> order(nt * np);
  for (int k = 0; k < nt * np; ++k) order[k] = k;
  std::sort(order.begin(), order.end(), [&](int x, int y) { return expected[x] < expected[y]; });
  double pool_obs = 0, pool_exp = 0;
  int cells = 0;
  for (int k : order) {
    if (expected[k] == 0 && observed[k] > 0) {
      std::ostringstream os;
      os << observed[k] << " samples in cell (theta " << k / np << ", phi " << k % np
         << ") where the pdf integrates to 0";
      r.failure = os.str();
      return r;
    }
    if (expected[k] < opt.min_expected) {
      pool_obs += observed[k];
      pool_exp += expected[k];
      if (pool_exp >= opt.min_expected) {
        r.statistic += (pool_obs - pool_exp) * (pool_obs - pool_exp) / pool_exp;
        ++cells;
        pool_obs = pool_exp = 0;
      }
      continue;
    }
    r.statistic += (observed[k] - expected[k]) * (observed[k] - expected[k]) / expected[k];
    ++cells;
  }
  if (pool_exp > 0) {
    // What is left over is too small to stand alone: it goes into the statistic anyway (a
    // sampler that puts many samples where the pdf expects almost none must fail).
    r.statistic += (pool_obs - pool_exp) * (pool_obs - pool_exp) / std::max(pool_exp, 1e-3);
    ++cells;
  }
  r.dof = std::max(1, cells - 1);
  r.p_value = boost::math::gamma_q(r.dof / 2.0, r.statistic / 2.0);
  return r;
}

// Significance for one of n tests so that the family keeps 0.01 (Sidak correction).
inline double SidakLevel(int n_tests, double alpha = 0.01) {
  return 1.0 - std::pow(1.0 - alpha, 1.0 / n_tests);
}

}  // namespace gonio::optics::testing
