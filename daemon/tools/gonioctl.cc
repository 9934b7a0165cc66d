// gonioctl: the operator's command line, talking to goniod's API (docs/api.md).
//
//   gonioctl [--url http://127.0.0.1:8470] [--token-file F] [--json] [-v] COMMAND
//     status                     state, current job, progress
//     submit PLAN [--repeat N] [--wait] [--dry-run]
//                                queue a plan file (validated by the daemon), or only price it
//     schedule FILE [--dry-run] [--wait]  queue a schedule's jobs (or list them, with timings)
//     fit RUN [--model beckmann,ggx]      fit a stored run; the results are stored with it
//     fits RUN                   the fits stored with a run (a schedule's, or fit's)
//     plot RUN --out DIR         the run's CSV, gonio-fit's curves and a PNG like Walter 2007's
//                                Figures 10-11 (measured BTDF*cos with the fits; empirical D)
//     queue                      jobs: current, queued, finished
//     cancel JOB | move JOB POS  a queued job
//     pause | resume | abort     run control
//     runs | show RUN            stored runs; one run with its measurements
//     throughput                 the bench's measured throughput, as the config's [throughput]
//     export RUN --out F.csv     the fitter's CSV
//     wait [--timeout S]         follow progress until the daemon is idle (a progress bar)
//
// Exit codes (for scripts): 0 done; 1 the daemon cannot be reached or failed (5xx); 2 the request
// was refused (4xx: bad input, unknown id, wrong token, not now); 3 wait ended with a run aborted,
// failed, suspended past its limit (fault), or the timeout.
#include <httplib.h>

#include <CLI/CLI.hpp>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <iostream>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>
#include <thread>

#include <sys/wait.h>
#include <unistd.h>

#include "common/progress_line.h"
#include "common/text.h"
#include "common/wrap.h"
#include "daemon/schedule/schedule.h"

namespace {

using nlohmann::json;

struct Reply {
  int status = 0;  // 0: no connection
  std::string body;
  json j;
};

class Api {
 public:
  Api(const std::string& url, std::string token) : cli_(url), token_(std::move(token)) {
    cli_.set_connection_timeout(5);
    cli_.set_read_timeout(kReadTimeoutS);
  }
  Reply Get(const std::string& path) { return Wrap(cli_.Get(path)); }
  Reply Post(const std::string& path, const json& body) {
    return Wrap(cli_.Post(path, Headers(), body.dump(), "application/json"));
  }
  // A request the daemon answers only when its work is done (a fit with the instrument response
  // takes seconds natively, minutes on a large run or a slow machine): a longer wait for it.
  Reply PostAndWait(const std::string& path, const json& body, int seconds) {
    cli_.set_read_timeout(seconds);
    Reply r = Post(path, body);
    cli_.set_read_timeout(kReadTimeoutS);
    if (r.status == 0 && r.body == httplib::to_string(httplib::Error::Read))
      r.body = "no answer within " + std::to_string(seconds) + " s";
    return r;
  }
  static constexpr int kReadTimeoutS = 30;
  Reply Delete(const std::string& path) { return Wrap(cli_.Delete(path, Headers())); }

 private:
  httplib::Headers Headers() const { return {{"Authorization", "Bearer " + token_}}; }
  static Reply Wrap(const httplib::Result& r) {
    Reply out;
    if (!r) {
      out.body = httplib::to_string(r.error());
      return out;
    }
    out.status = r->status;
    out.body = r->body;
    out.j = json::parse(r->body, nullptr, false);
    return out;
  }
  httplib::Client cli_;
  std::string token_;
};

// Prints an error reply and returns the exit code for it.
int Failed(const Reply& r, const std::string& url) {
  if (r.status == 0) {
    std::cerr << "gonioctl: cannot reach goniod at " << url << ": " << r.body << "\n";
    return 1;
  }
  std::string msg = r.body;
  if (r.j.is_object() && r.j.contains("error")) msg = r.j["error"].value("message", r.body);
  std::cerr << "gonioctl: " << r.status << ": " << msg << "\n";
  return r.status >= 500 ? 1 : 2;
}

// Runs a program with arguments (no shell) and returns its exit status, or -1 if it cannot run.
// The first candidate that exists, else the last (whose absence the caller reports).
std::string Companion(const std::vector<std::filesystem::path>& candidates) {
  for (const auto& c : candidates)
    if (std::filesystem::is_regular_file(c)) return std::filesystem::weakly_canonical(c).string();
  return candidates.back().string();
}

int RunProgram(const std::vector<std::string>& argv) {
  const pid_t pid = ::fork();
  if (pid < 0) return -1;
  if (pid == 0) {
    std::vector<char*> args;
    for (const auto& a : argv) args.push_back(const_cast<char*>(a.c_str()));
    args.push_back(nullptr);
    ::execv(args[0], args.data());
    std::perror(args[0]);
    ::_exit(127);
  }
  int status = 0;
  if (::waitpid(pid, &status, 0) < 0) return -1;
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

std::string Duration(double s) {
  std::ostringstream o;
  if (s < 120)
    o << static_cast<int>(s) << " s";
  else if (s < 7200)
    o << std::fixed << std::setprecision(1) << s / 60 << " min";
  else
    o << std::fixed << std::setprecision(1) << s / 3600 << " h";
  return o.str();
}

void PrintStatus(const json& s) {
  std::cout << "state: " << s.value("state", "?");
  if (!s.value("reason", std::string()).empty())
    std::cout << " (" << s["reason"].get<std::string>() << ")";
  std::cout << "\n";
  if (s["job"].is_object()) {
    const json& j = s["job"];
    std::cout << "job " << j["id"] << " '" << j.value("name", "") << "': " << j.value("state", "");
    if (!j["run"].is_null()) std::cout << ", run " << j["run"];
    std::cout << "\n";
  }
  if (s["progress"].is_object()) {
    const json& p = s["progress"];
    std::cout << "progress: " << p["done"] << "/" << p["total"] << " points, at theta_l "
              << p["theta_l_deg"] << " theta_v " << p["theta_v_deg"] << ", last " << p["value"]
              << " +- " << p["sigma"] << ", ETA " << Duration(p.value("eta_s", 0.0)) << "\n";
  }
  std::cout << "queued: " << s.value("queued", 0) << "\n";
}

// A run's progress: on a terminal a bar redrawn in place; in a log (not a terminal) a line when
// the state changes and at the run's half, so that a log reads as its stages.
class ProgressBar {
 public:
  void Show(int done, int total, double eta_s, const std::string& state) {
    std::ostringstream text;
    if (line_.terminal()) {
      const int width = 40;
      const int filled = total > 0 ? std::clamp(done * width / total, 0, width) : 0;
      text << "[" << std::string(filled, '#') << std::string(width - filled, '.') << "] ";
    }
    text << done << "/" << total << " points  " << state << "  ETA " << Duration(eta_s);
    const int half = total > 0 ? done * 2 / total : 0;
    if (line_.terminal())
      line_.Stage(text.str());
    else if (half != half_ || state != state_)
      line_.Stage(text.str());
    half_ = half;
    state_ = state;
  }
  void Done() { line_.Done(); }

 private:
  gonio::ProgressLine line_{std::cerr, ::isatty(2) != 0};
  int half_ = -1;
  std::string state_;
};

// What every subcommand shares: the API, how to print its replies, and waiting for the daemon.
class Ctl {
 public:
  Ctl(std::string url, const std::string& token, bool as_json, bool explain, double timeout_s)
      : url_(std::move(url)),
        api_(url_, token),
        as_json_(as_json),
        explain_(explain),
        timeout_s_(timeout_s) {}

  Api& api() { return api_; }
  const std::string& url() const { return url_; }
  bool as_json() const { return as_json_; }
  bool explain() const { return explain_; }

  // A reply as JSON (--json) or through `human`; an error reply's message and exit code.
  int Print(const Reply& r, const std::function<void(const json&)>& human) const {
    if (r.status < 200 || r.status >= 300) return Failed(r, url_);
    if (as_json_)
      std::cout << r.j.dump(2) << "\n";
    else
      human(r.j);
    return 0;
  }

  // Follows progress until the daemon is idle; the last job's outcome is the exit code.
  int WaitIdle() {
    const auto t0 = std::chrono::steady_clock::now();
    std::int64_t last_run = 0;
    while (true) {
      Reply r = api_.Get("/api/v1/status");
      if (r.status != 200) return Failed(r, url_);
      const std::string state = r.j.value("state", "");
      if (r.j["job"].is_object() && !r.j["job"]["run"].is_null())
        last_run = r.j["job"]["run"].get<std::int64_t>();
      if (r.j["progress"].is_object()) {
        const json& p = r.j["progress"];
        if (!as_json_)
          bar_.Show(p.value("done", 0), p.value("total", 0), p.value("eta_s", 0.0), state);
      }
      if (state == "idle" && r.j.value("queued", 0) == 0) return Outcome(state, last_run);
      if (state == "fault") {
        bar_.Done();
        std::cerr << "gonioctl: fault: " << r.j.value("reason", "") << "\n";
        return 3;
      }
      if (timeout_s_ > 0 &&
          std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() >
              timeout_s_) {
        bar_.Done();
        std::cerr << "gonioctl: still " << state << " after " << timeout_s_ << " s\n";
        return 3;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(500));
    }
  }

 private:
  int Outcome(const std::string& state, std::int64_t last_run) {
    bar_.Done();
    Reply jobs = api_.Get("/api/v1/jobs");
    std::string outcome = "done";
    if (jobs.status == 200)
      for (const json& j : jobs.j["jobs"])
        if (!j["run"].is_null() && j["run"].get<std::int64_t>() == last_run)
          outcome = j.value("state", "done");
    if (as_json_)
      std::cout << json{{"state", state}, {"run", last_run}, {"outcome", outcome}}.dump() << "\n";
    else
      std::cout << "idle; last run " << last_run << ": " << outcome << "\n";
    return outcome == "done" ? 0 : 3;
  }

  std::string url_;
  ProgressBar bar_;
  Api api_;
  bool as_json_;
  bool explain_;
  double timeout_s_;
};

// A file's text for a request body: read as bytes and refused (path:line:column) when it is not
// UTF-8, before any JSON is built from it.
std::optional<std::string> ReadText(const std::string& path) {
  auto text = gonio::ReadUtf8File(path);
  if (!text.ok()) {
    std::cerr << "gonioctl: " << text.error().message << "\n";
    return std::nullopt;
  }
  return std::move(text).value();
}

// Whether a dry run prices one run only (one entry, once): its total says nothing more.
bool OneRun(const json& j) { return j["jobs"].size() == 1 && j["jobs"][0].value("repeat", 1) == 1; }

// A dry run's total, saying which entries' exposures it leaves out.
void PrintTotal(const json& j, const std::string& also) {
  int unpriced = 0;
  for (const json& x : j["jobs"]) unpriced += x.value("estimate_priced", true) ? 0 : 1;
  std::string note = unpriced > 0 ? std::to_string(unpriced) + " line(s) motion only" : "";
  if (!also.empty()) note += (note.empty() ? "" : "; ") + also;
  std::cout << "total: about " << Duration(j.value("estimate_s", 0.0))
            << " of bench time for motion and exposure" << (note.empty() ? "" : " (" + note + ")")
            << "\n";
}

void PrintScheduleEntry(const json& x) {
  std::ostringstream line;
  line << "line " << x["line"] << ": " << x["repeat"] << " x " << x.value("plan", "") << ": "
       << x["points"] << " points";
  if (x.value("skipped", 0) > 0) line << " (" << x["skipped"] << " skipped)";
  if (x.value("estimate_priced", true))
    line << ", about " << Duration(x.value("estimate_s", 0.0)) << " each (from "
         << x.value("estimate_basis", std::string("?")) << ")";
  else  // the basis says why, and that the time is the motion's
    line << ", " << x.value("estimate_basis", std::string("?")) << ", about "
         << Duration(x.value("estimate_s", 0.0));
  if (!x["start_at_unix"].is_null()) {
    const std::time_t t = x["start_at_unix"].get<std::int64_t>();
    char b[32];
    std::strftime(b, sizeof b, "%F %R", std::localtime(&t));
    line << "; not before " << b;
  }
  if (!x["cooler_setpoint_c"].is_null())
    line << "; first cool to " << x["cooler_setpoint_c"].get<double>() << " C";
  if (!x["fit"].empty()) line << "; fit " << x["fit"].dump() << " after each";
  std::cout << gonio::Wrap(line.str(), 100, "  ", "    ");
}

// A plan's dry run: priced by the daemon as a schedule of one job (the same validation and
// estimate as a schedule's dry run), nothing queued.
int DryRunPlan(Ctl& ctl, const std::string& plan_path, const std::string& plan, int repeat) {
  // The plan's name as a TOML basic string: JSON's escapes are TOML's.
  const std::string schedule =
      "[[job]]\nplan = " + json(plan_path).dump() + "\nrepeat = " + std::to_string(repeat) + "\n";
  const json body{{"name", plan_path},
                  {"schedule", schedule},
                  {"plans", {{plan_path, plan}}},
                  {"dry_run", true}};
  return ctl.Print(ctl.api().Post("/api/v1/schedules", body), [&](const json& j) {
    std::cout << "plan " << plan_path << " (dry run; nothing queued):\n";
    for (const json& x : j["jobs"]) PrintScheduleEntry(x);
    if (!OneRun(j)) PrintTotal(j, "");
  });
}

int Submit(Ctl& ctl, const std::string& plan_path, int repeat, bool wait_after, bool dry_run) {
  const auto plan = ReadText(plan_path);
  if (!plan) return 2;
  if (dry_run) return DryRunPlan(ctl, plan_path, *plan, repeat);
  const json body{{"name", plan_path}, {"plan", *plan}, {"repeat", repeat}};
  const int rc = ctl.Print(ctl.api().Post("/api/v1/jobs", body), [](const json& j) {
    auto one = [](const json& x) {
      std::cout << "job " << x["id"] << " queued: " << x.value("name", "") << "\n";
    };
    if (j.contains("jobs"))
      for (const json& x : j["jobs"]) one(x);
    else
      one(j);
  });
  if (rc != 0 || !wait_after) return rc;
  return ctl.WaitIdle();
}

int Schedule(Ctl& ctl, const std::string& schedule_path, bool dry_run, bool wait_after) {
  // The daemon validates everything; here only the plan files are found (by the schedule
  // module's own reading of it) and read, relative to the schedule, with the schedule's line
  // when one is missing.
  const auto read = ReadText(schedule_path);
  if (!read) return 2;
  const std::string& text = *read;
  auto refs = gonio::daemon::PlanReferences(text, schedule_path);
  if (!refs.ok()) {
    std::cerr << "gonioctl: " << refs.error().message << "\n";
    return 2;
  }
  json plans = json::object();
  for (const auto& ref : *refs) {
    const auto file = std::filesystem::path(schedule_path).parent_path() / ref.name;
    std::ifstream pf(file);
    if (!pf) {
      std::cerr << "gonioctl: " << schedule_path << ":" << ref.line << ": plan '" << ref.name
                << "': cannot read " << file.string() << "\n";
      return 2;
    }
    const auto plan = ReadText(file.string());
    if (!plan) return 2;
    plans[ref.name] = *plan;
  }
  const json body{
      {"name", schedule_path}, {"schedule", text}, {"plans", plans}, {"dry_run", dry_run}};
  const int rc = ctl.Print(ctl.api().Post("/api/v1/schedules", body), [&](const json& j) {
    if (dry_run) {
      std::cout << "schedule " << schedule_path << " (dry run; nothing queued):\n";
      for (const json& x : j["jobs"]) PrintScheduleEntry(x);
      if (!OneRun(j)) PrintTotal(j, "start times and cooling not counted");
    } else {
      for (const json& x : j["jobs"])
        std::cout << "job " << x["id"] << " queued: " << x.value("name", "") << "\n";
    }
  });
  if (rc != 0 || !wait_after || dry_run) return rc;
  return ctl.WaitIdle();
}

// A number with `digits` significant digits.
std::string Sig(double v, int digits) {
  std::ostringstream o;
  o << std::setprecision(digits) << v;
  return o.str();
}

// A stored fit in a line: the width with two digits of its sigma, chi2/dof and the status; with
// `explain`, how the geometry entered it (fitting/fitter.h, GeometryUse), wrapped.
void PrintFit(const json& f, bool explain) {
  const double w = f["width"].value("sigma", 0.0);
  const int digits = w > 0 && std::isfinite(w)
                         ? std::clamp(1 - static_cast<int>(std::floor(std::log10(w))), 0, 12)
                         : 4;
  std::ostringstream width;
  width << std::fixed << std::setprecision(digits) << f["width"].value("value", 0.0) << " +- " << w;
  std::cout << "  " << std::left << std::setw(10) << f.value("model", "") << std::right << " "
            << f.value("width_name", "") << " " << width.str() << "  chi2/dof "
            << Sig(f.value("reduced_chi2", 0.0), 4) << "  " << f.value("status", "");
  if (f.contains("samples")) std::cout << " (" << f["samples"].get<std::string>() << ")";
  std::cout << "\n";
  if (!explain) return;
  const json g = f.value("geometry", json::object());
  if (!g.value("stated", false)) return;
  std::ostringstream line;
  line << std::setprecision(3) << "geometry: " << f["width"].value("sigma_geometry", 0.0)
       << " of the sigma; chi2/dof counts " << f.value("n_nuisance", 0.0)
       << " nuisance parameter(s)";
  const json stage = g.value("sample_stage", json::array());
  if (!stage.empty()) {
    line << "; sample stage offset per sweep (deg):";
    for (const json& s : stage)
      line << " at " << s.value("sample_deg", 0.0) << " " << std::showpos
           << s.value("offset_deg", 0.0) << std::noshowpos << " +- " << s.value("sigma_deg", 0.0);
  }
  std::cout << gonio::Wrap(line.str(), 100, "    ", "      ");
}

int Fits(Ctl& ctl, std::int64_t id) {
  return ctl.Print(ctl.api().Get("/api/v1/runs/" + std::to_string(id) + "/fits"),
                   [&](const json& j) {
                     std::cout << "run " << id << ": " << j["fits"].size() << " stored fit(s)\n";
                     for (const json& f : j["fits"]) PrintFit(f["summary"], ctl.explain());
                   });
}

json ModelList(const std::string& models) {
  json list = json::array();
  std::stringstream ms(models);
  for (std::string m; std::getline(ms, m, ',');) list.push_back(m);
  return list;
}

// How long gonioctl waits for goniod's fit: a large run with the instrument response under a
// sanitizer took more than the 30 s other requests get (CI: the 10-point run of goniod_test.sh).
constexpr int kFitWaitS = 600;

int Fit(Ctl& ctl, std::int64_t id, const std::string& models) {
  std::cerr << "fitting run " << id << " (" << models << ") in goniod...\n";
  return ctl.Print(ctl.api().PostAndWait("/api/v1/runs/" + std::to_string(id) + "/fit",
                                         {{"models", ModelList(models)}}, kFitWaitS),
                   [&](const json& j) {
                     std::cout << "run " << id << ":\n";
                     for (const json& f : j["fits"]) PrintFit(f, ctl.explain());
                   });
}

int Queue(Ctl& ctl) {
  return ctl.Print(ctl.api().Get("/api/v1/jobs"), [](const json& j) {
    for (const json& x : j["jobs"]) {
      std::cout << std::setw(5) << x["id"].get<std::int64_t>() << "  " << std::setw(10)
                << x.value("state", "") << "  run " << std::setw(5)
                << (x["run"].is_null() ? std::string("-") : x["run"].dump()) << "  "
                << x.value("name", "");
      if (!x.value("message", std::string()).empty())
        std::cout << "  (" << x["message"].get<std::string>() << ")";
      std::cout << "\n";
    }
  });
}

int Runs(Ctl& ctl) {
  return ctl.Print(ctl.api().Get("/api/v1/runs"), [](const json& j) {
    for (const json& r : j["runs"])
      std::cout << std::setw(5) << r["id"].get<std::int64_t>() << "  " << std::setw(8)
                << r.value("status", "") << "  " << r["points_done"] << "/"
                << r["points_total"].get<int>() - r["points_skipped"].get<int>() << " points  "
                << r.value("specimen", "") << "\n";
  });
}

// The bench's throughput as the instrument config's [throughput] table, to paste into it.
int Throughput(Ctl& ctl) {
  return ctl.Print(ctl.api().Get("/api/v1/throughput"), [](const json& t) {
    std::cout << std::setprecision(6) << "# the bench's throughput, measured on run " << t["run"]
              << " (gonioctl throughput)\n[throughput]\n"
              << "from_run = " << t["run"] << "\nscale = " << t["scale"].get<double>()
              << "\nfloor = " << t["floor"].get<double>()
              << "\nadu_per_value = " << t["adu_per_value"].get<double>()
              << "\ndark_adu = " << t["dark_adu"].get<double>() << "\n";
    if (t.contains("noise"))
      for (const char* k : {"shot", "read", "lamp", "dark"})
        std::cout << "noise_" << k << " = " << t["noise"][k].get<double>() << "\n";
  });
}

int Show(Ctl& ctl, std::int64_t id) {
  return ctl.Print(ctl.api().Get("/api/v1/runs/" + std::to_string(id)), [](const json& r) {
    std::cout << "run " << r["id"] << " (" << r.value("specimen", "")
              << "): " << r.value("status", "") << ", " << r["points_done"] << " points\n";
    // What the run was expected to cost and what its points took.
    const bool exposed = r.contains("exposed_s") && r["exposed_s"].is_number();
    const bool estimated = r.contains("estimate") && r["estimate"].is_object();
    std::ostringstream cost;
    if (exposed) cost << "exposure " << std::lround(r["exposed_s"].get<double>()) << " s";
    if (estimated) {
      const json& e = r["estimate"];
      const double priced_s = e.value("exposure_s", 0.0);
      cost << (exposed ? ", " : "exposure ") << "estimated " << std::lround(priced_s) << " s";
      if (exposed && priced_s > 0)
        cost << " (" << std::showpos
             << std::lround(100 * (priced_s / r["exposed_s"].get<double>() - 1)) << std::noshowpos
             << " %)";
      cost << " of " << std::lround(e.value("total_s", 0.0)) << " s with motion, from "
           << e.value("basis", std::string("?"));
    }
    if (exposed || estimated) std::cout << gonio::Wrap(cost.str(), 100, "", "  ");
    std::cout << "theta_l  theta_v   value          sigma       exposure_s\n";
    for (const json& m : r["measurements"])
      std::cout << std::setw(7) << m["theta_l_deg"].get<double>() << "  " << std::setw(7)
                << m["theta_v_deg"].get<double>() << "  " << std::setw(13)
                << m["value"].get<double>() << "  " << std::setw(10) << m["sigma"].get<double>()
                << "  " << m["exposure_s"].get<double>() << "\n";
  });
}

// The run's CSV into `path`; 0 or the exit code, with the message printed.
int SaveCsv(Ctl& ctl, std::int64_t id, const std::string& path) {
  Reply r = ctl.api().Get("/api/v1/runs/" + std::to_string(id) + "/csv");
  if (r.status != 200) return Failed(r, ctl.url());
  std::ofstream f(path);
  f << r.body;
  if (!f) {
    std::cerr << "gonioctl: " << path << ": cannot write\n";
    return 1;
  }
  return 0;
}

int Export(Ctl& ctl, std::int64_t id, const std::string& out) {
  if (int rc = SaveCsv(ctl, id, out); rc != 0) return rc;
  std::cout << "wrote " << out << "\n";
  return 0;
}

struct PlotOptions {
  std::string out, models, fit_tool, plot_script;
};

// The run's fit as goniod stores it, drawn: gonio-fit runs the same protocol with the same
// options (the run's specimen eta, no robust loss), so the curves are the stored fit's. It says
// so, and what it ran.
int Plot(Ctl& ctl, std::int64_t id, PlotOptions o) {
  // An installed gonioctl uses its installed companions; one in the build tree, the build's.
  const std::filesystem::path bin = std::filesystem::read_symlink("/proc/self/exe").parent_path();
  if (o.fit_tool.empty()) o.fit_tool = Companion({bin / "gonio-fit", GONIO_FIT_TOOL});
  if (o.plot_script.empty())
    o.plot_script = Companion({bin / "../share/gonio/plot_fit.py", GONIO_PLOT_SCRIPT});
  for (const auto& [what, path] : {std::pair<std::string, std::string>{"--gonio-fit", o.fit_tool},
                                   {"--plot-script", o.plot_script}}) {
    if (!std::filesystem::is_regular_file(path)) {
      std::cerr << "gonioctl: " << path << ": not found; name it with " << what << "\n";
      return 2;
    }
  }
  Reply run = ctl.api().Get("/api/v1/runs/" + std::to_string(id));
  if (run.status != 200) return Failed(run, ctl.url());
  std::ostringstream eta;
  eta << std::setprecision(17) << run.j.value("specimen_eta", 1.51);
  std::error_code ec;
  std::filesystem::create_directories(o.out, ec);
  if (ec) {
    std::cerr << "gonioctl: " << o.out << ": cannot create: " << ec.message() << "\n";
    return 1;
  }
  const std::string stem = o.out + "/run" + std::to_string(id);
  if (int rc = SaveCsv(ctl, id, stem + ".csv"); rc != 0) return rc;
  const std::vector<std::string> fit_argv{o.fit_tool, stem + ".csv", "--model", o.models,
                                          "--eta",    eta.str(),     "--out",   o.out};
  std::cerr << "gonioctl: fitting with " << o.fit_tool << ", plotting with " << o.plot_script
            << "\ngonioctl: the fit goniod stores (its protocol and options: --model " << o.models
            << " --eta " << eta.str() << ", no robust loss), computed again for the curves\n";
  if (int rc = RunProgram(fit_argv); rc != 0) {
    std::cerr << "gonioctl: " << o.fit_tool << " failed (" << rc << ")\n";
    return 1;
  }
  if (int rc = RunProgram({"/usr/bin/python3", o.plot_script, o.out, stem + ".png"}); rc != 0) {
    std::cerr << "gonioctl: " << o.plot_script << " failed (" << rc << ")\n";
    return 1;
  }
  return 0;
}

}  // namespace

static int Main(int argc, char** argv) {
  CLI::App app{"gonioctl: control goniod"};
  app.require_subcommand(1);
  std::string url = "http://127.0.0.1:8470", token_file;
  bool as_json = false;
  app.add_option("--url", url, "goniod's API")->capture_default_str();
  app.add_option("--token-file", token_file, "the daemon's token (for submit, pause, ...)");
  app.add_flag("--json", as_json, "print the daemon's JSON replies (for scripts)");
  bool explain = false;
  app.add_flag("-v,--verbose", explain, "details: how the geometry entered each fit (fits, fit)");

  std::string plan_path, out, schedule_path, models = "beckmann,ggx";
  int repeat = 1, position = 0;
  bool wait_after = false, dry_run = false;
  std::int64_t id = 0;
  double timeout_s = 0;
  PlotOptions po;
  auto* status = app.add_subcommand("status", "state, current job and progress");
  auto* submit = app.add_subcommand("submit", "queue a plan file");
  submit->add_option("plan", plan_path)->required()->check(CLI::ExistingFile);
  submit->add_option("--repeat", repeat, "queue it N times")->capture_default_str();
  submit->add_flag("--wait", wait_after, "then wait until the daemon is idle");
  submit->add_flag("--dry-run", dry_run, "price it and list its points; queue nothing");
  auto* queue = app.add_subcommand("queue", "list jobs");
  auto* cancel = app.add_subcommand("cancel", "cancel a queued job");
  cancel->add_option("job", id)->required();
  auto* move = app.add_subcommand("move", "move a queued job to a position (0 = next)");
  move->add_option("job", id)->required();
  move->add_option("position", position)->required();
  auto* pause = app.add_subcommand("pause", "pause after the current point");
  auto* resume = app.add_subcommand("resume", "resume a paused, suspended or faulted run");
  auto* abort = app.add_subcommand("abort", "end the current run (stages stopped)");
  auto* runs = app.add_subcommand("runs", "stored runs");
  auto* throughput = app.add_subcommand(
      "throughput", "the bench's measured throughput, as the instrument config's [throughput]");
  auto* show = app.add_subcommand("show", "one run and its measurements");
  show->add_option("run", id)->required();
  auto* exp = app.add_subcommand("export", "a run as the fitter's CSV");
  exp->add_option("run", id)->required();
  exp->add_option("--out", out)->required();
  auto* sched = app.add_subcommand("schedule", "queue a schedule's jobs");
  sched->add_option("file", schedule_path)->required()->check(CLI::ExistingFile);
  sched->add_flag("--dry-run", dry_run, "list what would run and how long it would take");
  sched->add_flag("--wait", wait_after, "then wait until the daemon is idle");
  auto* fit = app.add_subcommand("fit", "fit a stored run (results stored with it)");
  fit->add_option("run", id)->required();
  fit->add_option("--model", models, "comma-separated models")->capture_default_str();
  auto* fits = app.add_subcommand("fits", "the fits stored with a run");
  fits->add_option("run", id)->required();
  auto* plot = app.add_subcommand("plot", "a run's fit and a PNG (gonio-fit, plot_fit.py)");
  plot->add_option("run", id)->required();
  plot->add_option("--out", po.out, "directory for the CSV, the fit's curves and run<N>.png")
      ->required();
  plot->add_option("--model", models, "comma-separated models")->capture_default_str();
  plot->add_option(
      "--gonio-fit", po.fit_tool,
      "the fitter program (default: beside gonioctl when installed, else the build's)");
  plot->add_option("--plot-script", po.plot_script,
                   "fitting/tools/plot_fit.py (default: <prefix>/share/gonio/plot_fit.py when "
                   "installed, else the source tree's)");
  auto* wait = app.add_subcommand("wait", "follow progress until the daemon is idle");
  wait->add_option("--timeout", timeout_s, "give up after S seconds (0: never)");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? 0 : 2;
  }
  std::string token;
  if (!token_file.empty()) {
    std::ifstream in(token_file);
    if (!(in >> token)) {
      std::cerr << "gonioctl: " << token_file << ": cannot read a token\n";
      return 2;
    }
  }
  Ctl ctl(url, token, as_json, explain, timeout_s);
  Api& api = ctl.api();
  if (*status) return ctl.Print(api.Get("/api/v1/status"), PrintStatus);
  if (*submit) return Submit(ctl, plan_path, repeat, wait_after, dry_run);
  if (*sched) return Schedule(ctl, schedule_path, dry_run, wait_after);
  if (*fits) return Fits(ctl, id);
  if (*fit) return Fit(ctl, id, models);
  if (*queue) return Queue(ctl);
  if (*cancel)
    return ctl.Print(api.Delete("/api/v1/jobs/" + std::to_string(id)),
                     [](const json& j) { std::cout << "job " << j["id"] << " cancelled\n"; });
  if (*move)
    return ctl.Print(
        api.Post("/api/v1/jobs/" + std::to_string(id) + "/position", {{"position", position}}),
        [&](const json&) { std::cout << "job " << id << " moved\n"; });
  if (*pause) return ctl.Print(api.Post("/api/v1/pause", json::object()), PrintStatus);
  if (*resume) return ctl.Print(api.Post("/api/v1/resume", json::object()), PrintStatus);
  if (*abort) return ctl.Print(api.Post("/api/v1/abort", json::object()), PrintStatus);
  if (*runs) return Runs(ctl);
  if (*show) return Show(ctl, id);
  if (*throughput) return Throughput(ctl);
  if (*exp) return Export(ctl, id, out);
  if (*plot) {
    po.models = models;
    return Plot(ctl, id, po);
  }
  if (*wait) return ctl.WaitIdle();
  return 2;
}

// Nothing a user passes makes gonioctl abort: what escapes is reported and exits 1.
int main(int argc, char** argv) {
  try {
    return Main(argc, argv);
  } catch (const std::exception& e) {
    std::cerr << "gonioctl: internal error: " << e.what() << "\n";
  } catch (...) {
    std::cerr << "gonioctl: internal error\n";
  }
  return 1;
}
