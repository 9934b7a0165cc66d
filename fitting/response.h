// The instrument response of one measured point: the (light, view) direction pairs that the fixed
// rectangle of the image integrates over, with their weights, computed from the bench's
// configuration (docs/measurement.md). A stored sample is the rectangle's mean, so the model of
// it is not k f(l0, v0) cos at the nominal pair but
//   S = k / N sum_j w_j f(l_j, v_j) |cos theta_lj|                                         (R1)
// over the N sensor pixels of the rectangle, each traced from the camera's pinhole through the
// hemisphere lens to the rough surface: Snell's law at the sphere, the plate's glass path, the
// light direction from the hit point to the source. w_j is the Fresnel transmittance at the
// sphere relative to the pole's times the source's inverse square relative to its distance from
// the sphere centre; a pixel whose ray misses the lens or the plate has w_j = 0 (it sees only
// stray light, which a floor term or a measured background accounts for). A camera on the light
// side (reflection plans) sees the rough face directly: its rays go straight from the pinhole to
// z = 0, w_j the inverse square alone, and f is the BRDF (eq. 20).
//
// The finite source and lens apertures widen each pair into two small cones (the source's around
// l, the lens's around v). Averaging over them matters for narrow lobes only, so it is a separate
// step (WithApertures) that the fitter takes where it changes the prediction.
//
// Conventions (the bench's, documented in docs/measurement.md and docs/scene.md):
//   * Sample frame: the rough surface is z = 0, its normal +z toward the air and the source. The
//     hemisphere lens's sphere centre O = (0, 0, -(thickness - centred_thickness)).
//   * Stages: one vertical axis through O. Sample rotation s puts the source at polar angle s on
//     the +x side; the detector arm at lab angle a puts the camera at polar angle s - a in the x-z
//     plane; the azimuth stage turns the sample by phi about its normal (lab vectors turn by -phi).
//   * Camera: a pinhole camera_distance from O looking at O; the sensor pixel (col, row) looks at
//     ((col + 1/2 - W/2) p, (row + 1/2 - H/2) p) of the plane through O facing the camera, with p
//     the object-side pixel pitch, x horizontal (in the plane of incidence) and y vertical.
//
// This is written from the bench's geometry, not from the simulator: the simulated scene is what
// it is tested against (tests/fitting/response_test.cc renders the scene's rectangle).
#pragma once

#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "common/result.h"
#include "optics/bench_optics.h"
#include "optics/vecmath.h"

namespace gonio::fitting {

// The response is traced through the bench's optics (optics/bench_optics.h).
using optics::BenchOptics;

// Where a plan's rectangle lies on the sensor: output pixels of the camera's region.
struct SensorRectangle {
  int offset_x = 0, offset_y = 0;           // the region's origin, sensor pixels
  int binning_h = 1, binning_v = 1;         // sensor pixels per output pixel
  int x = 0, y = 0, width = 1, height = 1;  // the rectangle, output pixels of the region
};

// Everything a run needs to rebuild each point's response: stored with the run (as JSON).
struct ResponseSetup {
  BenchOptics bench;
  SensorRectangle rectangle;
  double thickness_mm = 6.0;  // the specimen's

  Status Validate() const;  // the bench's, and the rectangle inside the sensor
  std::string ToJson() const;
  // Errors name the field that is missing or wrong ("response: bench.mm_per_pixel: ...").
  static Result<ResponseSetup> FromJson(const std::string& text);
};

// The stage positions a point was measured at (read back), degrees.
struct StagePosition {
  double sample_deg = 0, arm_deg = 180, azimuth_deg = 0;
};

struct ResponseRay {
  optics::Vec3<double> l, v;  // sample frame: l toward the source, v toward the camera
  double weight = 0;          // w_j of (R1), > 0
};

struct Response {
  std::vector<ResponseRay> rays;  // the rays that reach the surface (w > 0)
  double pixels = 0;              // N of (R1): every pixel of the rectangle, dark ones included
  optics::Vec3<double> l0, v0;    // the nominal pair: the central ray through O
  double source_half_angle = 0, receiver_half_angle = 0;  // radians (WithApertures)
  bool apertures = false;  // whether the rays already carry the aperture cones
};

// The nominal pair of a stage position: l0 toward the source, v0 toward the camera (the central
// ray through O), in the sample frame. The camera on the air side gives a reflection pair.
std::pair<optics::Vec3<double>, optics::Vec3<double>> NominalDirections(const StagePosition& at);

// The response of a point: through the lens for a camera on the glass side (transmission), straight
// to the rough face for one on the air side (reflection; each ray weighted by the source's inverse
// square alone, so that w = 1 at the centre as it is in transmission). Errors: an invalid setup, a
// camera in the sample's plane, or a rectangle none of whose pixels reaches the surface.
// `max_rays` bounds the rays: a larger rectangle is traced at the centres of blocks of pixels,
// each block's ray weighted by its pixel count (the signal is smooth on the scale of a block).
Result<Response> ComputeResponse(const ResponseSetup& setup, const StagePosition& at,
                                 int max_rays = 256);

// The response with every pair spread over the source and lens cones: the rectangle traced with
// at most `max_base_rays` rays, then each ray turned into rings x per_ring directions in each
// cone (rings at the Gauss-Legendre nodes of cos theta, per_ring directions evenly spaced on
// each; the product of the two cones), its weight shared by the rule's weights. Each
// ray's cones are turned by the golden angle times its index, so that many rays with few cone
// directions each still cover the cones evenly between them (large rectangles).
Result<Response> ComputeResponseWithApertures(const ResponseSetup& setup, const StagePosition& at,
                                              int rings = 3, int per_ring = 6,
                                              int max_base_rays = 16);

// Successively finer responses of one point, for the fitter's refinement. The rectangle's levels
// trace more rays (64, 256, 1 024, then every pixel); the apertures' levels keep the rectangle's
// rays (at its level) and spread each over more rings and directions per cone (rings x per_ring:
// 1 x 5, 2 x 6, 3 x 8, 4 x 12, 6 x 16; each ray's cones turned by the golden angle). nullopt
// past the finest.
struct ResponseLevel {
  int max_rays = 0;       // 0: every pixel
  int cone_rings = 0;     // Gauss-Legendre rings per cone; 0: no apertures
  int cone_per_ring = 0;  // directions on each ring
};
std::optional<ResponseLevel> RectangleLevel(int level);
// The apertures' level `level` on top of the rectangle's `rectangle_level`.
std::optional<ResponseLevel> ApertureLevel(int level, int rectangle_level);
Result<Response> ComputeAtLevel(const ResponseSetup& setup, const StagePosition& at,
                                const ResponseLevel& level);
// At most how many rays ComputeAtLevel gives (the rectangle's rays or blocks times both cones'
// directions), known before tracing one: the fitter keeps a sample's model within a budget.
long MaxRaysAtLevel(const ResponseSetup& setup, const ResponseLevel& level);
// sum_j w_j f(l_j, v_j) / N over the rays ComputeAtLevel would give, without holding them: a
// level finer than a model's budget is evaluated this way (a 3 x 10 mm rectangle with fine cones
// is millions of rays). Errors: those of ComputeResponse.
Result<double> MeanOverLevel(const ResponseSetup& setup, const StagePosition& at,
                             const ResponseLevel& level,
                             const std::function<double(const ResponseRay&)>& f);

// One pair spread over the two cones (what ComputeResponseWithApertures does to each ray): the
// product of the cones' directions, `weight` shared by the quadrature's weights (they sum to
// `weight`); directions below the horizon dropped.
std::vector<ResponseRay> ApertureCones(const optics::Vec3<double>& l, const optics::Vec3<double>& v,
                                       double weight, double source_half_angle,
                                       double receiver_half_angle, int rings = 3, int per_ring = 6,
                                       double phase = 0);

// What a sample carries to rebuild its response: its run's setup (shared) and its stage position.
struct PointResponse {
  std::shared_ptr<const ResponseSetup> setup;
  StagePosition at;
};

// Relative solid angle -> half-angle of a cone: omega = 2 pi (1 - cos theta).
double ConeHalfAngle(double solid_angle_sr);

// What a rectangle takes in, for choosing one (the operator's console): its size on the plane
// through O facing the camera, and the spread of the view and light directions of its pixels
// about the nominal pair, weighted as in (R1). At normal incidence seen straight through unless
// `at` says otherwise. Errors: those of ComputeResponse.
struct RectangleCoverage {
  double width_mm = 0, height_mm = 0;
  double view_rms_deg = 0, view_max_deg = 0;
  double light_rms_deg = 0, light_max_deg = 0;
  int rays = 0;  // traced (blocks of pixels for a large rectangle)
};
Result<RectangleCoverage> CoverageOf(const ResponseSetup& setup,
                                     const StagePosition& at = {0, 180, 0});

}  // namespace gonio::fitting
