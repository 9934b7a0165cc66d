// Speed against accuracy for the measurement equation (issue #16, docs/measurement.md): the
// simulated scene renders the rectangle of each geometry (rays traced per pixel, the apertures
// where they change a value by 2e-4, with 64 directions per cone for antiglare, the lens's stray
// light), noise as the demo's budget gives it
// is drawn `repeats` times, and each draw is fitted three ways, five where the ray budget binds:
//   point      the point model at the nominal pair (no response), a floor where BIC wants one;
//   rectangle  through the rectangle's rays, apertures as points;
//   full       the rectangle and the apertures (the fitter's default for a run with [bench]),
//              each sample's model within FitOptions::max_response_rays ("N held": the samples
//              of a draw, median, modelled below the level asked for, corrected to the next
//              level, whose error, traced one level finer at the solution, is in sigma);
//   next change  the same with the whole change to the next level in sigma instead
//              (HeldError::kNextChange: no more rays, conservative), and
//   unbudgeted the same without the budget (a fit holds every level asked for), both run only
//              for a case where some draw's full fit held a sample.
// Per case and way: the median fit time, the mean alpha bias (relative, and in the fits' own
// sigmas, with its standard error over the draws), the bias of one fit of the data without noise
// (in its sigma: the model's and the fit's own, apart from the noise), the share of fits whose
// 2-sigma interval covers the truth, and the mean chi2/dof.
// Environment: MEASURE_NOISE scales the budget's sigma (drawn and stated alike; default 1): a
// bias that is the noise's through the model's curvature grows in sigma as the noise does (of
// order sigma^2, so bias/sigma doubles with the noise), one that is chance does not.
// MEASURE_SEED draws other noise (default 12345); MEASURE_WAYS runs those ways alone ("point",
// "rectangle", "full", "next", "unbudgeted"; the last two only where full held a sample).
// The scene is not the whole instrument (no stages, camera or monitor): the noise is drawn from
// the budget, not measured. Run: scripts/bench.sh measure [repeats] [cases], the second to run
// the cases whose "sample family mm WxH" holds it alone (e.g. antiglare, or 2x2 for antiglare
// under its small rectangle). bench/plot_measure.py charts the tables.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "common/bench_angles.h"
#include "fitting/fitter.h"
#include "fitting/response.h"
#include "sim/scene/scene.h"
#include "sim/truth/ground_truth.h"

using namespace gonio;

namespace {

struct Case {
  std::string sample, family;
  double alpha, thickness_mm, rect_w_px, rect_h_px, view_span_deg, view_step_deg;
};

struct Way {
  const char* name;
  bool response, apertures;
  long max_rays = fitting::FitOptions{}.max_response_rays;
  fitting::HeldError held_error = fitting::HeldError::kTraced;
  bool only_where_held = false;
};

struct Clean {
  fitting::Sample s;
  double value;
};

// The noise-free samples of a case: the scene's rectangle mean in units of k = 1000 e-/s.
std::vector<Clean> Render(const Case& c) {
  sim::BenchGeometry bench;
  bench.sample_thickness_mm = c.thickness_mm;
  sim::SceneOptions o;
  // The scene's cone quadrature, far finer than the narrow lobe needs (20 converge to 1e-6).
  if (c.alpha < 0.1) o.aperture_points = 64;
  const sim::Scene scene(bench, sim::MicrofacetTruth(c.family, c.alpha, 1.51), o);
  auto setup = std::make_shared<fitting::ResponseSetup>();
  setup->thickness_mm = c.thickness_mm;
  setup->rectangle.width = static_cast<int>(c.rect_w_px);
  setup->rectangle.height = static_cast<int>(c.rect_h_px);
  setup->rectangle.x = 256 - setup->rectangle.width / 2;
  setup->rectangle.y = 256 - setup->rectangle.height / 2;
  sim::ImageRegion region;
  region.offset_x = setup->rectangle.x;
  region.offset_y = setup->rectangle.y;
  region.width = setup->rectangle.width;
  region.height = setup->rectangle.height;
  std::vector<Clean> out;
  for (double ti : {0.0, 30.0, 60.0}) {
    const double tt = std::asin(std::sin(ti * M_PI / 180) / 1.51) * 180 / M_PI;
    for (double dv = -c.view_span_deg; dv <= c.view_span_deg + 1e-9; dv += c.view_step_deg) {
      const StageTargets t = StageTargetsFor(ti, -tt + dv);
      const double rate = cv::mean(scene.Render({t.sample_deg, t.arm_deg, 0}, region))[0];
      fitting::Sample s = fitting::SampleFromBenchAngles(ti, 0, -tt + dv, 0, 0, 0);
      s.response = fitting::PointResponse{setup, {t.sample_deg, t.arm_deg, 0}};
      out.push_back({s, rate / 1000});
    }
  }
  return out;
}

// The words of a list separated by spaces or commas.
std::vector<std::string> Words(const std::string& text) {
  std::vector<std::string> out;
  std::string word;
  for (char ch : text + " ") {
    if (ch == ' ' || ch == ',') {
      if (!word.empty()) out.push_back(word);
      word.clear();
    } else {
      word += ch;
    }
  }
  return out;
}

// A way's first word ("next" for "next change"), which MEASURE_WAYS names it by.
std::string FirstWord(const char* name) {
  const std::string s(name);
  return s.substr(0, s.find(' '));
}

// A positive number from the environment, or `fallback` where it is not set; exits naming the
// variable where it is not one.
double EnvNumber(const char* name, double fallback, bool integer) {
  const char* text = std::getenv(name);
  if (text == nullptr || *text == '\0') return fallback;
  char* end = nullptr;
  const double v = std::strtod(text, &end);
  if (*end != '\0' || !std::isfinite(v) || v <= 0 || (integer && v != std::floor(v))) {
    std::fprintf(stderr, "measurement_tradeoff: %s must be a positive %s, not '%s'\n", name,
                 integer ? "integer" : "number", text);
    std::exit(2);
  }
  return v;
}

}  // namespace

int main(int argc, char** argv) {
  const int repeats = argc > 1 ? std::max(1, std::atoi(argv[1])) : 20;
  const std::string only = argc > 2 ? argv[2] : "";
  const double noise = EnvNumber("MEASURE_NOISE", 1, false);
  const auto seed = static_cast<std::uint64_t>(EnvNumber("MEASURE_SEED", 12345, true));
  const char* ways_env = std::getenv("MEASURE_WAYS");
  const std::vector<std::string> only_ways = Words(ways_env != nullptr ? ways_env : "");
  // Figure 12's samples (docs/reference.md), each family with its own width; 1 x 3 mm rectangles
  // (6 x 19 pixels) for the wide lobes, 0.3 mm (2 x 2) and 3 x 10 mm (19 x 62) for antiglare.
  std::vector<Case> cases;
  for (const auto& [name, ab, ag] :
       {std::tuple{"ground", 0.344, 0.394}, std::tuple{"frosted", 0.400, 0.454},
        std::tuple{"etched", 0.493, 0.553}}) {
    cases.push_back({name, "beckmann", ab, 6, 6, 19, 20, 2.5});
    cases.push_back({name, "ggx", ag, 6, 6, 19, 20, 2.5});
  }
  cases.push_back({"ground", "beckmann", 0.344, 3, 6, 19, 20, 2.5});
  cases.push_back({"ground", "beckmann", 0.344, 9, 6, 19, 20, 2.5});
  for (double thickness : {6.0, 3.0, 9.0})
    cases.push_back({"antiglare", "beckmann", 0.023, thickness, 2, 2, 2, 0.25});
  cases.push_back({"antiglare", "ggx", 0.027, 6, 2, 2, 2, 0.25});
  cases.push_back({"antiglare", "beckmann", 0.023, 6, 19, 62, 2, 0.25});

  const Way ways[] = {{"point", false, false},
                      {"rectangle", true, false},
                      {"full", true, true},
                      {"next change", true, true, fitting::FitOptions{}.max_response_rays,
                       fitting::HeldError::kNextChange, true},
                      {"unbudgeted", true, true, 1L << 40, fitting::HeldError::kTraced, true}};
  for (const std::string& w : only_ways)
    if (std::none_of(std::begin(ways), std::end(ways),
                     [&](const Way& x) { return w == FirstWord(x.name); })) {
      std::fprintf(stderr,
                   "measurement_tradeoff: MEASURE_WAYS: no way '%s' (point, rectangle, full, next, "
                   "unbudgeted)\n",
                   w.c_str());
      return 2;
    }
  std::printf(
      "%d noise draws per case (seed %llu, the budget's sigma times %g); alpha bias relative and "
      "in the fits' sigmas (+- its standard error over the draws); coverage: share of 2-sigma "
      "intervals that hold the truth\n\n",
      repeats, static_cast<unsigned long long>(seed), noise);
  std::printf(
      "| sample | family | mm | rect px | fit | median s | bias | bias/sigma | noise-free "
      "bias/sigma | coverage | chi2/dof |\n|---|---|---|---|---|---|---|---|---|---|---|\n");
  for (const Case& c : cases) {
    char key[128];  // what `only` is looked for in: "antiglare beckmann 6 19x62"
    std::snprintf(key, sizeof key, "%s %s %g %gx%g", c.sample.c_str(), c.family.c_str(),
                  c.thickness_mm, c.rect_w_px, c.rect_h_px);
    if (!only.empty() && std::string(key).find(only) == std::string::npos) continue;
    const std::vector<Clean> clean = Render(c);
    bool held = false;  // some draw's full fit held a sample to the budget
    for (const Way& w : ways) {
      if (w.only_where_held && !held) continue;
      if (!only_ways.empty() &&
          std::find(only_ways.begin(), only_ways.end(), FirstWord(w.name)) == only_ways.end())
        continue;
      std::vector<int> held_per_draw;
      std::mt19937_64 rng(seed);
      std::normal_distribution<double> unit(0, 1);
      std::vector<double> seconds;
      double bias = 0, pull = 0, pull2 = 0, chi2 = 0;
      int covered = 0, fitted = 0;
      double noise_free = std::numeric_limits<double>::quiet_NaN();
      // Draw -1 is the data without noise: its bias is the model's and the fit's alone (the
      // floor's choice showed there first: +1.2 sigma with BIC alone on antiglare under 3 x 10 mm).
      for (int r = -1; r < repeats; ++r) {
        std::vector<fitting::Sample> samples;
        for (const Clean& k : clean) {
          fitting::Sample s = k.s;
          // The demo's budget: 0.05 % at the peak (monitor and shot noise), 0.002 absolute in
          // the tails (the stray light's own shot noise and the dark's).
          s.sigma = noise * std::hypot(5e-4 * k.value, 2e-3);
          s.value = r < 0 ? k.value : k.value + s.sigma * unit(rng);
          if (w.response && !w.apertures) {
            auto setup = std::make_shared<fitting::ResponseSetup>(*s.response->setup);
            setup->bench.source_sr = setup->bench.receiver_sr = 0;
            s.response->setup = setup;
          }
          samples.push_back(s);
        }
        fitting::FitOptions o;
        o.model.family = c.family == "ggx" ? fitting::Family::kGgx : fitting::Family::kBeckmann;
        o.floor = fitting::Floor::kAuto;
        o.use_response = w.response;
        o.max_response_rays = w.max_rays;
        o.held_error = w.held_error;
        const auto t0 = std::chrono::steady_clock::now();
        auto f = fitting::Fit(samples, o);
        const bool fitted_ok =
            f.ok() && f->status != fitting::FitStatus::kFailed && f->width.sigma > 0;
        if (r < 0) {
          if (fitted_ok) noise_free = (f->width.value - c.alpha) / f->width.sigma;
          continue;
        }
        seconds.push_back(
            std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
        if (!fitted_ok) continue;
        ++fitted;
        held_per_draw.push_back(f->response.capped);
        bias += (f->width.value - c.alpha) / c.alpha;
        pull += (f->width.value - c.alpha) / f->width.sigma;
        pull2 += std::pow((f->width.value - c.alpha) / f->width.sigma, 2);
        covered += std::abs(f->width.value - c.alpha) < 2 * f->width.sigma;
        chi2 += f->reduced_chi2;
      }
      std::sort(seconds.begin(), seconds.end());
      std::sort(held_per_draw.begin(), held_per_draw.end());
      const int held_median = held_per_draw.empty() ? 0 : held_per_draw[held_per_draw.size() / 2];
      held = held || (!held_per_draw.empty() && held_per_draw.back() > 0);
      const std::string name =
          held_median > 0 ? std::string(w.name) + " (" + std::to_string(held_median) + " held)"
                          : std::string(w.name);
      const double n = std::max(1, fitted);
      // The standard error of the mean pull, from the pulls' own spread.
      const double se =
          fitted > 1 ? std::sqrt(std::max(0.0, pull2 / n - std::pow(pull / n, 2)) * n / (n - 1) / n)
                     : std::numeric_limits<double>::quiet_NaN();
      std::printf(
          "| %s | %s | %g | %gx%g | %s | %.3g | %+.2e | %+.2f ± %.2f | %+.2f | %d/%d | %.3g |\n",
          c.sample.c_str(), c.family.c_str(), c.thickness_mm, c.rect_w_px, c.rect_h_px,
          name.c_str(), seconds[seconds.size() / 2], bias / n, pull / n, se, noise_free, covered,
          repeats, chi2 / n);
      std::fflush(stdout);
    }
  }
  return 0;
}
