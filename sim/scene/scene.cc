#include "sim/scene/scene.h"

#include <cmath>
#include <numbers>
#include <utility>

#include <opencv2/core/utility.hpp>

#include "common/bench_angles.h"
#include "optics/fresnel.h"
#include "sim/truth/scattering.h"

namespace gonio::sim {

using V = optics::Vec3<double>;

namespace {

constexpr double kDeg = std::numbers::pi / 180;

// Lab-fixed directions expressed in the sample frame before the azimuth turn.
V InPlane(double polar_rad) { return {std::sin(polar_rad), 0, std::cos(polar_rad)}; }

// The sample turned by phi about its normal sees lab-fixed vectors turned by -phi.
V AzimuthTurn(const V& w, double phi_rad) {
  const double c = std::cos(phi_rad), s = std::sin(phi_rad);
  return {c * w.x + s * w.y, -s * w.x + c * w.y, w.z};
}

struct Frame {
  V source_dir, camera_dir;  // before the azimuth turn
  double phi = 0;
};

// The object-plane point (mm) that a sensor pixel's centre looks at.
std::pair<double, double> ObjectPointMm(const ImageRegion& region, int col, int row) {
  return {(col + 0.5 - region.sensor_width / 2.0) * region.mm_per_pixel,
          (row + 0.5 - region.sensor_height / 2.0) * region.mm_per_pixel};
}

Frame FrameOf(const StageAngles& a) {
  const double s = a.sample_deg * kDeg;
  return {InPlane(s), InPlane(s - a.arm_deg * kDeg), a.azimuth_deg * kDeg};
}

}  // namespace

NominalGeometry Nominal(const BenchGeometry& bench, const StageAngles& angles) {
  const Frame f = FrameOf(angles);
  NominalGeometry g;
  g.l = AzimuthTurn(f.source_dir, f.phi);
  g.v = AzimuthTurn(f.camera_dir, f.phi);
  g.transmission = g.v.z < 0;
  const double separation = std::acos(std::clamp(Dot(f.source_dir, f.camera_dir), -1.0, 1.0));
  g.arm_shadows_source = separation < bench.arm_shadow_half_angle_deg * kDeg;
  g.source_hidden = g.arm_shadows_source || angles.beam_blocked;
  return g;
}

StageAngles StageAnglesFor(double theta_l_deg, double theta_v_deg, double azimuth_deg) {
  const StageTargets t = StageTargetsFor(theta_l_deg, theta_v_deg, azimuth_deg);
  return {t.sample_deg, t.arm_deg, t.azimuth_deg};
}

Scene::Scene(BenchGeometry bench, std::shared_ptr<const GroundTruth> truth, SceneOptions options)
    : bench_(bench), truth_(std::move(truth)), o_(options) {}

std::optional<PixelRay> Scene::Trace(const StageAngles& angles, double x_mm, double y_mm) const {
  const Frame f = FrameOf(angles);
  const V c = f.camera_dir;
  const V origin{0, 0, -bench_.CentreOffsetMm()};
  const V up{0, 1, 0};
  const V across{c.z, 0, -c.x};  // Cross(up, c): horizontal, facing the camera
  const V pinhole = origin + c * bench_.camera_distance_mm;
  const V r = Normalize(origin + across * x_mm + up * y_mm - pinhole);
  if (c.z > 0) return TraceReflection(f.source_dir, f.phi, pinhole, r);
  if (c.z == 0) return std::nullopt;  // edge-on

  // Enter the sphere (first intersection from the camera side).
  const double R = bench_.sphere_radius_mm;
  const V oc = pinhole - origin;
  const double b = Dot(oc, r);
  const double disc = b * b - (LengthSquared(oc) - R * R);
  if (disc <= 0) return std::nullopt;
  const V on_sphere = pinhole + r * (-b - std::sqrt(disc));
  if (on_sphere.z > -bench_.sample_thickness_mm) return std::nullopt;  // beside the lens
  const V n_s = (on_sphere - origin) / R;                              // outward
  const double cos_i = Dot(-r, n_s);
  if (cos_i <= 0) return std::nullopt;
  const double t_exit = 1 - optics::FresnelDielectric(cos_i, bench_.eta);
  const double t_pole = 1 - optics::FresnelDielectric(1.0, bench_.eta);
  const V in_glass = Refract(-r, n_s, cos_i, bench_.eta);
  if (in_glass.z <= 0) return std::nullopt;

  // Through the glass to the rough surface z = 0.
  const V hit = on_sphere + in_glass * (-on_sphere.z / in_glass.z);
  if (std::abs(hit.x) > bench_.plate_half_width_mm || std::abs(hit.y) > bench_.plate_half_width_mm)
    return std::nullopt;
  const V source = origin + f.source_dir * bench_.source_distance_mm;
  const V to_source = source - hit;
  const double dist = Length(to_source);
  PixelRay ray;
  ray.l = AzimuthTurn(to_source / dist, f.phi);
  ray.v = AzimuthTurn(-in_glass, f.phi);
  ray.hit_mm = AzimuthTurn(hit, f.phi);
  // Radiance leaves the sphere scaled by the Fresnel transmittance relative to the pole's; the
  // irradiance at the hit point falls with the square of its distance from the source.
  const double inv_sq = bench_.source_distance_mm / dist;
  ray.exit_transmittance = t_exit / t_pole * inv_sq * inv_sq;
  return ray;
}

// The camera on the light side sees the rough face straight from the air: no lens in the way,
// the same flood illumination falling off with the square of the distance to the source.
std::optional<PixelRay> Scene::TraceReflection(const V& source_dir, double phi, const V& pinhole,
                                               const V& r) const {
  if (r.z >= 0) return std::nullopt;
  const V hit = pinhole + r * (-pinhole.z / r.z);  // the rough surface z = 0
  if (std::abs(hit.x) > bench_.plate_half_width_mm || std::abs(hit.y) > bench_.plate_half_width_mm)
    return std::nullopt;
  const V origin{0, 0, -bench_.CentreOffsetMm()};
  const V to_source = origin + source_dir * bench_.source_distance_mm - hit;
  const double dist = Length(to_source);
  PixelRay ray;
  ray.l = AzimuthTurn(to_source / dist, phi);
  ray.v = AzimuthTurn(-r, phi);
  ray.hit_mm = AzimuthTurn(hit, phi);
  const double inv_sq = bench_.source_distance_mm / dist;
  // The scene's constant k is per unit of f_t cos theta_l as seen through the lens: radiance
  // leaving the glass is f_t cos E / eta^2 times the pole's Fresnel transmittance. The same k for
  // radiance reflected into the air undoes both, so the two sides' rates compare.
  const double t_pole = 1 - optics::FresnelDielectric(1.0, bench_.eta);
  ray.exit_transmittance = bench_.eta * bench_.eta / t_pole * inv_sq * inv_sq;
  return ray;
}

int Scene::AperturePoints(const StageAngles& angles) const {
  const NominalGeometry g = Nominal(bench_, angles);
  if (g.source_hidden || !g.transmission || g.l.z <= 0) return 0;
  const ApertureDecision d =
      ApertureMatters(*truth_, g.l, g.v, o_.apertures, o_.aperture_tolerance);
  // A narrow lobe: one whose peak at this incidence (the straight-through view) the apertures
  // change by more than 1 %. Its frames are averaged wherever the lobe is lit at the nominal pair,
  // whatever the change there: on the ring where the lobe's curvature changes sign the cones
  // change the nominal pixel by nothing and the rest of the rectangle by much (antiglare at 60 deg,
  // 1.01 deg off its peak: 4.7 sigma of the mean over 2 x 6 pixels, 30 over 3 x 10 mm, when the
  // nominal pixel decided alone).
  const double tt = std::asin(std::sin(angles.sample_deg * kDeg) / bench_.eta) / kDeg;
  const NominalGeometry peak =
      Nominal(bench_, StageAnglesFor(angles.sample_deg, -tt, angles.azimuth_deg));
  const bool narrow =
      ApertureMatters(*truth_, peak.l, peak.v, o_.apertures, 0).relative_change > 0.01;
  // relative_change is 0 where neither the point nor the cones see any of the lobe.
  if (narrow) return d.relative_change > 0 ? o_.aperture_points : 0;
  return d.matters ? 5 : 0;
}

double Scene::RateAt(const StageAngles& angles, double x_mm, double y_mm, bool shadowed,
                     int aperture_points) const {
  const auto ray = shadowed ? std::nullopt : Trace(angles, x_mm, y_mm);
  if (!ray) {
    return std::hypot(x_mm, y_mm) < bench_.sphere_radius_mm ? o_.stray_lens_e_per_s
                                                            : o_.stray_background_e_per_s;
  }
  double signal = 0;
  if (ray->v.z > 0) {  // reflection: the truth may hold no BRDF (then stray light only)
    if (ray->l.z > 0)
      signal = o_.electrons_per_s_per_unit * truth_->BrdfCos(ray->l, ray->v).value_or(0) *
               ray->exit_transmittance;
  } else if (ray->l.z > 0) {
    const double f = aperture_points > 0 ? ApertureAveragedBtdfCos(*truth_, ray->l, ray->v,
                                                                   o_.apertures, aperture_points)
                                         : truth_->BtdfCos(ray->l, ray->v);
    signal = o_.electrons_per_s_per_unit * f * ray->exit_transmittance;
  }
  return signal + o_.stray_lens_e_per_s;
}

double Scene::PixelRate(const StageAngles& angles, const ImageRegion& region, int col,
                        int row) const {
  const bool shadowed = Nominal(bench_, angles).source_hidden;
  const auto [x, y] = ObjectPointMm(region, col, row);
  return RateAt(angles, x, y, shadowed, AperturePoints(angles));
}

cv::Mat1d Scene::Render(const StageAngles& angles, const ImageRegion& region) const {
  cv::Mat1d out(region.height, region.width, 0.0);
  const bool shadowed = Nominal(bench_, angles).source_hidden;
  const int points = AperturePoints(angles);
  // A wide lobe's aperture factor (averaged / point value) varies slowly across the image: it is
  // computed at every 8th sensor pixel and interpolated, which makes a frame 20 times cheaper
  // than averaging every pixel (0.5 s, long enough to hold up the camera's firmware) and changes
  // a 1 x 3 mm rectangle's mean by under 1e-5 (SceneTest.ApertureFactorGridMatchesEveryPixel).
  // A narrow lobe's pixels are each averaged, and so are those of a truth whose factor jumps by
  // more than 5 % somewhere (a binned table).
  constexpr int kStep = 8;
  const int c0 = region.offset_x, r0 = region.offset_y;
  const int c1 = std::min(region.sensor_width, c0 + region.width * region.binning_h);
  const int r1 = std::min(region.sensor_height, r0 + region.height * region.binning_v);
  bool grid = points == 5;
  const int nx = grid ? (c1 - c0 - 1) / kStep + 2 : 0, ny = grid ? (r1 - r0 - 1) / kStep + 2 : 0;
  cv::Mat1d factor(std::max(ny, 1), std::max(nx, 1), 1.0);
  if (grid) {
    cv::parallel_for_(cv::Range(0, ny), [&](const cv::Range& rows) {
      for (int j = rows.start; j < rows.end; ++j)
        for (int i = 0; i < nx; ++i) {
          const auto [x, y] = ObjectPointMm(region, c0 + i * kStep, r0 + j * kStep);
          const auto ray = shadowed ? std::nullopt : Trace(angles, x, y);
          if (!ray || ray->v.z > 0 || ray->l.z <= 0) continue;
          const double p = truth_->BtdfCos(ray->l, ray->v);
          if (p > 0)
            factor(j, i) = ApertureAveragedBtdfCos(*truth_, ray->l, ray->v, o_.apertures, 5) / p;
        }
    });
    // A truth that is not smooth on the grid's scale (a binned Monte Carlo table: the cones
    // reach into the next bin) cannot be interpolated: each pixel is averaged instead.
    double lo = 0, hi = 0;
    cv::minMaxLoc(factor, &lo, &hi);
    if (lo < 0.95 || hi > 1.05) grid = false;
  }
  auto factor_at = [&](int col, int row) {
    const double u = double(col - c0) / kStep, v = double(row - r0) / kStep;
    const int i = std::min(static_cast<int>(u), nx - 2), j = std::min(static_cast<int>(v), ny - 2);
    const double fu = u - i, fv = v - j;
    return (1 - fv) * ((1 - fu) * factor(j, i) + fu * factor(j, i + 1)) +
           fv * ((1 - fu) * factor(j + 1, i) + fu * factor(j + 1, i + 1));
  };
  cv::parallel_for_(cv::Range(0, region.height), [&](const cv::Range& rows) {
    for (int j = rows.start; j < rows.end; ++j) {
      for (int i = 0; i < region.width; ++i) {
        double sum = 0;
        for (int dj = 0; dj < region.binning_v; ++dj) {
          for (int di = 0; di < region.binning_h; ++di) {
            const int col = region.offset_x + i * region.binning_h + di;
            const int row = region.offset_y + j * region.binning_v + dj;
            if (col >= region.sensor_width || row >= region.sensor_height) continue;
            const auto [x, y] = ObjectPointMm(region, col, row);
            if (!grid) {
              sum += RateAt(angles, x, y, shadowed, points);
              continue;
            }
            // The point rate is stray light plus the signal; only the signal is averaged.
            const double rate = RateAt(angles, x, y, shadowed, 0);
            const double stray = o_.stray_lens_e_per_s;
            sum += rate > stray ? stray + (rate - stray) * factor_at(col, row) : rate;
          }
        }
        out(j, i) = sum;
      }
    }
  });
  return out;
}

}  // namespace gonio::sim
