// The bench's finite apertures (docs/reference.md section 1): the fibre source subtends 0.000076 sr
// at the sample (610 mm), the camera lens 0.000039 sr (885 mm, f/5.6). A measured sample is the
// BTDF*cos averaged over both cones, not its value at one pair of directions. Whether that
// matters depends on the lobe: "model no more than the scene needs" - the scene asks
// ApertureMatters() and averages only where the difference exceeds what a measurement resolves.
#pragma once

#include "sim/truth/ground_truth.h"

namespace gonio::sim {

struct Apertures {
  double source_sr = 0.000076;    // fibre light guide end, 6 mm at 610 mm
  double receiver_sr = 0.000039;  // 35 mm lens at f/5.6, 885 mm
  // Cone half-angles (radians) of the solid angles: omega = 2 pi (1 - cos theta).
  double SourceHalfAngle() const;
  double ReceiverHalfAngle() const;
};

// BTDF*cos averaged uniformly over the source cone around l and the receiver cone around v (the
// view cone is the same inside the glass: rays to the camera leave the hemisphere along its
// normal, unrefracted). Quadrature: about n_points directions per cone, on rings at the
// Gauss-Legendre nodes of cos(theta) and evenly spaced in azimuth (the product is evaluated).
double ApertureAveragedBtdfCos(const GroundTruth& truth, const optics::Vec3<double>& l,
                               const optics::Vec3<double>& v, const Apertures& a,
                               int n_points = 32);

struct ApertureDecision {
  bool matters = false;
  double relative_change = 0;  // |averaged - point| / point at the geometry asked about
};
// Whether averaging over the apertures changes the signal at (l, v) by more than `tolerance`
// (relative; e.g. the 1-sigma noise of a measurement at that point).
ApertureDecision ApertureMatters(const GroundTruth& truth, const optics::Vec3<double>& l,
                                 const optics::Vec3<double>& v, const Apertures& a,
                                 double tolerance);

}  // namespace gonio::sim
