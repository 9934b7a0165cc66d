// One measured sample of the bench, and the checks every sample set passes before a fit.
#pragma once

#include <optional>
#include <span>
#include <string>
#include <vector>

#include "common/result.h"
#include "fitting/response.h"
#include "optics/vecmath.h"

namespace gonio::fitting {

// A sample: S(l, v) = k f(l, v) |cos theta_l| (docs/reference.md section 1), with f the BTDF
// (eq. 21) when the view is on the glass side (transmission, the bench's main use) and the BRDF
// (eq. 20) when it is on the air side (reflection: the camera on the light side). One sample set
// is one side: the two sides' k differ (the lens's exit on one, not the other).
struct Sample {
  optics::Vec3<double> light;  // unit; z > 0 (air side), pointing from the sample to the source
  // unit, pointing from the sample to the camera; z < 0 (glass side) for transmission, z > 0
  // (air side) for reflection
  optics::Vec3<double> view;
  double value = 0;  // S in any consistent unit (e.g. dark-subtracted counts per second)
  double sigma = 0;  // 1-sigma uncertainty of value, same unit, > 0
  // The statistical part of sigma (shot, read and dark noise), when the bench's budget gives it
  // (acquisition: sigma_stat); 0 when unknown. The fitter splits each parameter's sigma by it.
  double sigma_stat = 0;
  // The bench measured this point's stray-light background (the beam blocked) and subtracted
  // it, with its uncertainty in sigma: no floor stands in for it (Floor::kAuto fits none).
  bool background_subtracted = false;
  // The error this sample shares with the others of its dark set (the dark frames subtracted
  // from each of them; acquisition: dark_set, sigma_dark): a part of sigma, in value's units, the
  // same error in counts for all of the set. The fitter takes each set's as one nuisance
  // (FitSummary::dark). -1 and 0: none known, sigma is independent from sample to sample.
  int dark_set = -1;
  double sigma_dark = 0;  // >= 0, < sigma
  int line = 0;           // where it came from (file line), 0 when not from a file
  // The instrument response (response.h), when the sample came from a run of a bench whose
  // geometry is known; absent for synthetic or bare CSV samples (the point model then).
  std::optional<PointResponse> response;
};

// The bench's angles, in degrees: the light at theta_l from +n (air side) at azimuth phi_l; the
// view at theta_v from -n (glass side) at azimuth phi_v. In one plane (phi = 0) a negative angle
// means the other side of the normal. The straight-through direction of light at theta_l is
// theta_v = -theta_t (same azimuth convention), with theta_t the refraction angle.
Sample SampleFromBenchAngles(double theta_l_deg, double phi_l_deg, double theta_v_deg,
                             double phi_v_deg, double value, double sigma);
// A reflection sample from the bench's reflection angles (common/bench_angles.h): the view at
// theta_v from +n, positive away from the light, so theta_v = theta_l is the mirror direction.
Sample SampleFromReflectionAngles(double theta_l_deg, double phi_l_deg, double theta_v_deg,
                                  double phi_v_deg, double value, double sigma);
inline bool IsReflection(const Sample& s) { return s.view.z > 0; }
// The bench angles of a sample's directions (degrees), the inverse of the above with phi = 0 or
// 180 folded into a signed theta (for a reflection sample, theta_v as the reflection angles
// count it).
double ThetaLightDeg(const Sample& s);
double ThetaViewDeg(const Sample& s);

// Checks what a fit needs: finite values, sigma > 0, values not more than 5 sigma below zero
// (dark-subtracted noise may be slightly negative; more is a dark-subtraction error), unit
// directions on the right sides (the light on the air side, the view off the surface plane, every
// view on one side), at least n_params + 1 samples, and some signal (some value above its
// sigma). Errors name the first
// offending sample and what is wrong with it: "<source>:12: ..." when the sample came from line
// 12 of a file called source, "line 12: ..." without a source, "sample 11: ..." (0-based index)
// when it has no line.
Status ValidateSamples(std::span<const Sample> samples, int n_params,
                       const std::string& source = "");

std::string Where(const Sample& s, std::size_t index, const std::string& source = "");

// The samples with a relative systematic uncertainty added in quadrature to each sigma:
// sigma^2 + (relative * |value|)^2. A bench's stored sigma is statistical only (frames, dark,
// monitor); what it does not see - the rectangle's spread of view directions, stray light, a
// tabulated truth's own Monte Carlo error - would otherwise make every fit "poor" by chi-square.
// relative must be finite and >= 0 (0 returns the samples unchanged).
std::vector<Sample> WithSystematic(std::span<const Sample> samples, double relative);

// Samples grouped by light direction (one group per incidence of a sweep).
struct IncidenceGroup {
  double theta_l_deg = 0;
  std::vector<Sample> samples;
};
std::vector<IncidenceGroup> GroupByIncidence(std::span<const Sample> samples);

}  // namespace gonio::fitting
