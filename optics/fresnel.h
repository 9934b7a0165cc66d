// Fresnel reflectance of a smooth dielectric interface for unpolarised light.
#pragma once

#include "optics/vecmath.h"

namespace gonio::optics {

// Exact unpolarised dielectric Fresnel reflectance, Walter et al. 2007 eq. 22 (after [CT82]).
//
//   cosTheta_i: |cos| of the angle between the incident direction and the facet normal m, in
//               [0, 1]. (A negative value is taken by magnitude.)
//   eta:        eta_t / eta_i, the index of the medium light enters relative to the one it leaves.
//               eta < 1 means leaving the denser medium, where total internal reflection occurs.
// Returns F in [0, 1]; 1 under total internal reflection (g imaginary) and at grazing incidence.
// F is continuous at the critical angle, so F = 1 there keeps the derivative bounded for Jets.
template <typename T>
T FresnelDielectric(const T& cosTheta_i, const T& eta) {
  using std::abs;
  using std::sqrt;
  const T c = abs(cosTheta_i);
  const T g2 = eta * eta - T(1) + c * c;
  if (g2 <= T(0)) return T(1);  // total internal reflection
  const T g = sqrt(g2);
  const T a = (g - c) / (g + c);
  const T b = (c * (g + c) - T(1)) / (c * (g - c) + T(1));
  return T(0.5) * a * a * (T(1) + b * b);
}

}  // namespace gonio::optics
