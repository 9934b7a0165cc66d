// What both Monte Carlo ground truths do at a hit: refract by Snell's law and decide whether a
// Fresnel-weighted branch goes on (splitting, with Russian roulette for faint branches).
#pragma once

#include <cmath>
#include <random>

#include "optics/vecmath.h"

namespace gonio::sim {

// Refraction of the direction wi (pointing away from the surface, on the side the facet normal
// wm faces, cos_i = wi.wm > 0) into the medium of relative index eta (entered / left).
// Precondition: no total internal reflection (the caller's Fresnel factor is < 1).
inline optics::Vec3<double> Refract(const optics::Vec3<double>& wi, const optics::Vec3<double>& wm,
                                    double cos_i, double eta) {
  const double k = 1 - (1 - cos_i * cos_i) / (eta * eta);
  return Normalize(-wi / eta + wm * (cos_i / eta - std::sqrt(k)));
}

// Russian roulette below the split threshold: a branch of weight w < threshold survives with
// probability w / threshold at weight threshold, which keeps the expectation (Sun's plain cutoff
// would lose energy). Returns whether the branch goes on; *w is updated.
inline bool SurviveBranch(double* w, double threshold, std::mt19937_64& rng) {
  if (*w <= 0) return false;
  if (*w >= threshold) return true;
  if (std::uniform_real_distribution<double>(0, 1)(rng) * threshold < *w) {
    *w = threshold;
    return true;
  }
  return false;
}

}  // namespace gonio::sim
