// The measurement model the fitter fits: S(l, v) = k f(l, v) |cos theta_l| (REFERENCE.md section
// 1), for the model families of Walter 2007 (Beckmann, GGX, Phong) and Sun 2008.
//
// Each family has one width parameter, in its own unit:
//   Beckmann, GGX: alpha (slope-like, > 0)      Phong: exponent alpha_p (> 0)
//   Sun 2008: smoothness s = tau / sigma (> 0)
// AlphaEquivalent() maps a width to the Beckmann alpha it resembles (Phong: alpha_p = 2 alpha^-2 -
// 2, Walter section 5.2; Sun: alpha = 2 / s, docs/optics.md), so that widths can be compared and
// searched on one scale.
#pragma once

#include <optional>
#include <string>
#include <string_view>

#include "fitting/optics/microfacet.h"
#include "fitting/optics/sun2008.h"

namespace gonio::fitting {

enum class Family { kBeckmann, kGgx, kPhong, kSun2008 };

inline constexpr Family kAllFamilies[] = {Family::kBeckmann, Family::kGgx, Family::kPhong,
                                          Family::kSun2008};

const char* Name(Family f);
// Accepts the names Name() returns ("beckmann", "ggx", "phong", "sun2008"); case-sensitive.
std::optional<Family> ParseFamily(std::string_view name);
// The width parameter's name in reports: "alpha", "exponent" or "s".
const char* WidthName(Family f);

double AlphaEquivalent(Family f, double width);
// Inverse of AlphaEquivalent. For Phong, alpha >= 1 has no exponent >= 0: returns nullopt.
std::optional<double> WidthFromAlphaEquivalent(Family f, double alpha);

struct ModelSpec {
  Family family = Family::kBeckmann;
  // Which Smith G1 Beckmann uses (the others have one form each).
  optics::SmithG1 g1 = optics::SmithG1::kExact;
};

std::string Describe(const ModelSpec& m);

// The transmitted radiance BTDF f(l, v) of the family (microfacet.h conventions: l = light,
// v = view, eta = index below / above), for any scalar T (double or ceres::Jet).
template <typename T>
T ModelBtdf(const ModelSpec& m, const optics::Vec3<T>& l, const optics::Vec3<T>& v, const T& width,
            const T& eta) {
  using namespace optics;
  switch (m.family) {
    case Family::kBeckmann:
      return RoughDielectricBsdf<BeckmannDistribution<T>>(BeckmannDistribution<T>(width, m.g1), eta)
          .Btdf(l, v);
    case Family::kGgx:
      return RoughDielectricBsdf<GgxDistribution<T>>(GgxDistribution<T>(width), eta).Btdf(l, v);
    case Family::kPhong:
      return RoughDielectricBsdf<PhongDistribution<T>>(PhongDistribution<T>(width), eta).Btdf(l, v);
    case Family::kSun2008:
      return Sun2008Btdf(l, v, width, eta);
  }
  return T(0);
}

// S = k f(l, v) |cos theta_l|.
template <typename T>
T MeasurementModel(const ModelSpec& m, const optics::Vec3<T>& l, const optics::Vec3<T>& v,
                   const T& width, const T& k, const T& eta) {
  return k * ModelBtdf(m, l, v, width, eta) * optics::AbsCosTheta(l);
}

}  // namespace gonio::fitting
