// The bench's optical geometry (Walter 2007 section 6, docs/scene.md): where the fibre source and
// the camera stand from the sphere centre O, the hemisphere lens, the plate, the sensor's pixel
// pitch at O, the apertures' solid angles, and what each of these is known to. The fitter's
// instrument response traces rays through it (fitting/response.h), the simulator renders its
// scene from it (sim/), and the instrument's config reads it from its [bench] table (config/).
#pragma once

#include <cmath>
#include <cstdlib>
#include <string>
#include <utility>

#include "common/result.h"

namespace gonio::optics {

// The bench's optics, as the instrument configuration's [bench] table gives them.
struct BenchOptics {
  double source_distance_mm = 610;
  double camera_distance_mm = 885;
  double sphere_radius_mm = 37.5;
  double lens_eta = 1.51;             // the hemisphere lens (and the plate: one index)
  double centred_thickness_mm = 6.0;  // the plate thickness that puts O on the rough surface
  double plate_half_width_mm = 50;
  double mm_per_pixel = 0.16;  // object-side pixel pitch at O
  int sensor_width = 512, sensor_height = 512;
  double source_sr = 0.000076;    // the fibre end's solid angle at the sample
  double receiver_sr = 0.000039;  // the lens aperture's at the sample
  // What the geometry is known to: the uncertainty budget's geometry components (the
  // fitter's GeometryUse). 0 means not stated, and the fit says it leaves that component out.
  //   angle_sigma_deg: each stage's read-back angle, per point (encoder resolution / sqrt 12 and
  //     repeatability); it enters each sample's sigma through the local slope of the signal.
  //   thickness_sigma_mm: the plate's thickness (so the sphere centre's offset), common to a run.
  //   rectangle_sigma_px: the rectangle's position against the optical axis (the camera's
  //     alignment), output pixels, common to a run.
  double angle_sigma_deg = 0;
  double thickness_sigma_mm = 0;
  double rectangle_sigma_px = 0;
  // Where the optical axis meets the sensor, sensor pixels right of and below its centre (the
  // camera's alignment; 0 = the centre). The fitter moves it by fractions of a pixel to profile
  // the rectangle's position (fitter.h, GeometryUse).
  double axis_x_px = 0, axis_y_px = 0;

  // Positive, finite lengths; the sensor's size; apertures >= 0. Errors name the field
  // ("bench.mm_per_pixel must be ...").
  Status Validate() const;
};

inline Status BenchOptics::Validate() const {
  const std::pair<const char*, double> lengths[] = {
      {"source_distance_mm", source_distance_mm},   {"camera_distance_mm", camera_distance_mm},
      {"sphere_radius_mm", sphere_radius_mm},       {"centred_thickness_mm", centred_thickness_mm},
      {"plate_half_width_mm", plate_half_width_mm}, {"mm_per_pixel", mm_per_pixel}};
  for (const auto& [name, value] : lengths)
    if (!(std::isfinite(value) && value > 0))
      return InvalidArgument(std::string("bench.") + name + " must be a finite number > 0");
  if (!(lens_eta > 1 && lens_eta < 3)) return InvalidArgument("bench.lens_eta must lie in (1, 3)");
  if (sensor_width < 1 || sensor_height < 1)
    return InvalidArgument("bench.sensor_width and sensor_height must be >= 1");
  for (const auto& [name, value] : {std::pair{"angle_sigma_deg", angle_sigma_deg},
                                    {"thickness_sigma_mm", thickness_sigma_mm},
                                    {"rectangle_sigma_px", rectangle_sigma_px}})
    if (!(std::isfinite(value) && value >= 0 && value < 1000))
      return InvalidArgument(std::string("bench.") + name + " must be a finite number >= 0");
  if (!(std::abs(axis_x_px) <= sensor_width && std::abs(axis_y_px) <= sensor_height))
    return InvalidArgument("bench.axis_x_px and axis_y_px must be finite and on the sensor");
  if (!(std::isfinite(source_sr) && source_sr >= 0 && source_sr < 1) ||
      !(std::isfinite(receiver_sr) && receiver_sr >= 0 && receiver_sr < 1))
    return InvalidArgument("bench.source_sr and receiver_sr must lie in [0, 1) sr");
  if (!(camera_distance_mm > sphere_radius_mm && source_distance_mm > sphere_radius_mm))
    return InvalidArgument("bench: the source and the camera must lie outside the lens's sphere");
  return OkStatus();
}

}  // namespace gonio::optics
