// The bench of Walter et al. 2007 section 6 (docs/reference.md section 1) as the simulated camera
// sees it: stage angles -> the light and view directions at the sample, and the image of the
// hemisphere lens, pixel by pixel, with the radiance the ground truth predicts.
//
// Frames (all lengths in mm, angles in degrees at the edges):
// - Sample frame: the rough surface is z = 0 with its normal +z toward the air and the source;
//   the hemisphere lens is below. The sphere centre O = (0, 0, -d), d = CentreOffsetMm(): 0 for a
//   6 mm sample, positive (centre inside the glass) for a thicker one.
// - Stages: one vertical axis (the sample frame's y) through O carries both the sample rotation
//   and the detector arm. The source sits at lab angle 0. Sample rotation s puts the source at
//   polar angle s on the +x side, l = (sin s, 0, cos s) (the fitter's convention, sample.h); the
//   arm at lab angle a puts the camera at polar angle s - a in the x-z plane (a = 180, s = 0:
//   straight through; Snell's direction is at a = 180 + s - theta_t). The optional azimuth axis
//   turns the sample about its own normal.
// - Camera: a pinhole CameraDistanceMm() from O looking at O; pixel (col, row) of the full sensor
//   looks at the point (col + 1/2 - W/2, row + 1/2 - H/2) * mm_per_pixel of the plane through O
//   facing the camera (object-side pixel pitch).
//
// What is modelled, and why (docs/scene.md): each pixel's ray is traced exactly - refraction
// into the sphere, the glass path to the rough surface, the light direction from the hit point to
// the source. That single trace carries the finite rectangle's spread of view directions, the
// sphere-centre offset (it moves the hit points, hence the light direction) and the edge of the
// plate; none needs its own correction. The finite source and lens apertures are averaged where
// they matter (transmission only): a wide lobe's when ApertureMatters says so at the nominal
// geometry, a narrow lobe's wherever it is lit there (Scene::AperturePoints). With the
// camera on the light side (reflection plans) the flat rough face is seen directly: the ray meets
// z = 0, and the pixel's radiance is the truth's BRDF (no lens, no glass path; light reflected at
// the hemisphere's back faces is not modelled). One refractive index for
// sample, adhesive and lens: their 1.50-1.52 mismatch bends a ray by < 0.02 deg.
#pragma once

#include <memory>
#include <optional>

#include <opencv2/core.hpp>

#include "sim/scene/aperture.h"
#include "sim/truth/ground_truth.h"

namespace gonio::sim {

struct BenchGeometry {
  double source_distance_mm = 610;
  double camera_distance_mm = 885;
  double sphere_radius_mm = 37.5;  // 75 mm plano-convex lens, nearly a hemisphere
  double eta = 1.51;               // glass below the rough surface, air above
  double sample_thickness_mm = 6.0;
  double centred_thickness_mm = 6.0;  // the thickness that puts O on the rough surface
  double plate_half_width_mm = 50;    // 100 mm square plate
  // Half-angle (deg) around the source direction inside which the detector arm and camera body
  // block the source beam (reflection geometries near retro-reflection).
  double arm_shadow_half_angle_deg = 4.0;

  double CentreOffsetMm() const { return sample_thickness_mm - centred_thickness_mm; }
};

struct StageAngles {
  double sample_deg = 0;   // sample rotation: the incidence angle
  double arm_deg = 180;    // detector arm, lab angle; 180 = straight through at normal incidence
  double azimuth_deg = 0;  // optional third axis, about the sample normal
  // The beam block (an axis of role "beam_block": a flag on a small rotation stage ahead of the
  // sample) is in the source beam: no source light reaches the sample, stray light remains.
  bool beam_blocked = false;
};

// The directions at the sample for the nominal rays (through O), in the sample frame.
struct NominalGeometry {
  optics::Vec3<double> l, v;  // toward the source; toward the camera
  bool transmission = false;  // camera on the glass side (v.z < 0)
  bool arm_shadows_source = false;
  // No source light reaches the sample: the arm shadows it, or the beam block is in the beam.
  bool source_hidden = false;
};
NominalGeometry Nominal(const BenchGeometry& bench, const StageAngles& angles);

// Stage angles for the fitter's bench angles (fitting/sample.h): light at theta_l, view at
// theta_v from -n in the plane of incidence (theta_v = -theta_t is straight through). The arm
// angle is returned in [0, 360). The inverse of Nominal in the plane of incidence.
StageAngles StageAnglesFor(double theta_l_deg, double theta_v_deg, double azimuth_deg = 0);

// The image geometry the camera asks for: a region of the sensor, binned.
struct ImageRegion {
  int sensor_width = 512, sensor_height = 512;
  double mm_per_pixel = 0.16;      // object-side pitch at O; 512 px = 82 mm covers the lens
  int offset_x = 0, offset_y = 0;  // sensor pixels
  int width = 512, height = 512;   // output pixels
  int binning_h = 1, binning_v = 1;
  bool operator==(const ImageRegion&) const = default;
};

struct SceneOptions {
  // Photo-electrons per second in one sensor pixel per unit of BtdfCos (1/sr), at the lamp's
  // nominal output: the overall constant k of S = k f_t cos theta_l, with QE folded in.
  double electrons_per_s_per_unit = 1000;  // ground glass peaks near 23/sr: ~23000 e-/s
  // Stray light (e-/s per sensor pixel) where the lens is in view, and around it.
  double stray_lens_e_per_s = 2.0;
  double stray_background_e_per_s = 0.2;
  Apertures apertures;
  // Average the apertures when they change the nominal value by more than this: 2e-4, below the
  // 3e-4 a ground-glass peak resolves (docs/measurement.md); 0.005 left a 0.1-0.8 % bias there.
  double aperture_tolerance = 2e-4;
  // Directions per cone where they are averaged (aperture.h's rings) for a narrow lobe, one whose
  // straight-through peak at the incidence rendered the apertures change by more than 1 %: 20 is
  // two Gauss-Legendre rings of 10, within 1e-6 of 320 directions on antiglare's flank 1.4 deg
  // off its peak, where 10 (one ring) left the lobe 3.6 % low; at four times 10's cost. A wide
  // lobe gets one ring of 5, exact to second order in the cone's size like every ring rule (about
  // 1e-5 for ground glass), at a sixteenth of 20's cost.
  int aperture_points = 20;
};

// One pixel's traced ray.
struct PixelRay {
  optics::Vec3<double> l, v;    // sample frame, at the hit point
  optics::Vec3<double> hit_mm;  // on the rough surface
  // What multiplies k * f cos theta_l: the Fresnel transmittance at the sphere surface relative
  // to the pole's, and the source's inverse square; for reflection, eta^2 / the pole's
  // transmittance instead of the first (Scene::TraceReflection says why).
  double exit_transmittance = 1;
};

class Scene {
 public:
  Scene(BenchGeometry bench, std::shared_ptr<const GroundTruth> truth, SceneOptions options = {});

  const BenchGeometry& bench() const { return bench_; }
  const GroundTruth& truth() const { return *truth_; }
  const SceneOptions& options() const { return o_; }

  // The ray of the object-plane point (x_mm, y_mm) (x horizontal in the plane of incidence,
  // y vertical): nullopt where it misses the lens or the plate. A camera on the air side
  // (reflection) sees the rough face directly; v then points up (v.z > 0).
  std::optional<PixelRay> Trace(const StageAngles& angles, double x_mm, double y_mm) const;

  // Photo-electron rate (e-/s) per output pixel at the lamp's nominal output: the sum over each
  // bin of the sensor pixels' rates. Where the arm shadows the source only stray light remains.
  cv::Mat1d Render(const StageAngles& angles, const ImageRegion& region) const;

  // The rate of one sensor pixel at its centre (what Render sums), for tests. Its apertures are
  // averaged at the pixel itself, where Render interpolates a wide lobe's aperture factor from
  // every 8th pixel: the two agree within 1e-5.
  double PixelRate(const StageAngles& angles, const ImageRegion& region, int col, int row) const;

 private:
  // `aperture_points`: directions per cone to average over, 0 for none.
  double RateAt(const StageAngles& angles, double x_mm, double y_mm, bool shadowed,
                int aperture_points) const;
  std::optional<PixelRay> TraceReflection(const optics::Vec3<double>& source_dir, double phi,
                                          const optics::Vec3<double>& pinhole,
                                          const optics::Vec3<double>& r) const;
  // The directions per cone the geometry's pixels are averaged over (0: none needed).
  int AperturePoints(const StageAngles& angles) const;

  BenchGeometry bench_;
  std::shared_ptr<const GroundTruth> truth_;
  SceneOptions o_;
};

}  // namespace gonio::sim
