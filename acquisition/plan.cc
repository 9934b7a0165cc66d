#include "acquisition/plan.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <sstream>

#include "acquisition/exposure.h"
#include "acquisition/strategy.h"
#include "config/toml_reader.h"
#include "fitting/model.h"

namespace gonio::acquisition {

using config::Reader;

namespace {

// A list of numbers, each in [lo, hi]; errors name the list's line.
Status Numbers(Reader& r, const toml::table& t, const char* key, std::vector<double>* out,
               double lo, double hi) {
  const toml::node* n = t.get(key);
  if (n == nullptr) return OkStatus();
  const toml::array* a = n->as_array();
  if (a == nullptr || a->empty()) return r.Fail(n, std::string("'") + key + "' must be a list");
  out->clear();
  for (const toml::node& v : *a) {
    const auto x = v.value<double>();
    if (!x) return r.Fail(&v, std::string("'") + key + "' must list numbers");
    if (!(*x >= lo && *x <= hi)) {
      std::ostringstream s;
      s << "'" << key << "' value " << *x << " is outside [" << lo << ", " << hi << "]";
      return r.Fail(&v, s.str());
    }
    out->push_back(*x);
  }
  return OkStatus();
}

const devices::AxisSettings* Axis(const std::vector<devices::AxisSettings>& axes,
                                  const std::string& name) {
  for (const auto& a : axes)
    if (a.name == name) return &a;
  return nullptr;
}

// The travel limits an angle must respect, or "" when it fits (arm angles may wrap by 360).
std::string LimitProblem(const devices::AxisSettings* a, double* deg) {
  if (a == nullptr) return "";
  for (double candidate : {*deg, *deg - 360, *deg + 360}) {
    if (candidate >= a->min_deg && candidate <= a->max_deg) {
      *deg = candidate;
      return "";
    }
  }
  std::ostringstream s;
  s << a->name << " at " << *deg << " deg is outside its travel limits [" << a->min_deg << ", "
    << a->max_deg << "]";
  return s.str();
}

}  // namespace

Result<std::vector<Specimen>> LoadSpecimens(const std::string& path) {
  auto parsed = config::ParseTomlFile(path);
  if (!parsed.ok()) return parsed.error();
  Reader r(path);
  GONIO_TRY(r.Keys(*parsed, "top level", {"specimen"}));
  std::vector<Specimen> out;
  const toml::array* list = (*parsed)["specimen"].as_array();
  if (list == nullptr) return r.Fail(nullptr, "no [[specimen]] tables");
  for (const toml::node& item : *list) {
    const toml::table* t = item.as_table();
    if (t == nullptr) return r.Fail(&item, "each [[specimen]] must be a table");
    GONIO_TRY(
        r.Keys(*t, "specimen", {"name", "material", "thickness_mm", "eta", "expected_alpha"}));
    Specimen s;
    if (t->get("name") == nullptr) return r.Fail(&item, "specimen without 'name'");
    GONIO_TRY(r.String(*t, "name", &s.name));
    for (const Specimen& o : out)
      if (o.name == s.name) return r.Fail(t->get("name"), "specimen '" + s.name + "' listed twice");
    GONIO_TRY(r.String(*t, "material", &s.material));
    GONIO_TRY(r.Number(*t, "thickness_mm", &s.thickness_mm, 0.1, 50));
    GONIO_TRY(r.Number(*t, "eta", &s.eta, 1.0, 4.0));
    if (t->get("expected_alpha") != nullptr) {
      double a = 0;
      GONIO_TRY(r.Number(*t, "expected_alpha", &a, 0.001, 5));
      s.expected_alpha = a;
    }
    out.push_back(s);
  }
  return out;
}

namespace {
Result<Plan> Finish(Reader& r, const toml::table& root, const PlanContext& context, Plan p);
Result<Plan> AutoRectangleFrom(Reader& r, const toml::table& rect, const toml::table& root,
                               const PlanContext& context, Plan p);

// [strategy] (plan.h, StrategyPolicy), or strategy = "name" for a kind with its defaults:
// checked after [geometry], whose side it depends on.
Status StrategyFrom(Reader& r, const toml::table& root, Plan* p) {
  const toml::node* node = root.get("strategy");
  if (node == nullptr) return OkStatus();
  StrategyPolicy& s = p->strategy;
  const toml::table* t = node->as_table();
  static const toml::table kNone;
  if (node->is_string()) {
    const std::string name = *node->value<std::string>();
    const auto* known = std::find(kStrategyNames.begin(), kStrategyNames.end(), name);
    if (known == kStrategyNames.end())
      return r.Fail(node, "strategy '" + name + "' is not one of uniform, lobe, adaptive");
    s.kind = static_cast<StrategyKind>(known - kStrategyNames.begin());
    t = &kNone;
  } else if (t == nullptr) {
    return r.Fail(node, "strategy must be a name (\"lobe\") or a [strategy] table");
  }
  GONIO_TRY(r.Keys(*t, "strategy",
                   {"kind", "lobe_fraction", "tail_every", "coarse_every", "coarse_frames",
                    "coarse_max_s", "batch", "target_rel_sigma_alpha", "budget_s"}));
  GONIO_TRY(r.Choice(*t, "kind", &s.kind, kStrategyNames));
  GONIO_TRY(r.Number(*t, "lobe_fraction", &s.lobe_fraction, 1e-6, 0.9));
  GONIO_TRY(r.Integer(*t, "tail_every", &s.tail_every, 1, 1000));
  GONIO_TRY(r.Integer(*t, "coarse_every", &s.coarse_every, 1, 1000));
  GONIO_TRY(r.Integer(*t, "coarse_frames", &s.coarse_frames, 1, 1000));
  GONIO_TRY(r.Number(*t, "coarse_max_s", &s.coarse_max_s, 1e-6, 3600));
  GONIO_TRY(r.Integer(*t, "batch", &s.batch, 1, 1000));
  GONIO_TRY(r.Number(*t, "target_rel_sigma_alpha", &s.target_rel_sigma_alpha, 1e-6, 1));
  GONIO_TRY(r.Number(*t, "budget_s", &s.budget_s, 1, 1e8));
  const toml::node* kind = t->get("kind") != nullptr ? t->get("kind") : node;
  const std::string kind_name = ToString(s.kind);
  if (s.kind != StrategyKind::kUniform && p->side != Side::kTransmission)
    return r.Fail(kind, "strategy '" + kind_name +
                            "' is for transmission plans (its model is the transmitted lobe)");
  if (s.kind == StrategyKind::kLobe && !p->specimen.expected_alpha)
    return r.Fail(kind, "strategy 'lobe' needs the specimen's expected width: give '" +
                            p->specimen.name + "' an expected_alpha in the specimen catalogue");
  if (s.kind == StrategyKind::kAdaptive && t->get("budget_s") == nullptr)
    return r.Fail(kind,
                  "strategy 'adaptive' needs budget_s, the bench seconds it may spend (a target "
                  "alone might never be reached)");
  for (const char* key : {"target_rel_sigma_alpha", "budget_s", "coarse_every", "coarse_frames",
                          "coarse_max_s", "batch"})
    if (s.kind != StrategyKind::kAdaptive && t->get(key) != nullptr)
      return r.Fail(t->get(key), std::string("'") + key +
                                     "' is for kind = \"adaptive\" (this plan's kind is " +
                                     kind_name + ")");
  for (const char* key : {"lobe_fraction", "tail_every"})
    if (s.kind != StrategyKind::kLobe && t->get(key) != nullptr)
      return r.Fail(t->get(key), std::string("'") + key +
                                     "' is for kind = \"lobe\" (this plan's kind is " + kind_name +
                                     ")");
  return OkStatus();
}

Result<Plan> PlanFromTable(const toml::table& root, const std::string& path,
                           const PlanContext& context) {
  Reader r(path);
  Plan p;
  p.path = path;
  GONIO_TRY(
      r.Keys(root, "top level",
             {"sample", "geometry", "exposure", "darks", "rectangle", "strategy", "background"}));

  const toml::node* sample = root.get("sample");
  if (sample == nullptr) return r.Fail(nullptr, "the plan names no 'sample'");
  std::string name;
  GONIO_TRY(r.String(root, "sample", &name));
  bool found = false;
  for (const Specimen& s : context.specimens)
    if (s.name == name) p.specimen = s, found = true;
  if (!found) {
    std::string known;
    for (const Specimen& s : context.specimens) known += (known.empty() ? "" : ", ") + s.name;
    return r.Fail(sample, "unknown sample '" + name + "' (the catalogue has: " + known + ")");
  }

  const toml::table* g = root["geometry"].as_table();
  if (g == nullptr) return r.Fail(nullptr, "the plan has no [geometry]");
  GONIO_TRY(r.Keys(*g, "geometry",
                   {"incidence_deg", "view_from_deg", "view_to_deg", "view_step_deg", "azimuth_deg",
                    "arm_shadow_half_angle_deg", "view_about", "side"}));
  if (g->get("incidence_deg") == nullptr) return r.Fail(g, "[geometry] needs incidence_deg");
  GONIO_TRY(Numbers(r, *g, "incidence_deg", &p.incidence_deg, 0, 89.9));
  p.azimuth_deg = {0};
  GONIO_TRY(Numbers(r, *g, "azimuth_deg", &p.azimuth_deg, -180, 180));
  GONIO_TRY(r.Number(*g, "view_from_deg", &p.view_from_deg, -89.9, 89.9));
  GONIO_TRY(r.Number(*g, "view_to_deg", &p.view_to_deg, -89.9, 89.9));
  GONIO_TRY(r.Number(*g, "view_step_deg", &p.view_step_deg, 0.01, 90));
  GONIO_TRY(r.Number(*g, "arm_shadow_half_angle_deg", &p.arm_shadow_half_angle_deg, 0, 45));
  GONIO_TRY(r.Choice(*g, "side", &p.side, kSideNames));
  GONIO_TRY(r.Choice(*g, "view_about", &p.view_about, kViewAboutNames));
  if ((p.view_about == ViewAbout::kRefracted && p.side != Side::kTransmission) ||
      (p.view_about == ViewAbout::kSpecular && p.side != Side::kReflection))
    return r.Fail(g->get("view_about"),
                  std::string("view_about '") + ToString(p.view_about) + "' is for side = \"" +
                      (p.side == Side::kReflection ? "transmission" : "reflection") +
                      "\" (this plan's side is " + ToString(p.side) + ")");
  if (!(p.view_from_deg <= p.view_to_deg))
    return r.Fail(g->get("view_to_deg") ? g->get("view_to_deg") : g,
                  "view_to_deg must not be below view_from_deg");

  if (const toml::table* e = root["exposure"].as_table()) {
    ExposurePolicy& x = p.exposure;
    GONIO_TRY(r.Keys(*e, "exposure",
                     {"frames", "initial_s", "min_s", "max_s", "saturation", "target", "floor"}));
    std::int64_t frames = x.frames;
    GONIO_TRY(r.Integer(*e, "frames", &frames, 1, 1000));
    x.frames = static_cast<int>(frames);
    GONIO_TRY(r.Number(*e, "min_s", &x.min_s, 1e-6, 3600));
    GONIO_TRY(r.Number(*e, "max_s", &x.max_s, 1e-6, 3600));
    GONIO_TRY(r.Number(*e, "initial_s", &x.initial_s, 1e-6, 3600));
    GONIO_TRY(r.Number(*e, "saturation", &x.saturation, 0.1, 1));
    GONIO_TRY(r.Number(*e, "target", &x.target, 0.01, 1));
    GONIO_TRY(r.Number(*e, "floor", &x.floor, 0, 1));
    if (!(x.min_s <= x.initial_s && x.initial_s <= x.max_s))
      return r.Fail(e, "exposure needs min_s <= initial_s <= max_s");
    if (!(x.floor < x.target && x.target < x.saturation))
      return r.Fail(e, "exposure needs floor < target < saturation");
  } else if (root.get("exposure") != nullptr) {
    return r.Fail(root.get("exposure"), "[exposure] must be a table");
  }
  if (const toml::table* d = root["darks"].as_table()) {
    GONIO_TRY(r.Keys(*d, "darks", {"frames", "max_age_s", "max_temperature_change_c"}));
    std::int64_t frames = p.darks.frames;
    GONIO_TRY(r.Integer(*d, "frames", &frames, 1, 1000));
    p.darks.frames = static_cast<int>(frames);
    GONIO_TRY(r.Number(*d, "max_age_s", &p.darks.max_age_s, 1, 1e6));
    GONIO_TRY(
        r.Number(*d, "max_temperature_change_c", &p.darks.max_temperature_change_c, 0.01, 20));
  }
  GONIO_TRY(StrategyFrom(r, root, &p));
  if (const toml::table* b = root["background"].as_table()) {
    GONIO_TRY(r.Keys(*b, "background", {"measure", "frames"}));
    GONIO_TRY(r.Bool(*b, "measure", &p.background.measure));
    std::int64_t frames = p.background.frames;
    GONIO_TRY(r.Integer(*b, "frames", &frames, 0, 1000));
    if (frames == 1)
      return r.Fail(b->get("frames"),
                    "[background] frames must be 0 (the point's) or at least 2: one frame gives "
                    "no scatter for the background's sigma");
    p.background.frames = static_cast<int>(frames);
  } else if (root.get("background") != nullptr) {
    return r.Fail(root.get("background"), "[background] must be a table");
  }
  const toml::table* rect = root["rectangle"].as_table();
  if (rect == nullptr)
    return r.Fail(nullptr,
                  "the plan has no [rectangle] table (x, y, width, height, or auto = true)");
  if (rect->get("auto") != nullptr) return AutoRectangleFrom(r, *rect, root, context, std::move(p));
  GONIO_TRY(r.Keys(*rect, "rectangle", {"x", "y", "width", "height"}));
  std::int64_t v[4] = {-1, -1, 0, 0};
  const char* keys[4] = {"x", "y", "width", "height"};
  for (int k = 0; k < 4; ++k) {
    if (rect->get(keys[k]) == nullptr)
      return r.Fail(rect, std::string("[rectangle] needs '") + keys[k] + "'");
    GONIO_TRY(r.Integer(*rect, keys[k], &v[k], k < 2 ? 0 : 1, 100000));
  }
  p.rectangle = {static_cast<int>(v[0]), static_cast<int>(v[1]), static_cast<int>(v[2]),
                 static_cast<int>(v[3])};
  if (context.image_width > 0 && (p.rectangle.x + p.rectangle.width > context.image_width ||
                                  p.rectangle.y + p.rectangle.height > context.image_height)) {
    std::ostringstream s;
    s << "the rectangle " << p.rectangle.width << "x" << p.rectangle.height << " at ("
      << p.rectangle.x << ", " << p.rectangle.y << ") is outside the " << context.image_width << "x"
      << context.image_height << " image";
    return r.Fail(rect, s.str());
  }
  return Finish(r, root, context, std::move(p));
}

// The checks every plan passes last, and its text.
Result<Plan> Finish(Reader& r, const toml::table& root, const PlanContext& context, Plan p) {
  if (!context.camera_missing.empty())
    return r.Fail(nullptr,
                  "this instrument cannot measure a run: its camera has " + context.camera_missing);
  p.beam_block = context.beam_block;
  if (p.background.measure && !p.beam_block) {
    const toml::table* b = root["background"].as_table();
    return r.Fail(b != nullptr && b->get("measure") != nullptr ? b->get("measure") : b,
                  "[background] measure = true needs a beam block, and this instrument has none "
                  "(its config has no [beam_block] and no axis \"beam_block\")");
  }
  const toml::table* g = root["geometry"].as_table();
  // Every incidence must be reachable by the sample axis: a plan that cannot do what it says
  // is refused, not quietly thinned (single view angles beyond reach are only skipped).
  const devices::AxisSettings* sample_axis = Axis(context.axes, "sample");
  for (std::size_t k = 0; k < p.incidence_deg.size(); ++k) {
    double deg = p.incidence_deg[k];
    if (std::string why = LimitProblem(sample_axis, &deg); !why.empty())
      return r.Fail(&(*g->get("incidence_deg")->as_array())[k], "incidence: " + why);
  }
  std::ostringstream text;
  text << root;
  p.text = text.str();
  return p;
}

// The worst relative change, over the planned points inside the expected lobe, that averaging
// over the rectangle makes to the expected value (Beckmann at the specimen's expected width).
struct RectangleEffect {
  double worst = 0;
  double theta_l_deg = 0, theta_v_deg = 0;
};
Result<RectangleEffect> EffectOf(const Plan& p, const PlanContext& context, const Rectangle& rc) {
  const fitting::ResponseSetup setup = *ResponseSetupFor(context, p, rc);
  const double alpha = *p.specimen.expected_alpha, eta = p.specimen.eta;
  struct Value {
    double theta_l, theta_v, point, averaged;
  };
  std::vector<Value> values;
  for (const PlannedPoint& pt : ExpandGrid(p, context)) {
    if (pt.skipped) continue;
    auto r = fitting::ComputeResponse(
        setup, {pt.stage.sample_deg, pt.stage.arm_deg, pt.stage.azimuth_deg}, 64);
    if (!r.ok()) return r.error();
    const fitting::ModelSpec beckmann;
    double sum = 0;
    for (const auto& ray : r->rays)
      sum += ray.weight * fitting::MeasurementModel(beckmann, ray.l, ray.v, alpha, 1.0, eta);
    values.push_back({pt.theta_l_deg, pt.theta_v_deg,
                      fitting::MeasurementModel(beckmann, r->l0, r->v0, alpha, 1.0, eta),
                      sum / r->pixels});
  }
  RectangleEffect e;
  for (const Value& v : values) {
    double peak = 0;  // of the point's incidence
    for (const Value& o : values)
      if (o.theta_l == v.theta_l) peak = std::max(peak, o.point);
    if (!(v.point > 0.1 * peak)) continue;
    const double change = std::abs(v.averaged / v.point - 1);
    if (change > e.worst) e = {change, v.theta_l, v.theta_v};
  }
  return e;
}

// [rectangle] auto = true (plan.h, AutoRectangle): rectangles of the given aspect grow from two
// pixels wide around the centre; the last whose effect stays within tolerance * expected_sigma
// is the plan's. Widths and heights are even, so that the rectangle is symmetric about the centre
// pixel corner: an odd one is half a pixel off (0.08 mm on the demo's bench, ~0.04 deg of view,
// 1.6 % on ground glass's flank). The reason names it, its size at the sphere centre and the
// first one too large.
Result<Plan> AutoRectangleFrom(Reader& r, const toml::table& rect, const toml::table& root,
                               const PlanContext& context, Plan p) {
  GONIO_TRY(r.Keys(rect, "rectangle",
                   {"auto", "tolerance", "expected_sigma", "aspect", "centre_x", "centre_y"}));
  bool on = false;
  GONIO_TRY(r.Bool(rect, "auto", &on));
  if (!on)
    return r.Fail(rect.get("auto"),
                  "[rectangle] auto = false: give x, y, width and height instead");
  AutoRectangle a;
  GONIO_TRY(r.Number(rect, "tolerance", &a.tolerance, 0.01, 100));
  GONIO_TRY(r.Number(rect, "expected_sigma", &a.expected_sigma, 1e-6, 0.5));
  GONIO_TRY(r.Number(rect, "aspect", &a.aspect, 0.05, 20));
  for (const char* key : {"centre_x", "centre_y"})
    if (rect.get(key) != nullptr) {
      std::int64_t c = 0;
      GONIO_TRY(r.Integer(rect, key, &c, 0, 100000));
      (key[7] == 'x' ? a.centre_x : a.centre_y) = static_cast<int>(c);
    }
  if (!context.response)
    return r.Fail(&rect,
                  "[rectangle] auto needs the bench's geometry, and the instrument config has no "
                  "[bench] table");
  if (!p.specimen.expected_alpha)
    return r.Fail(&rect, "[rectangle] auto needs the specimen's expected width: give '" +
                             p.specimen.name + "' an expected_alpha in the specimen catalogue");
  if (p.side != Side::kTransmission)
    return r.Fail(&rect,
                  "[rectangle] auto is for transmission plans (the response is traced "
                  "through the hemisphere)");
  const fitting::SensorRectangle& region = context.response->rectangle;
  const int image_w =
      context.image_width > 0
          ? context.image_width
          : (context.response->bench.sensor_width - region.offset_x) / region.binning_h;
  const int image_h =
      context.image_height > 0
          ? context.image_height
          : (context.response->bench.sensor_height - region.offset_y) / region.binning_v;
  const int cx = a.centre_x.value_or(image_w / 2), cy = a.centre_y.value_or(image_h / 2);
  if (cx >= image_w || cy >= image_h)
    return r.Fail(&rect, "[rectangle] centre (" + std::to_string(cx) + ", " + std::to_string(cy) +
                             ") is outside the " + std::to_string(image_w) + "x" +
                             std::to_string(image_h) + " image");
  const double allowed = a.tolerance * a.expected_sigma;
  std::optional<std::pair<Rectangle, RectangleEffect>> best, next;
  for (int w = 2; w <= image_w; w += 2) {
    const int h = std::max(2, 2 * static_cast<int>(std::lround(a.aspect * w / 2)));
    const Rectangle rc{cx - w / 2, cy - h / 2, w, h};
    if (rc.x < 0 || rc.y < 0 || rc.x + w > image_w || rc.y + h > image_h) break;
    auto e = EffectOf(p, context, rc);
    if (!e.ok()) return r.Fail(&rect, "[rectangle] auto: " + e.error().message);
    if (e->worst > allowed && best) {
      next = {rc, *e};
      break;
    }
    best = {rc, *e};
    if (e->worst > allowed) break;  // even one pixel wide is too large: that one, and say so
  }
  if (!best) return r.Fail(&rect, "[rectangle] auto: no rectangle fits the image");
  p.rectangle = best->first;
  p.auto_rectangle = a;
  const double mm = context.response->bench.mm_per_pixel;
  std::ostringstream why;
  why.precision(3);
  why << "rectangle auto: " << p.rectangle.width << " x " << p.rectangle.height << " px at ("
      << p.rectangle.x << ", " << p.rectangle.y << "), "
      << p.rectangle.width * region.binning_h * mm << " x "
      << p.rectangle.height * region.binning_v * mm
      << " mm at the sphere centre: its spread of directions changes the expected lobe (Beckmann "
         "alpha "
      << *p.specimen.expected_alpha << ") by at most " << 100 * best->second.worst
      << " % (at theta_l " << best->second.theta_l_deg << ", theta_v " << best->second.theta_v_deg
      << "), within " << a.tolerance << " x " << 100 * a.expected_sigma << " %";
  if (next)
    why << "; the next, " << next->first.width << " x " << next->first.height << " px, by "
        << 100 * next->second.worst << " %";
  else if (best->second.worst > allowed)
    why << " - NOT within it: even two pixels wide is too large for this lobe";
  p.rectangle_reason = why.str();
  return Finish(r, root, context, std::move(p));
}
}  // namespace

std::optional<fitting::ResponseSetup> ResponseSetupFor(const PlanContext& context, const Plan& plan,
                                                       const Rectangle& rectangle) {
  if (!context.response) return std::nullopt;
  fitting::ResponseSetup s = *context.response;
  s.thickness_mm = plan.specimen.thickness_mm;
  s.rectangle.x = rectangle.x;
  s.rectangle.y = rectangle.y;
  s.rectangle.width = rectangle.width;
  s.rectangle.height = rectangle.height;
  return s;
}

Result<Plan> LoadPlan(const std::string& path, const PlanContext& context) {
  auto parsed = config::ParseTomlFile(path);
  if (!parsed.ok()) return parsed.error();
  return PlanFromTable(*parsed, path, context);
}

Result<Plan> LoadPlanText(std::string_view text, const std::string& name,
                          const PlanContext& context) {
  auto parsed = config::ParseTomlText(text, name);
  if (!parsed.ok()) return parsed.error();
  return PlanFromTable(*parsed, name, context);
}

std::vector<PlannedPoint> ExpandPoints(const Plan& plan, const PlanContext& context) {
  std::vector<PlannedPoint> points = ExpandGrid(plan, context);
  SelectByStrategy(plan, &points);
  return points;
}

std::vector<PlannedPoint> ExpandGrid(const Plan& plan, const PlanContext& context) {
  std::vector<double> views;
  const int n = static_cast<int>(
      std::floor((plan.view_to_deg - plan.view_from_deg) / plan.view_step_deg + 1e-9));
  for (int k = 0; k <= n; ++k) views.push_back(plan.view_from_deg + k * plan.view_step_deg);
  std::vector<PlannedPoint> out;
  bool forward = true;
  for (double phi : plan.azimuth_deg) {
    for (double theta_l : plan.incidence_deg) {
      for (std::size_t j = 0; j < views.size(); ++j) {
        double theta_v = views[forward ? j : views.size() - 1 - j];
        if (plan.view_about == ViewAbout::kRefracted) {  // Snell: sin(theta_t) = sin(theta_l) / eta
          const double theta_t = std::asin(std::sin(theta_l * M_PI / 180) / plan.specimen.eta);
          theta_v += -theta_t * 180 / M_PI;
        } else if (plan.view_about == ViewAbout::kSpecular) {
          theta_v += theta_l;
        }
        PlannedPoint p;
        p.index = static_cast<int>(out.size());
        p.theta_l_deg = theta_l;
        p.theta_v_deg = theta_v;
        p.phi_deg = phi;
        p.reflection = plan.side == Side::kReflection;
        p.stage = p.reflection ? StageTargetsForReflection(theta_l, theta_v, phi)
                               : StageTargetsFor(theta_l, theta_v, phi);
        std::string why;
        if (std::abs(theta_v) >= 89.9) why = "theta_v beyond grazing";
        if (why.empty()) why = LimitProblem(Axis(context.axes, "arm"), &p.stage.arm_deg);
        if (why.empty()) why = LimitProblem(Axis(context.axes, "sample"), &p.stage.sample_deg);
        if (why.empty() && Axis(context.axes, "azimuth") != nullptr)
          why = LimitProblem(Axis(context.axes, "azimuth"), &p.stage.azimuth_deg);
        if (why.empty() && ArmInSourceBeam(p.stage.arm_deg, plan.arm_shadow_half_angle_deg))
          why = "the detector arm would block the source beam";
        if (why.empty() && phi != 0 && Axis(context.axes, "azimuth") == nullptr)
          why = "azimuth " + std::to_string(phi) + " deg needs an azimuth axis";
        p.skipped = !why.empty();
        p.reason = why;
        out.push_back(p);
      }
      forward = !forward;  // serpentine: the next incidence sweeps back
    }
  }
  return out;
}

namespace {

// A trapezoid: distance / speed + speed / acceleration; 0 for an axis not in `axes`.
double AxisMoveSeconds(const std::vector<devices::AxisSettings>& axes, const std::string& name,
                       double a0, double a1) {
  const devices::AxisSettings* a = Axis(axes, name);
  if (a == nullptr || a0 == a1) return 0.0;
  const double d = std::abs(a1 - a0), v = a->speed_deg_s, acc = a->acceleration_deg_s2;
  return d >= v * v / acc ? d / v + v / acc : 2 * std::sqrt(d / acc);
}

}  // namespace

double MoveSeconds(const std::vector<devices::AxisSettings>& axes, const StageTargets& from,
                   const StageTargets& to) {
  // The axes move together: the slowest decides.
  return std::max({AxisMoveSeconds(axes, "sample", from.sample_deg, to.sample_deg),
                   AxisMoveSeconds(axes, "arm", from.arm_deg, to.arm_deg),
                   AxisMoveSeconds(axes, "azimuth", from.azimuth_deg, to.azimuth_deg)});
}

int BackgroundFrames(const Plan& plan) {
  if (!plan.background.measure) return 0;
  return std::max(2, plan.background.frames > 0 ? plan.background.frames : plan.exposure.frames);
}

std::optional<ExposureHistory::Entry> ExposureHistory::Near(const PlannedPoint& p) const {
  std::optional<Entry> best;
  for (const Entry& e : entries) {
    if (e.reflection != p.reflection || std::abs(e.theta_l_deg - p.theta_l_deg) > 1 ||
        std::abs(e.phi_deg - p.phi_deg) > 1)
      continue;
    if (!best ||
        std::abs(e.theta_v_deg - p.theta_v_deg) < std::abs(best->theta_v_deg - p.theta_v_deg))
      best = e;
  }
  return best;
}

double EstimateSeconds(const Plan& plan, const std::vector<PlannedPoint>& points,
                       const std::vector<devices::AxisSettings>& axes, double typical_exposure_s,
                       const ExposureHistory* history, const LobeForecast* forecast,
                       EstimateParts* parts) {
  EstimateParts e;
  double clock = 0;  // bench time so far, for the darks' age
  auto expose = [&](double t, int n) {
    e.exposure_s += n * t;
    clock += n * t;
  };
  std::map<double, double> darks;  // exposure -> when its dark set was taken
  auto dark_for = [&](double t) {
    auto it = std::find_if(darks.begin(), darks.end(),
                           [&](const auto& d) { return SameExposure(d.first, t); });
    if (it != darks.end() && clock - it->second <= plan.darks.max_age_s) return;
    const int frames = std::max(2, plan.darks.frames);  // the engine takes at least 2
    expose(t, frames);
    e.dark_exposure_s += frames * t;
    darks[it != darks.end() ? it->first : t] = clock;
  };
  StageTargets at{0, 180, 0};
  double last_s = 0;  // the engine starts each point at the previous point's exposure
  // A measured background: its frames at the point's exposure, and the flag's move into the beam
  // (its move out goes with the next point's).
  const int background_frames = BackgroundFrames(plan);
  const double flag_s = background_frames > 0 && plan.beam_block
                            ? AxisMoveSeconds(axes, "beam_block", plan.beam_block->open_deg,
                                              plan.beam_block->blocked_deg)
                            : 0.0;
  for (const PlannedPoint& p : points) {
    if (p.skipped) continue;
    e.motion_s += flag_s;
    clock += flag_s;
    const double move = MoveSeconds(axes, at, p.stage);
    e.motion_s += move;
    clock += move;
    at = p.stage;
    ExposureHistory::Entry seen{};  // (a plain value: GCC 12 misreads an optional here)
    bool have_seen = false;
    if (history != nullptr)
      if (const auto near = history->Near(p)) seen = *near, have_seen = true;
    // Forecast: every transmission point, those the lobe does not reach too (rate 0: the engine
    // ranges them up to max_s).
    const bool forecast_it = forecast != nullptr && !have_seen && !p.reflection;
    if (have_seen) {
      // The last ranging try is the first averaged frame; earlier tries priced at its exposure.
      ++e.from_history;
      e.ranging_frames += seen.ranging_tries - 1;
      expose(seen.exposure_s, plan.exposure.frames + seen.ranging_tries - 1 + background_frames);
      dark_for(seen.exposure_s);
      last_s = seen.exposure_s;
    } else if (forecast_it) {
      // The engine's ranging, played on the forecast.
      ++e.from_forecast;
      const double rate = forecast->Rate(p);
      const ExposurePolicy& x = plan.exposure;
      const double range = forecast->linear_limit_adu - forecast->bench.dark_adu;
      double t = std::clamp(last_s > 0 ? last_s : OnLadder(x.initial_s), x.min_s, x.max_s);
      for (int tries = 1;; ++tries) {
        expose(t, 1);
        dark_for(t);
        const ExposureJudgement j = JudgeExposure(x, t, rate * t, range);
        if (tries >= forecast->max_ranging_tries || (!j.too_bright && !j.too_dim) ||
            (j.too_bright && t <= x.min_s))
          break;
        ++e.ranging_frames;
        t = j.next_s;
      }
      expose(t, plan.exposure.frames - 1 + background_frames);
      last_s = t;
    } else {
      ++e.from_typical;
      ++e.ranging_frames;
      // +1: the ranging frame
      expose(typical_exposure_s, plan.exposure.frames + 1 + background_frames);
    }
  }
  if (parts != nullptr) *parts = e;
  return e.motion_s + e.exposure_s;
}

}  // namespace gonio::acquisition
