// Test helpers: integrals over directions by Gauss-Legendre quadrature in (theta, phi).
// Independent of the samplers under test, so pdfs and BSDFs can be checked against them.
#pragma once

#include <boost/math/quadrature/gauss.hpp>
#include <cmath>

#include "optics/vecmath.h"

namespace gonio::optics::testing {

// Order-6 Gauss-Legendre tensor rule over one (theta, phi) cell.
template <typename F>
double GaussCell(const F& f, double t0, double t1, double p0, double p1) {
  using boost::math::quadrature::gauss;
  return gauss<double, 6>::integrate(
      [&](double theta) {
        const double st = std::sin(theta), ct = std::cos(theta);
        return st * gauss<double, 6>::integrate(
                        [&](double phi) { return f(SphericalDirection(st, ct, phi)); }, p0, p1);
      },
      t0, t1);
}

// Integral of f(w) dw over the cell theta in [t0, t1], phi in [p0, p1] (radians; theta from +z
// over the whole sphere, so the cell may lie below the horizon). Adaptive: a cell whose four
// quarters disagree with it is split, because the densities under test have jumps (the horizon;
// for GGX's visible normals, the circle where the half vector h_t crosses the horizon) that a
// fixed rule does not converge across.
template <typename F>
double IntegrateCellAdaptive(const F& f, double t0, double t1, double p0, double p1, double whole,
                             int depth) {
  const double tm = 0.5 * (t0 + t1), pm = 0.5 * (p0 + p1);
  const double q[4] = {GaussCell(f, t0, tm, p0, pm), GaussCell(f, t0, tm, pm, p1),
                       GaussCell(f, tm, t1, p0, pm), GaussCell(f, tm, t1, pm, p1)};
  const double sum = q[0] + q[1] + q[2] + q[3];
  if (depth == 0 || std::abs(sum - whole) <= 1e-11) return sum;
  return IntegrateCellAdaptive(f, t0, tm, p0, pm, q[0], depth - 1) +
         IntegrateCellAdaptive(f, t0, tm, pm, p1, q[1], depth - 1) +
         IntegrateCellAdaptive(f, tm, t1, p0, pm, q[2], depth - 1) +
         IntegrateCellAdaptive(f, tm, t1, pm, p1, q[3], depth - 1);
}

template <typename F>
double IntegrateCell(const F& f, double t0, double t1, double p0, double p1) {
  return IntegrateCellAdaptive(f, t0, t1, p0, p1, GaussCell(f, t0, t1, p0, p1), 8);
}

// Integral of f(w) over [theta0, theta1] x [0, 2 pi), split into n_theta x n_phi cells.
template <typename F>
double IntegrateSphere(const F& f, double theta0, double theta1, int n_theta, int n_phi) {
  double sum = 0;
  for (int a = 0; a < n_theta; ++a) {
    const double t0 = theta0 + (theta1 - theta0) * a / n_theta;
    const double t1 = theta0 + (theta1 - theta0) * (a + 1) / n_theta;
    for (int b = 0; b < n_phi; ++b)
      sum += IntegrateCell(f, t0, t1, 2 * kPi * b / n_phi, 2 * kPi * (b + 1) / n_phi);
  }
  return sum;
}

// Isotropic integral 2 pi * integral_0^{pi/2} g(theta) sin(theta) dtheta, split in n pieces
// graded towards theta = 0 (where narrow lobes live): piece k spans [(k/n)^2, ((k+1)/n)^2] pi/2.
template <typename G>
double IntegrateHemisphereIsotropic(const G& g, int n = 400) {
  using boost::math::quadrature::gauss;
  double sum = 0;
  for (int k = 0; k < n; ++k) {
    const double a = 0.5 * kPi * (double(k) / n) * (double(k) / n);
    const double b = 0.5 * kPi * (double(k + 1) / n) * (double(k + 1) / n);
    sum += gauss<double, 10>::integrate([&](double t) { return g(t) * std::sin(t); }, a, b);
  }
  return 2 * kPi * sum;
}

}  // namespace gonio::optics::testing
