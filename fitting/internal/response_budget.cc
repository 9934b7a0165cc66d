#include "fitting/internal/response_budget.h"

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <limits>
#include <memory>
#include <sstream>
#include <tuple>

namespace gonio::fitting::internal {
namespace {

// sum_j w_j f(l_j, v_j) |cos theta_lj| / N at k = 1 (eq. R1), in double.
double ResponseValue(const ModelSpec& m, const Response& r, double width, double eta) {
  double sum = 0;
  for (const ResponseRay& ray : r.rays)
    sum += ray.weight * MeasurementModel(m, ray.l, ray.v, width, 1.0, eta);
  return sum / r.pixels;
}

// The aperture-averaged point model at the nominal pair, at k = 1.
double NominalAperturesValue(const ModelSpec& m, const Response& r, double width, double eta) {
  double sum = 0;
  for (const ResponseRay& ray :
       ApertureCones(r.l0, r.v0, 1.0, r.source_half_angle, r.receiver_half_angle))
    sum += ray.weight * MeasurementModel(m, ray.l, ray.v, width, 1.0, eta);
  return sum;
}

// A sample's response at a level (nullptr past the finest).
Result<const Response*> ResponseAt(ResponseCache::PerSample& c, bool apertures, int level,
                                   const Sample& s, std::size_t i) {
  const auto lv = apertures ? ApertureLevel(level, c.rectangle_level) : RectangleLevel(level);
  if (!lv) return static_cast<const Response*>(nullptr);
  auto& slots = apertures ? c.apertures : c.rectangle;
  // Sized once for every level, so that pointers to computed responses stay valid.
  if (slots.empty()) slots.resize(8);
  if (!slots[level]) {
    auto r = ComputeAtLevel(*s.response->setup, s.response->at, *lv);
    if (!r.ok())
      return Error{r.error().code, Where(s, i) + ": its instrument response: " + r.error().message};
    slots[level] = std::move(r).value();
  }
  return &*slots[level];
}

// The model at k = 1 over a level's rays without holding them (one finer than the budget).
Result<double> StreamedValue(const ModelSpec& m, const Sample& s, std::size_t i,
                             const ResponseLevel& level, double width, double eta) {
  auto v = MeanOverLevel(*s.response->setup, s.response->at, level, [&](const ResponseRay& ray) {
    return MeasurementModel(m, ray.l, ray.v, width, 1.0, eta);
  });
  if (!v.ok())
    return Error{v.error().code, Where(s, i) + ": its instrument response: " + v.error().message};
  return *v;
}

// The step in ln(width) over which a held ratio's slope is taken (forward: one more streamed
// evaluation of each level).
constexpr double kSlopeStep = 1e-3;

// d ln(finer / held) / d ln(width) from the two levels at width and at width e^kSlopeStep (at
// k = 1); 0 where a value is not positive.
double RatioSlope(double held, double finer, double held_up, double finer_up) {
  if (!(held > 0 && finer > 0 && held_up > 0 && finer_up > 0)) return 0;
  return (std::log(finer_up / held_up) - std::log(finer / held)) / kSlopeStep;
}
HeldLevel HeldAt(double held, double finer, double allowed) {
  const double change = std::abs(finer - held);
  if (change <= 0.5 * allowed) return {};
  return {held > 0 ? finer / held : 1.0, change};
}

// From level `from` on, the coarsest level whose value the next finer one changes by at most
// `allowed` / 2 (or the finest): a narrow lobe under a large rectangle needs more rays than a
// wide one. A next level of more than `max_rays` rays is evaluated streamed and not taken: the
// level returned is the last within the budget, and `*held` says by how much it falls short.
Result<int> Refine(const ModelSpec& m, ResponseCache::PerSample& c, bool apertures, int from,
                   const Sample& s, std::size_t i, double width, double k, double eta,
                   double allowed, long max_rays, HeldLevel* held) {
  *held = {};
  auto cur = ResponseAt(c, apertures, from, s, i);
  if (!cur.ok()) return cur.error();
  double value = k * ResponseValue(m, **cur, width, eta);
  for (int level = from;; ++level) {
    const auto lv =
        apertures ? ApertureLevel(level + 1, c.rectangle_level) : RectangleLevel(level + 1);
    if (lv && MaxRaysAtLevel(*s.response->setup, *lv) > max_rays) {
      auto streamed = StreamedValue(m, s, i, *lv, width, eta);
      if (!streamed.ok()) return streamed.error();
      *held = HeldAt(value, k * *streamed, allowed);
      if (held->change > 0) {
        held->streamed = level + 1;
        held->streamed_value = *streamed;
        auto here = ResponseAt(c, apertures, level, s, i);
        if (!here.ok()) return here.error();
        const double up = width * std::exp(kSlopeStep);
        auto streamed_up = StreamedValue(m, s, i, *lv, up, eta);
        if (!streamed_up.ok()) return streamed_up.error();
        held->slope =
            RatioSlope(value / k, *streamed, ResponseValue(m, **here, up, eta), *streamed_up);
      }
      return level;
    }
    auto next = ResponseAt(c, apertures, level + 1, s, i);
    if (!next.ok()) return next.error();
    if (*next == nullptr) return level;
    const double finer = k * ResponseValue(m, **next, width, eta);
    if (std::abs(finer - value) <= 0.5 * allowed) return level;
    value = finer;
  }
}

}  // namespace

Result<int> DecideMode(const ModelSpec& m, const Sample& s, std::size_t i, ResponseCache& cache,
                       double width, double k, double eta, double tolerance, long max_rays) {
  if (!s.response || !s.response->setup) return 0;
  ResponseCache::PerSample& c = cache.of[i];
  c.quadrature = 0;
  c.correction = 1;
  c.rectangle_held = c.apertures_held = {};
  auto coarse = ResponseAt(c, false, 0, s, i);
  if (!coarse.ok()) return coarse.error();
  const Response& r0 = **coarse;
  const double point = k * MeasurementModel(m, r0.l0, r0.v0, width, 1.0, eta);
  const double allowed = tolerance * s.sigma;
  HeldLevel rectangle_held;
  auto level = Refine(m, c, false, c.rectangle_level, s, i, width, k, eta, allowed, max_rays,
                      &rectangle_held);
  if (!level.ok()) return level.error();
  if (*level != c.rectangle_level) {  // the apertures' responses were built on the old rays
    c.apertures.clear();
    c.aperture_level = 0;
  }
  c.rectangle_level = *level;
  const Response& rect = *c.rectangle[c.rectangle_level];
  int mode = std::abs(k * ResponseValue(m, rect, width, eta) - point) > allowed ? 1 : 0;
  // The apertures matter where they change the nominal pair's value, or the rectangle's: under a
  // large rectangle a point in a narrow lobe's far tail takes its value from the pixels nearest
  // the lobe, which the cones reach into while the nominal pair's cones do not (antiglare under
  // 3 x 10 mm, 2 deg off its peak at normal incidence: the apertures add 1.1e-4 at the nominal
  // pair, 0.06 sigma, and 0.019 over the rectangle, 9.5 sigma; judged at the nominal pair alone,
  // the fit modelled it without them and invented a floor three times the true stray light).
  if (!c.aperture_probe) {
    auto probe = ComputeAtLevel(*s.response->setup, s.response->at,
                                *ApertureLevel(0, /*rectangle_level=*/0));
    if (!probe.ok())
      return Error{probe.error().code,
                   Where(s, i) + ": its instrument response: " + probe.error().message};
    c.aperture_probe = std::move(probe).value();
  }
  const bool apertures_matter =
      k * std::abs(NominalAperturesValue(m, r0, width, eta) - point / k) > allowed ||
      k * std::abs(ResponseValue(m, *c.aperture_probe, width, eta) -
                   ResponseValue(m, r0, width, eta)) >
          allowed;
  HeldLevel apertures_held;
  const auto coarsest = ApertureLevel(c.aperture_level, c.rectangle_level);
  if (apertures_matter &&
      MaxRaysAtLevel(*s.response->setup, *coarsest) > max_rays) {  // none fits the budget
    auto streamed = StreamedValue(m, s, i, *coarsest, width, eta);
    if (!streamed.ok()) return streamed.error();
    apertures_held = HeldAt(k * ResponseValue(m, rect, width, eta), k * *streamed, allowed);
    if (apertures_held.change > 0) {
      apertures_held.streamed = c.aperture_level;
      apertures_held.streamed_value = *streamed;
      const double up = width * std::exp(kSlopeStep);
      auto streamed_up = StreamedValue(m, s, i, *coarsest, up, eta);
      if (!streamed_up.ok()) return streamed_up.error();
      apertures_held.slope = RatioSlope(ResponseValue(m, rect, width, eta), *streamed,
                                        ResponseValue(m, rect, up, eta), *streamed_up);
    }
  } else if (apertures_matter) {
    mode = 2;
    auto ap = Refine(m, c, true, c.aperture_level, s, i, width, k, eta, allowed, max_rays,
                     &apertures_held);
    if (!ap.ok()) return ap.error();
    c.aperture_level = *ap;
  }
  // Each held step's ratio corrects the model to the finer value at this estimate, with its slope
  // in the width (the rounds take both again as the fit moves); each change, the error of a model
  // that would not be corrected, stays in sigma until the fit has settled, when TraceHeld
  // replaces it with the corrected model's own error (FitOptions::held_error).
  c.correction = rectangle_held.ratio * apertures_held.ratio;
  c.quadrature = std::hypot(rectangle_held.change, apertures_held.change);
  c.rectangle_held = rectangle_held;
  c.apertures_held = apertures_held;
  c.slope = rectangle_held.slope + apertures_held.slope;  // the ratios multiply
  c.log_width = std::log(width);
  c.apertures_on = c.rectangle_level;
  if (c.quadrature > 0 && mode == 0) mode = 1;  // the correction is the rectangle's
  return mode;
}

SampleModel BuildModel(const Sample& s, std::size_t i, const ResponseCache& cache, int mode,
                       double eta) {
  SampleModel sm;
  sm.mode = mode;
  const ResponseCache::PerSample& c = cache.of[i];
  if (c.IsHeld()) {
    sm.slope = c.slope;
    sm.log_width0 = c.log_width;
  }
  const Response* r = mode == 2   ? &*c.apertures[c.aperture_level]
                      : mode == 1 ? &*c.rectangle[c.rectangle_level]
                                  : nullptr;
  if (r == nullptr) {
    const bool has = !c.rectangle.empty() && c.rectangle[0].has_value();
    sm.g.push_back(has ? PrecomputeGeometry(c.rectangle[0]->l0, c.rectangle[0]->v0, eta)
                       : PrecomputeGeometry(s.light, s.view, eta));
    sm.w.push_back(c.correction);
    return sm;
  }
  sm.g.reserve(r->rays.size());
  for (const ResponseRay& ray : r->rays) {
    sm.g.push_back(PrecomputeGeometry(ray.l, ray.v, eta));
    sm.w.push_back(c.correction * ray.weight / r->pixels);
  }
  return sm;
}

Result<std::vector<int>> DecideModes(std::span<const Sample> samples, const FitOptions& o,
                                     ResponseCache& cache, double width, double k, double eta) {
  std::vector<int> modes(samples.size(), 0);
  if (!o.use_response) return modes;
  for (std::size_t i = 0; i < samples.size(); ++i) {
    auto m = DecideMode(o.model, samples[i], i, cache, width, k, eta, o.response_tolerance,
                        o.max_response_rays);
    if (!m.ok()) return m.error();
    modes[i] = *m;
  }
  return modes;
}

// A held sample's next level is traced (TraceHeld) only up to this many times the budget: past
// it, tracing would cost far more than the fit (a 6 x 16 cone pair over 1 178 pixels is 11 M).
constexpr long kTraceRaysPerBudget = 64;

Result<int> TraceHeld(std::span<const Sample> samples, const FitOptions& o, ResponseCache& cache,
                      double width, double k, double eta) {
  const long limit = o.max_response_rays > std::numeric_limits<long>::max() / kTraceRaysPerBudget
                         ? std::numeric_limits<long>::max()
                         : kTraceRaysPerBudget * o.max_response_rays;
  int traced = 0;
  for (std::size_t i = 0; i < samples.size(); ++i) {
    ResponseCache::PerSample& c = cache.of[i];
    if (!c.IsHeld()) continue;
    const Sample& s = samples[i];
    bool whole = true;
    // The last decision's streamed value where it was taken at this width (the rounds settled
    // there), else streamed again.
    const bool here = std::log(width) == c.log_width;
    // The error of a step streamed at `at` (`value` there at k = 1 when `here`): its change to
    // `finer`, or `change` where untraced.
    auto error = [&](const std::optional<ResponseLevel>& at, double value,
                     const std::optional<ResponseLevel>& finer, double change) -> Result<double> {
      if (!finer) return 0.0;
      if (MaxRaysAtLevel(*s.response->setup, *finer) > limit) {
        whole = false;
        return change;
      }
      if (!here) {
        auto a = StreamedValue(o.model, s, i, *at, width, eta);
        if (!a.ok()) return a.error();
        value = *a;
      }
      auto b = StreamedValue(o.model, s, i, *finer, width, eta);
      if (!b.ok()) return b.error();
      return k * std::abs(*b - value);
    };
    double rect = 0, ap = 0;
    if (const HeldLevel& h = c.rectangle_held; h.streamed >= 0) {
      auto e = error(RectangleLevel(h.streamed), h.streamed_value, RectangleLevel(h.streamed + 1),
                     h.change);
      if (!e.ok()) return e.error();
      rect = *e;
    }
    if (const HeldLevel& h = c.apertures_held; h.streamed >= 0) {
      auto e = error(ApertureLevel(h.streamed, c.apertures_on), h.streamed_value,
                     ApertureLevel(h.streamed + 1, c.apertures_on), h.change);
      if (!e.ok()) return e.error();
      ap = *e;
    }
    c.quadrature = std::hypot(rect, ap);
    traced += whole;
  }
  return traced;
}

std::vector<std::array<int, 3>> DecidedLevels(const std::vector<int>& modes,
                                              const ResponseCache& cache) {
  std::vector<std::array<int, 3>> out;
  out.reserve(modes.size());
  for (std::size_t i = 0; i < modes.size(); ++i)
    out.push_back({modes[i], cache.of[i].rectangle_level, cache.of[i].aperture_level});
  return out;
}

std::pair<int, double> WithQuadrature(std::span<const Sample> samples, const ResponseCache& cache,
                                      std::vector<Sample>& out) {
  if (out.size() != samples.size()) out.assign(samples.begin(), samples.end());
  int capped = 0;
  double largest = 0;
  for (std::size_t i = 0; i < samples.size(); ++i) {
    const double q = cache.of[i].quadrature;
    out[i].sigma = std::hypot(samples[i].sigma, q);
    if (!cache.of[i].IsHeld()) continue;
    ++capped;
    largest = std::max(largest, q / samples[i].sigma);
  }
  return {capped, largest};
}

namespace {

// "1234 rays", "2.35 M rays".
std::string RayCount(long n) {
  std::ostringstream s;
  if (n >= 1000000)
    s << std::setprecision(3) << n / 1e6 << " M";
  else
    s << n;
  return s.str() + " rays";
}

}  // namespace

std::string DescribeModels(const std::vector<int>& modes, std::span<const SampleModel> models,
                           int capped) {
  int rect = 0, ap = 0;
  long rays = 0;
  for (std::size_t i = 0; i < modes.size(); ++i) {
    rect += modes[i] >= 1;
    ap += modes[i] == 2;
    rays += static_cast<long>(models[i].g.size());
  }
  std::ostringstream s;
  s << rect << " of " << modes.size() << " samples over their rectangle, " << ap
    << " with the apertures";
  if (capped > 0) s << ", " << capped << " held to the ray budget";
  s << "; " << RayCount(rays) << " a pass";
  return s.str();
}

void MoveToFitted(const GeometryUse& g, ResponseSetup& c) {
  c.thickness_mm += g.thickness.offset;
  c.bench.axis_x_px -= g.rectangle_x.offset * c.rectangle.binning_h;
  c.bench.axis_y_px -= g.rectangle_y.offset * c.rectangle.binning_v;
}

double ModelAt(const FitSummary& f, const Sample& sample, const StagePosition& at) {
  const double w = f.width.value, k = f.scale.value, eta = f.eta.value;
  if (!sample.response || !sample.response->setup) {
    return MeasurementModel(f.model, sample.light, sample.view, w, k, eta);
  }
  Sample s = sample;
  const StagePosition& was = sample.response->at;
  if (at.sample_deg != was.sample_deg || at.arm_deg != was.arm_deg ||
      at.azimuth_deg != was.azimuth_deg) {  // moved: its nominal pair moves with it
    s.response->at = at;
    std::tie(s.light, s.view) = NominalDirections(at);
  }
  ResponseCache cache(1);
  const FitOptions defaults;
  auto mode = DecideMode(f.model, s, 0, cache, w, k, eta, defaults.response_tolerance,
                         defaults.max_response_rays);
  if (!mode.ok()) return MeasurementModel(f.model, s.light, s.view, w, k, eta);
  const SampleModel sm = BuildModel(s, 0, cache, *mode, eta);
  double value = 0;
  for (std::size_t j = 0; j < sm.g.size(); ++j)
    value += sm.w[j] * MeasurementModel(f.model, sm.g[j].l, sm.g[j].v, w, k, eta);
  return value;
}

double StageSlope(const FitSummary& f, const Sample& s, double StagePosition::*axis) {
  if (!s.response || !s.response->setup) return 0.0;
  const double h = 0.01;  // deg: the slope over a hundredth of a degree
  StagePosition a = s.response->at, b = s.response->at;
  a.*axis += h;
  b.*axis -= h;
  return (ModelAt(f, s, a) - ModelAt(f, s, b)) / (2 * h);
}

std::pair<double, double> StageSlopes(const FitSummary& f, const Sample& s) {
  return {StageSlope(f, s, &StagePosition::sample_deg), StageSlope(f, s, &StagePosition::arm_deg)};
}

}  // namespace gonio::fitting::internal
