#include "daemon/schedule/schedule.h"

#include <algorithm>
#include <ctime>

#include "config/toml_reader.h"
#include "fitting/model.h"

namespace gonio::daemon {

std::optional<std::int64_t> ParseLocalTime(const std::string& iso) {
  for (const char* format : {"%Y-%m-%dT%H:%M:%S", "%Y-%m-%dT%H:%M"}) {
    std::tm tm{};
    const char* end = ::strptime(iso.c_str(), format, &tm);
    if (end != nullptr && *end == '\0') {
      tm.tm_isdst = -1;
      const std::time_t t = std::mktime(&tm);
      if (t != -1) return static_cast<std::int64_t>(t);
    }
  }
  return std::nullopt;
}

Result<std::vector<PlanReference>> PlanReferences(std::string_view text, const std::string& name) {
  auto parsed = config::ParseTomlText(text, name);
  if (!parsed.ok()) return parsed.error();
  std::vector<PlanReference> out;
  if (const toml::array* jobs = (*parsed)["job"].as_array()) {
    for (const toml::node& n : *jobs) {
      const toml::table* t = n.as_table();
      const toml::node* p = t ? t->get("plan") : nullptr;
      const auto plan = p ? p->value<std::string>() : std::nullopt;
      if (!plan) continue;  // ParseSchedule names what is wrong with it
      if (std::none_of(out.begin(), out.end(), [&](const auto& r) { return r.name == *plan; }))
        out.push_back({*plan, static_cast<int>(p->source().begin.line)});
    }
  }
  return out;
}

double Schedule::EstimateSeconds() const {
  double s = 0;
  for (const auto& j : jobs) s += j.repeat * j.estimate_s;
  return s;
}

Result<Schedule> ParseSchedule(std::string_view text, const std::string& name,
                               const std::map<std::string, std::string>& plans,
                               const acquisition::PlanContext& context,
                               const EstimateBasis& basis) {
  auto parsed = config::ParseTomlText(text, name);
  if (!parsed.ok()) return parsed.error();
  const toml::table& root = *parsed;
  config::Reader r(name);
  GONIO_TRY(r.Keys(root, "top level", {"job"}));
  const toml::array* jobs = root["job"].as_array();
  if (jobs == nullptr || jobs->empty())
    return r.Fail(root.get("job"), "the schedule has no [[job]]");
  Schedule out;
  out.name = name;
  std::map<std::string, acquisition::RunEstimate> estimates;  // by plan name
  for (const toml::node& node : *jobs) {
    const toml::table* t = node.as_table();
    if (t == nullptr) return r.Fail(&node, "'job' must be a table: [[job]]");
    GONIO_TRY(r.Keys(*t, "job", {"plan", "repeat", "start_at", "fit", "cooler"}));
    ScheduleEntry e;
    e.line = static_cast<int>(node.source().begin.line);
    if (t->get("plan") == nullptr) return r.Fail(&node, "this [[job]] names no 'plan'");
    GONIO_TRY(r.String(*t, "plan", &e.plan_name));
    auto it = plans.find(e.plan_name);
    if (it == plans.end())
      return r.Fail(t->get("plan"), "plan '" + e.plan_name + "' was not sent with the schedule");
    e.plan_text = it->second;
    auto plan = acquisition::LoadPlanText(e.plan_text, e.plan_name, context);
    if (!plan.ok()) return plan.error();
    const auto points = acquisition::ExpandPoints(*plan, context);
    for (const auto& p : points) (p.skipped ? e.skipped : e.points) += 1;
    // Once per plan: an adaptive plan's estimate simulates its runs (seconds), and a schedule may
    // name a plan in many jobs.
    auto priced = estimates.find(e.plan_name);
    if (priced == estimates.end()) {
      const auto seen = basis.history ? basis.history(plan->specimen.name) : std::nullopt;
      priced = estimates
                   .emplace(e.plan_name,
                            acquisition::EstimateOn(
                                *plan, points, context.axes, seen ? &*seen : nullptr,
                                basis.throughput, basis.linear_limit_adu, basis.max_ranging_tries))
                   .first;
    }
    e.estimate_s = priced->second.total_s;
    e.estimate_basis = priced->second.basis;
    e.estimate_priced = priced->second.priced;
    GONIO_TRY(r.Integer(*t, "repeat", &e.repeat, 1, 1000));
    if (const toml::node* s = t->get("start_at")) {
      std::string iso;
      GONIO_TRY(r.String(*t, "start_at", &iso));
      e.start_at_unix = ParseLocalTime(iso);
      if (!e.start_at_unix)
        return r.Fail(s, "'start_at' = \"" + iso + "\" is not a local time like 2026-11-24T02:00");
    }
    if (const toml::node* f = t->get("fit")) {
      const toml::array* models = f->as_array();
      if (models == nullptr) return r.Fail(f, "'fit' must be a list of model names");
      for (const toml::node& m : *models) {
        const auto v = m.value<std::string>();
        if (!v || !fitting::ParseFamily(*v))
          return r.Fail(&m, "unknown model in 'fit' (known: beckmann, ggx, phong, sun2008)");
        // Refused here, not hours later when the run is fitted.
        if (*v == "sun2008" && plan->side == acquisition::Side::kReflection)
          return r.Fail(&m, "'fit' names sun2008, a transmission model, but plan '" + e.plan_name +
                                "' measures reflection");
        e.fit.push_back(*v);
      }
    }
    if (const toml::node* c = t->get("cooler")) {
      const toml::table* ct = c->as_table();
      if (ct == nullptr) return r.Fail(c, "'cooler' must be a table: [job.cooler]");
      GONIO_TRY(r.Keys(*ct, "job.cooler", {"setpoint_c", "tolerance_c", "hold_s", "timeout_s"}));
      if (ct->get("setpoint_c") == nullptr) return r.Fail(c, "[job.cooler] needs 'setpoint_c'");
      CoolerWait w;
      GONIO_TRY(r.Number(*ct, "setpoint_c", &w.setpoint_c, -100, 40));
      GONIO_TRY(r.Number(*ct, "tolerance_c", &w.tolerance_c, 0.01, 20));
      GONIO_TRY(r.Number(*ct, "hold_s", &w.hold_s, 0, 86400));
      GONIO_TRY(r.Number(*ct, "timeout_s", &w.timeout_s, 1, 86400));
      e.cooler = w;
    }
    out.jobs.push_back(std::move(e));
  }
  return out;
}

}  // namespace gonio::daemon
