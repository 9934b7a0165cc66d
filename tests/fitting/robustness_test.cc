// Bad input never crashes, hangs or silently produces a number: randomised inputs to the CSV
// parser and the fitter each end in an error naming the problem or in a finite result.
// (Run under AddressSanitizer/UBSan in CI, which turns any memory or UB slip into a failure.)
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <string>

#include "fitting/fitter.h"
#include "fitting/samples_csv.h"
#include "fitting/synthetic.h"

namespace gonio::fitting {
namespace {

TEST(Robustness, CsvParserNeverCrashesOnMutatedFiles) {
  SyntheticSweep spec;
  spec.theta_v_step = 10;
  const auto good = MakeSyntheticSweep(spec);
  std::string base = "theta_l_deg,phi_l_deg,theta_v_deg,phi_v_deg,value,sigma\n";
  for (const Sample& s : good)
    base += std::to_string(ThetaLightDeg(s)) + ",0," + std::to_string(ThetaViewDeg(s)) + ",0," +
            std::to_string(s.value) + "," + std::to_string(s.sigma) + "\n";
  std::mt19937_64 rng(17);
  const std::string alphabet = "0123456789.,-+eE\n\r #naifNA\t\"x";
  int errors = 0, parsed = 0;
  for (int k = 0; k < 3000; ++k) {
    std::string text = base;
    const int edits = 1 + static_cast<int>(rng() % 8);
    for (int e = 0; e < edits && !text.empty(); ++e) {
      const std::size_t at = rng() % text.size();
      switch (rng() % 3) {
        case 0:
          text[at] = alphabet[rng() % alphabet.size()];
          break;
        case 1:
          text.erase(at, 1 + rng() % 5);
          break;
        default:
          text.insert(at, 1, alphabet[rng() % alphabet.size()]);
          break;
      }
    }
    auto r = ParseSamplesCsv(text, "m.csv");
    if (!r) {
      ++errors;
      EXPECT_EQ(r.error().message.rfind("m.csv", 0), 0u) << r.error().message;  // names the file
      continue;
    }
    ++parsed;
    for (const Sample& s : *r) {
      ASSERT_TRUE(std::isfinite(s.value) && std::isfinite(s.sigma));
      ASSERT_NEAR(optics::LengthSquared(s.view), 1.0, 1e-9);
    }
  }
  EXPECT_GT(errors, 100);  // the mutations do break files...
  EXPECT_GT(parsed, 100);  // ...and some survive as valid CSV
}

TEST(Robustness, FitterReturnsAnErrorOrAFiniteResultForHostileSamples) {
  SyntheticSweep spec;
  spec.theta_v_step = 4;
  const auto good = MakeSyntheticSweep(spec);
  std::mt19937_64 rng(23);
  const double specials[] = {
      0.0, -0.0, 1e-300, 1e300, -1e300, std::nan(""), std::numeric_limits<double>::infinity(),
      -1.0};
  int errors = 0, fits = 0;
  for (int k = 0; k < 400; ++k) {
    auto data = good;
    for (int e = 0; e <= k % 3; ++e) {  // one to three edits
      Sample& s = data[rng() % data.size()];
      const double v = specials[rng() % std::size(specials)];
      switch (rng() % 4) {
        case 0:
          s.value = v;
          break;
        case 1:
          s.sigma = v;
          break;
        case 2:
          s.view.z = v;
          break;
        default:
          s.value *= 1e6;
          break;  // an outlier, still valid input
      }
    }
    FitOptions o;
    o.model.family = kAllFamilies[k % 4];
    o.max_local_fits = 1;
    auto r = Fit(data, o);
    if (!r) {
      ++errors;
      EXPECT_FALSE(r.error().message.empty());
      continue;
    }
    ++fits;
    if (r->status == FitStatus::kFailed) continue;
    EXPECT_TRUE(std::isfinite(r->width.value) && r->width.value > 0);
    EXPECT_TRUE(std::isfinite(r->scale.value) && std::isfinite(r->chi2));
    EXPECT_TRUE(std::isfinite(r->width.sigma));
  }
  // One invalid edit rejects the whole set, so most sets are errors; both branches must occur.
  EXPECT_GT(errors, 100);
  EXPECT_GT(fits, 10);
}

}  // namespace
}  // namespace gonio::fitting
