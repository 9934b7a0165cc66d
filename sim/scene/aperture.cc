#include "sim/scene/aperture.h"

#include <cmath>
#include <vector>

namespace gonio::sim {
namespace {

using optics::Vec3;

double HalfAngle(double sr) { return std::acos(1 - sr / (2 * optics::kPi)); }

// Directions within a cone of half-angle `half` around w, each representing an equal share of
// the cone's solid angle: about n points on rings of equal solid angle, each ring's points evenly
// spaced in azimuth (at least 5, the rings staggered). Even spacing puts the points' centroid on
// the axis and makes their second moments isotropic, so the rule's error is of fourth order in
// the cone's size. A Fibonacci spiral of 6 or 10 points, used before, has its centroid off the
// axis: it shifted every averaged lobe by about 0.01 deg, a 1 % left-right tilt of ground glass's
// flanks that no model of the bench has (docs/measurement.md).
std::vector<Vec3<double>> ConePoints(const Vec3<double>& w, double half, int n) {
  // An orthonormal frame around w.
  const Vec3<double> a = std::abs(w.x) < 0.9 ? Vec3<double>{1, 0, 0} : Vec3<double>{0, 1, 0};
  const Vec3<double> t1 = optics::Normalize(optics::Cross(w, a)), t2 = optics::Cross(w, t1);
  const double cos_max = std::cos(half);
  const int rings = std::max(1, static_cast<int>(std::lround(std::sqrt(n / 5.0))));
  const int per_ring = std::max(5, n / rings);
  std::vector<Vec3<double>> out;
  for (int i = 0; i < rings; ++i) {
    const double cos_t = 1 - (1 - cos_max) * (i + 0.5) / rings;  // the ring's middle solid angle
    const double sin_t = std::sqrt(std::max(0.0, 1 - cos_t * cos_t));
    for (int j = 0; j < per_ring; ++j) {
      const double phi = 2 * optics::kPi * (j + 0.5 * (i % 2)) / per_ring;
      out.push_back(w * cos_t + t1 * (sin_t * std::cos(phi)) + t2 * (sin_t * std::sin(phi)));
    }
  }
  return out;
}

}  // namespace

double Apertures::SourceHalfAngle() const { return HalfAngle(source_sr); }
double Apertures::ReceiverHalfAngle() const { return HalfAngle(receiver_sr); }

double ApertureAveragedBtdfCos(const GroundTruth& truth, const Vec3<double>& l,
                               const Vec3<double>& v, const Apertures& a, int n_points) {
  const auto ls = ConePoints(l, a.SourceHalfAngle(), n_points);
  const auto vs = ConePoints(v, a.ReceiverHalfAngle(), n_points);
  double sum = 0;
  for (const auto& li : ls)
    for (const auto& vi : vs) sum += truth.BtdfCos(li, vi);
  return sum / (double(ls.size()) * double(vs.size()));
}

ApertureDecision ApertureMatters(const GroundTruth& truth, const Vec3<double>& l,
                                 const Vec3<double>& v, const Apertures& a, double tolerance) {
  ApertureDecision d;
  const double point = truth.BtdfCos(l, v);
  const double averaged = ApertureAveragedBtdfCos(truth, l, v, a);
  d.relative_change = point > 0 ? std::abs(averaged - point) / point : (averaged > 0 ? 1.0 : 0.0);
  d.matters = d.relative_change > tolerance;
  return d;
}

}  // namespace gonio::sim
