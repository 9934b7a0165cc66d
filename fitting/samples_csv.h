// Samples as CSV: the thin file layer above the fitter (the database layer arrives with #6).
//
// Format: a header row naming the columns, in any order, then one sample per row.
//   theta_l_deg, theta_v_deg, value, sigma   required (bench angles, sample.h)
//   phi_l_deg, phi_v_deg                     optional, default 0
//   side                                     optional: transmission (or empty) or reflection
//                                            (theta_v from +n, common/bench_angles.h; fitted
//                                            with the BRDF, eq. 20)
//   sample_read_deg, arm_read_deg,           with a "# response: {json}" line before the header
//   azimuth_read_deg                         (an exported run of a bench with [bench]): each
//                                            sample's stage position, so that it carries its
//                                            instrument response (response.h)
//   sigma_stat                               optional: sigma's statistical part (an export's)
//   background                               optional: the stray-light background measured at
//                                            the point and already subtracted from value (an
//                                            export's; empty where none was): no floor is fitted
//                                            to rows that all have one
// Other columns are ignored. Blank lines and other lines starting with '#' are skipped.
// Every error names file:line and the column; nothing is guessed.
#pragma once

#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "common/result.h"
#include "fitting/sample.h"

namespace gonio::fitting {

Result<std::vector<Sample>> ReadSamplesCsv(const std::string& path);
// `name` is what messages call the text (a path, or "<stdin>").
Result<std::vector<Sample>> ParseSamplesCsv(std::string_view text, const std::string& name);
// Writes the required and optional columns; used for synthetic data sets (tests, benchmarks).
Status WriteSamplesCsv(const std::string& path, std::span<const Sample> samples);

}  // namespace gonio::fitting
