// The model's residuals as Ceres cost functors: (S_model - value) / sigma for one sample (eta free
// or fixed) or for a batch of samples in one block (eta fixed, no robust loss), and the nuisance
// parameters' Gaussian priors. S_model is eq. R1 of docs/measurement.md over the sample's
// SampleModel, plus the floor, the sample stage's offset through its slope and the dark set's
// nuisance through its sigma_dark. Only solve.cc builds them.
#pragma once

#include <ceres/ceres.h>

#include <cmath>
#include <cstddef>
#include <span>
#include <vector>

#include "fitting/internal/solve.h"
#include "optics/vecmath.h"

namespace gonio::fitting::internal {

using optics::Vec3;

// Whether a residual (double or Jet) and its derivatives are finite.
inline bool ResidualFinite(double x) { return std::isfinite(x); }
template <typename T>
bool ResidualFinite(const T& x) {
  return ceres::isfinite(x);
}

// Residual with eta free: the whole model on Jets, over the sample's pairs.
// `delta` is the sample stage's offset of the sample's group, entering through the slope
// (StageGroups); a sample in no group has the overload without it (no derivative to carry).
// With dark sets (DarkSets) every sample also takes its set's nuisance `z` through `dark`, its
// sigma_dark (a sample in none, or in no group, gets a constant block of 0).
struct Residual {
  ModelSpec model;
  const SampleModel* sm;
  double value, inv_sigma, floor_unit, slope, dark = 0;

  template <typename T>
  bool operator()(const T* log_width, const T* log_k, const T* eta_raw, const T* floor,
                  T* r) const {
    const T zero(0);
    return (*this)(log_width, log_k, eta_raw, floor, &zero, &zero, r);
  }

  template <typename T>
  bool operator()(const T* log_width, const T* log_k, const T* eta_raw, const T* floor,
                  const T* delta, T* r) const {
    const T zero(0);
    return (*this)(log_width, log_k, eta_raw, floor, delta, &zero, r);
  }

  template <typename T>
  bool operator()(const T* log_width, const T* log_k, const T* eta_raw, const T* floor,
                  const T* delta, const T* z, T* r) const {
    using std::exp;
    const T width = exp(log_width[0]), k = exp(log_k[0]), eta = EtaFromRaw(eta_raw[0]);
    T m(0);
    for (std::size_t j = 0; j < sm->g.size(); ++j)
      m += T(sm->w[j]) *
           MeasurementModel(model, Vec3<T>(sm->g[j].l), Vec3<T>(sm->g[j].v), width, k, eta);
    m *= CorrectionAt(*sm, width);
    r[0] = (m + floor[0] * T(floor_unit) + T(slope) * delta[0] + T(dark) * z[0] - T(value)) *
           T(inv_sigma);
    return ResidualFinite(r[0]);
  }
};

// Residual with eta fixed: the geometry is precomputed (model.h, FixedGeometry) and only
// D * shadowing is differentiated.
struct FixedEtaResidual {
  ModelSpec model;
  const SampleModel* sm;
  double value, inv_sigma, floor_unit, slope, dark = 0;

  template <typename T>
  bool operator()(const T* log_width, const T* log_k, const T* floor, T* r) const {
    const T zero(0);
    return (*this)(log_width, log_k, floor, &zero, &zero, r);
  }

  template <typename T>
  bool operator()(const T* log_width, const T* log_k, const T* floor, const T* delta, T* r) const {
    const T zero(0);
    return (*this)(log_width, log_k, floor, delta, &zero, r);
  }

  template <typename T>
  bool operator()(const T* log_width, const T* log_k, const T* floor, const T* delta, const T* z,
                  T* r) const {
    using std::exp;
    const T m = exp(log_k[0]) * FixedEtaValue(model, *sm, exp(log_width[0]));
    r[0] = (m + floor[0] * T(floor_unit) + T(slope) * delta[0] + T(dark) * z[0] - T(value)) *
           T(inv_sigma);
    return ResidualFinite(r[0]);
  }
};

// All samples in one residual block (eta fixed, no robust loss): the same arithmetic without
// Ceres' per-block bookkeeping, which dominates the cost of small fits. A robust loss applies
// per residual block, so with one the samples keep a block each. Point-model samples share the
// light part of the shadowing per incidence. One block per group of the sample stage (the
// group's offset `delta`, through each sample's slope), and one per run of samples in none.
struct BatchFixedEtaResidual {
  ModelSpec model;
  std::span<const SampleModel> sm;
  std::span<const Sample> samples;
  std::span<const double> slope;
  double floor_unit;
  std::vector<Vec3<double>> lights;   // distinct light directions of point-model samples
  std::vector<std::size_t> light_of;  // per sample, index into lights (point model only)

  BatchFixedEtaResidual(const ModelSpec& m, std::span<const SampleModel> models,
                        std::span<const Sample> s, std::span<const double> slopes,
                        double floor_scale)
      : model(m),
        sm(models),
        samples(s),
        slope(slopes),
        floor_unit(floor_scale),
        light_of(s.size()) {
    for (std::size_t i = 0; i < s.size(); ++i) {
      if (sm[i].mode != 0) continue;
      const Vec3<double>& l = sm[i].g[0].l;
      std::size_t k = 0;
      while (k < lights.size() && optics::LengthSquared(lights[k] - l) > 0) ++k;
      if (k == lights.size()) lights.push_back(l);
      light_of[i] = k;
    }
  }

  template <typename T>
  bool operator()(const T* log_width, const T* log_k, const T* floor, T* r) const {
    const T zero(0);
    return (*this)(log_width, log_k, floor, &zero, r);
  }

  template <typename T>
  bool operator()(const T* log_width, const T* log_k, const T* floor, const T* delta, T* r) const {
    using std::exp;
    const T width = exp(log_width[0]), k = exp(log_k[0]);
    std::vector<T> k_shadow_light(lights.size());
    for (std::size_t j = 0; j < lights.size(); ++j)
      k_shadow_light[j] = k * ShadowingLight(model, lights[j], width);
    const T b = floor[0] * T(floor_unit);
    for (std::size_t i = 0; i < sm.size(); ++i) {
      const FixedGeometry& g0 = sm[i].g[0];
      const T m = sm[i].mode != 0 ? k * FixedEtaValue(model, sm[i], width)
                  : g0.factor > 0 ? k_shadow_light[light_of[i]] * T(g0.factor) *
                                        DTimesShadowingView(model, g0, width)
                                  : T(0);
      // Empty slopes: the fit has no stage groups (a run in none has slopes of 0 and delta 0).
      const T shift = slope.empty() ? T(0) : T(slope[i]) * delta[0];
      r[i] = (m + b + shift - T(samples[i].value)) * T(1 / samples[i].sigma);
      // A step to a width where the model overflows is refused quietly (the trust region
      // shrinks), rather than reported by Ceres as a broken cost function.
      if (!ResidualFinite(r[i])) return false;
    }
    return true;
  }
};

// The prior of a group's offset: a pseudo-observation of 0 with sigma prior_deg.
struct PriorResidual {
  double inv_sigma;
  template <typename T>
  bool operator()(const T* delta, T* r) const {
    r[0] = delta[0] * T(inv_sigma);
    return true;
  }
};

// A cost of `r` (owned) with automatic or numeric (central) derivatives: kResiduals residuals
// (ceres::DYNAMIC: n of them) over parameter blocks of the sizes kBlocks.
template <typename F, int kResiduals, int... kBlocks>
ceres::CostFunction* MakeCost(F* r, bool automatic, int n = 1) {
  if constexpr (kResiduals == ceres::DYNAMIC) {
    if (automatic) return new ceres::AutoDiffCostFunction<F, kResiduals, kBlocks...>(r, n);
    return new ceres::NumericDiffCostFunction<F, ceres::CENTRAL, kResiduals, kBlocks...>(
        r, ceres::TAKE_OWNERSHIP, n);
  } else {
    if (automatic) return new ceres::AutoDiffCostFunction<F, kResiduals, kBlocks...>(r);
    return new ceres::NumericDiffCostFunction<F, ceres::CENTRAL, kResiduals, kBlocks...>(r);
  }
}

}  // namespace gonio::fitting::internal
