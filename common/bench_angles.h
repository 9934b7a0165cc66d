// The bench's stage angles for a measurement geometry (Walter 2007 section 6): the sample rotation
// sets the incidence angle, the detector arm the view angle, through the hemisphere (transmission)
// or on the light side (reflection). Angles are the fitter's bench angles
// (fitting/sample.h): light at theta_l, view at theta_v from -n in the plane of incidence, so
// theta_v = -theta_t looks straight through. The source is fixed in the lab at arm angle 0; arm
// 180 deg looks straight through the sample at normal incidence. Dependency-free: the simulator
// and acquisition share it.
#pragma once

#include <cmath>

namespace gonio {

struct StageTargets {
  double sample_deg = 0;
  double arm_deg = 180;  // in [0, 360)
  double azimuth_deg = 0;
};

inline StageTargets StageTargetsFor(double theta_l_deg, double theta_v_deg,
                                    double azimuth_deg = 0) {
  double arm = std::fmod(theta_l_deg + theta_v_deg + 180, 360.0);
  if (arm < 0) arm += 360;
  return {theta_l_deg, arm, azimuth_deg};
}

// Reflection (the camera on the light side, looking at the rough face from the air): theta_v is
// measured from +n, positive away from the light, so theta_v = theta_l is the specular direction
// and theta_v = -theta_l looks back along the beam (arm 0, in the source's beam).
inline StageTargets StageTargetsForReflection(double theta_l_deg, double theta_v_deg,
                                              double azimuth_deg = 0) {
  double arm = std::fmod(theta_l_deg + theta_v_deg, 360.0);
  if (arm < 0) arm += 360;
  return {theta_l_deg, arm, azimuth_deg};
}

// Whether the detector arm sits in the source's beam: within `half_angle_deg` of arm angle 0.
inline bool ArmInSourceBeam(double arm_deg, double half_angle_deg) {
  double a = std::fmod(arm_deg, 360.0);
  if (a < 0) a += 360;
  return a < half_angle_deg || a > 360 - half_angle_deg;
}

}  // namespace gonio
