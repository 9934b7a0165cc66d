// gonio-acquire: runs a measurement plan on the instrument and stores it in SQLite, without the
// daemon (goniod of #7 runs the same engine behind its API).
//
//   gonio-acquire -c config/instrument.toml --db runs.sqlite run plan.toml [--dry-run]
//   gonio-acquire ... resume [RUN]        # an interrupted run (default: the latest one)
//   gonio-acquire ... --cool -10 run plan.toml   # the CCD cooled and held first
//   gonio-acquire --db runs.sqlite export RUN --out run.csv    # the fitter's CSV
//   gonio-acquire --db runs.sqlite status RUN
//
// Ctrl-C (SIGINT) or SIGTERM pauses after the current point is stored; resume continues it. A
// second signal, or one while a device fault is waited out, stops the point in hand as goniod's
// SIGTERM does (its exposure abandoned, the point left pending, the run paused), and does not wait
// more than 2 s on a device that does not answer: the stages are then told to stop and the
// process exits (every stored point is its own transaction; resume continues the run).
// A device fault that the drivers' own retries did not clear (a device restarted, a cable
// pulled) pauses the run, which is tried again every --retry-s until it measures again, as goniod
// does, for at most --give-up-s (0: stop at the first fault).
// --cool C cools the CCD to C and waits until it holds there (--cool-hold seconds within 0.5 C)
// before the first point, as goniod's [job.cooler] does: at ambient a CCD's dark current is tens
// of times larger, and darks taken while it cools are stale by the next point. A camera without
// a cooler is refused rather than measured warm.
// Exit codes: 0 done; 1 a device or storage error not cleared in time (the run is left paused);
// 2 bad input; 3 paused by a signal.
#include <CLI/CLI.hpp>
#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <mutex>
#include <optional>
#include <sstream>
#include <thread>

#include "acquisition/engine.h"
#include "acquisition/plan.h"
#include "acquisition/run_start.h"
#include "acquisition/storage.h"
#include "config/instrument_config.h"
#include "daemon/instrument/instrument.h"

namespace {

using namespace gonio;
using namespace gonio::acquisition;

std::atomic<bool> g_stop{false};       // a signal came: pause after the point in hand
std::atomic<bool> g_interrupt{false};  // do not wait for the point in hand (Engine::InterruptOn)
std::atomic<bool> g_waiting{false};    // no point in hand: a device fault is being waited out
std::atomic<devices::StageController*> g_stages{nullptr};
std::atomic<Storage*> g_store{nullptr};  // with g_run, the run StopNow leaves paused
std::atomic<std::int64_t> g_run{0};
// Held by StopNow to the end: the measuring thread does not report meanwhile. Never destroyed:
// main ends holding it (HoldExitFromTeardown).
std::mutex& g_exit = *new std::mutex;

// Declared after the devices and the store, so destroyed before them: from then on the process
// ends with main's code, and a late StopNow (a second signal's grace running out as the run
// pauses by itself) waits for ever instead of stopping stages that are being destroyed.
struct HoldExitFromTeardown {
  HoldExitFromTeardown() = default;
  HoldExitFromTeardown(const HoldExitFromTeardown&) = delete;
  HoldExitFromTeardown& operator=(const HoldExitFromTeardown&) = delete;
  ~HoldExitFromTeardown() { g_exit.lock(); }
};

// Tells the stages to stop, waiting for them at most 1.5 s. Call with g_exit held.
void StopStagesQuickly() {
  if (devices::StageController* stages = g_stages.load()) {
    constexpr double kStopWaitS = 1.5;
    if (!daemon::StopStagesWithin(*stages, kStopWaitS))
      std::cerr << "gonio-acquire: the stages did not confirm STOP: they may still be moving"
                << std::endl;
  }
}

// Exits (3, paused by a signal) without waiting for the measuring thread, which a device that does
// not answer can hold for tens of seconds where no interrupt reaches (Aravis' connect retries, a
// Modbus timeout).
[[noreturn]] void StopNow(const std::string& why) {
  g_exit.lock();
  std::cerr << "gonio-acquire: " << why << ": still waiting on a device, exiting without it; "
            << "the point in hand, if any, is left pending (gonio-acquire ... resume continues "
            << "the run)" << std::endl;
  StopStagesQuickly();
  // Storage is safe to share between threads; a point being stored meanwhile is one transaction,
  // in whole or not at all. A run that finished meanwhile stays done.
  if (Storage* store = g_store.load(); store != nullptr && g_run > 0) {
    if (auto info = store->GetRun(g_run); info.ok() && info->status != RunStatus::kDone) {
      (void)store->AddEvent(g_run, "paused", "stopped at once (" + why + ")");
      (void)store->SetRunStatus(g_run, RunStatus::kPaused);
    }
  }
  std::fflush(nullptr);
  std::_Exit(3);
}

// The end of a run stopped at once (g_interrupt): the devices are not closed either, since a
// camera that has gone holds its close for its GVCP retries (some 10 s). Every stored point is
// already committed; the stages are told to stop.
[[noreturn]] void ExitWithoutClosing(int code) {
  g_exit.lock();
  StopStagesQuickly();
  std::fflush(nullptr);  // std::cout is synced with stdio: what main printed is in stdout's buffer
  std::_Exit(code);
}

// Stops the point in hand as goniod's SIGTERM does: the engine abandons the exposure in progress
// and leaves the run paused with the point pending, and the measuring thread then reports and
// exits 3. A thread held where no interrupt reaches is not waited for beyond kGraceS (StopNow).
[[noreturn]] void StopPointInHand(const std::string& why) {
  std::cerr << "gonio-acquire: " << why << ": stopping the point in hand" << std::endl;
  g_interrupt = true;
  constexpr double kGraceS = 2.0;
  std::this_thread::sleep_for(std::chrono::duration<double>(kGraceS));
  StopNow(why);
}

// Takes SIGINT and SIGTERM (blocked in every thread) on a thread of its own. The first sets
// g_stop, which the run and the cooling wait see between points; a second, or the first while a
// device fault is waited out, stops the point in hand (during the wait between two attempts the
// retry loop sees g_stop first and pauses as usual).
void WatchSignals(sigset_t signals) {
  int sig = 0;
  if (sigwait(&signals, &sig) != 0) return;
  g_stop = true;
  std::cerr << "gonio-acquire: " << (sig == SIGTERM ? "SIGTERM" : "SIGINT")
            << ": pausing after the point in hand (a second signal stops at once)" << std::endl;
  const timespec tick{0, 100'000'000};
  for (;;) {
    if (g_waiting) StopPointInHand("a device fault is being waited out");
    if (sigtimedwait(&signals, nullptr, &tick) > 0) StopPointInHand("a second signal");
  }
}

int Fail(const Error& e) {
  std::cerr << "gonio-acquire: " << e.ToString() << "\n";
  return e.code == ErrorCode::kInvalidArgument ? 2 : 1;
}

std::string Duration(double s) {
  char b[32];
  if (s < 10) {
    std::snprintf(b, sizeof b, "%.1f s", s);
  } else if (s < 120) {
    std::snprintf(b, sizeof b, "%.0f s", s);
  } else if (s < 7200) {
    std::snprintf(b, sizeof b, "%.1f min", s / 60);
  } else {
    std::snprintf(b, sizeof b, "%.1f h", s / 3600);
  }
  return b;
}

// What `resume` continues: the run given, or the latest unfinished one; nullopt, with the reason
// printed, when there is nothing to continue.
Result<std::optional<RunInfo>> RunToResume(Storage& store, std::int64_t run_id,
                                           const std::string& db_path) {
  if (run_id == 0) {
    auto latest = store.UnfinishedRun();
    if (!latest.ok()) return latest.error();
    if (!*latest) {
      std::cout << "no interrupted run in " << db_path << ": nothing to resume\n";
      return std::optional<RunInfo>();
    }
    run_id = **latest;
  }
  auto info = store.GetRun(run_id);
  if (!info.ok()) return info.error();
  if (info->status == RunStatus::kDone) {
    std::cout << "run " << run_id << " is already done\n";
    return std::optional<RunInfo>();
  }
  return std::optional<RunInfo>(*info);
}

// The plan's points, the skipped ones with their reasons, and the bench time it will take,
// priced at the exposures the newest finished run of its specimen needed if there is one, else
// at the specimen's expected lobe through the bench's throughput.
Result<RunEstimate> PrintPlanSummary(Storage& store, const std::string& plan_path, const Plan& plan,
                                     const std::vector<PlannedPoint>& points,
                                     const RunStart& start) {
  int skipped = 0;
  for (const auto& p : points) skipped += p.skipped;
  auto estimate = EstimateNewRun(store, start, plan, points);
  if (!estimate.ok()) return estimate.error();
  std::cout << "plan " << plan_path << ": " << plan.specimen.name << ", " << points.size() - skipped
            << " points (" << skipped << " skipped), about " << Duration(estimate->total_s)
            << " of bench time for motion and exposure (from " << estimate->basis << ")\n";
  for (const auto& p : points)
    if (p.skipped)
      std::cout << "  skip theta_l " << p.theta_l_deg << " theta_v " << p.theta_v_deg << ": "
                << p.reason << "\n";
  return estimate;
}

// How a device fault is waited out (goniod's suspenders: ControllerOptions).
struct Retry {
  double every_s = 2;
  double give_up_s = 600;
};

// Cools the CCD and waits for it to hold (--cool); a signal ends the wait (kAborted, exit 1: the
// run stays as it was, pending or paused).
Status Cool(devices::Camera& camera, const devices::TemperatureWait& w) {
  if (!camera.Capabilities().cooler)
    return Error{ErrorCode::kFailedPrecondition,
                 "--cool: this camera has no cooler (measure without --cool, at its own "
                 "temperature)"};
  std::cout << "cooling the CCD to " << w.setpoint_c << " C (held " << w.hold_s << " s within "
            << w.tolerance_c << " C, at most " << Duration(w.timeout_s) << ")" << std::endl;
  if (Status s = camera.CoolAndWait(w); !s.ok()) return s;
  if (auto t = camera.TemperatureC(); t.ok())
    std::cout << "the CCD holds " << *t << " C" << std::endl;
  return OkStatus();
}

double SteadyS() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

// Measures the run to its end, or until a signal pauses it (exit 3). A device fault pauses it and
// it is resumed every retry.every_s; the outage is printed once (again if its message changes)
// and its end once, when a point is stored.
int Measure(Storage& store, daemon::Instrument& in, const RunStart& start, std::int64_t run_id,
            const Plan& plan, const Retry& retry) {
  g_store = &store;
  g_run = run_id;
  Engine engine(*in.stages, *in.camera, in.monitor.monitor.get(), store, start.engine);
  engine.InterruptOn(&g_interrupt);
  double outage_since = -1;  // steady seconds; < 0: none
  std::string outage;        // the fault printed for it
  const auto on_point = [&](const Progress& p) {
    g_waiting = false;  // measuring again: a signal now waits for the point in hand
    if (outage_since >= 0) {
      std::printf("measuring again after %s (the device fault cleared)\n",
                  Duration(SteadyS() - outage_since).c_str());
      outage_since = -1;
      outage.clear();
    }
    char background[64] = "";
    if (p.last.background)
      std::snprintf(background, sizeof background, "  (background %.3g subtracted)",
                    *p.last.background);
    std::printf(
        "[%4d/%d] theta_l %5.1f theta_v %6.1f  exposure %-9.4g s  value %.5g +- %.2g%s  ETA %s\n",
        p.done, p.total, p.point.theta_l_deg, p.point.theta_v_deg, p.last.exposure_s, p.last.value,
        p.last.sigma, background, Duration(p.eta_s).c_str());
    std::fflush(stdout);
  };
  for (;;) {
    const Status s = engine.Run(run_id, plan, g_stop, on_point);
    g_waiting = false;
    if (s.ok()) break;
    {
      const std::lock_guard reporting(g_exit);
      // A signal during a fault: the run is paused as a signal pauses it (exit 3 below).
      if (g_stop && s.error().code != ErrorCode::kAborted) {
        std::cerr << "gonio-acquire: " << s.error().ToString() << "\n";
        break;
      }
      if (s.error().code == ErrorCode::kAborted || retry.give_up_s <= 0) return Fail(s.error());
      const double now = SteadyS();
      if (outage_since < 0) outage_since = now;
      if (now - outage_since > retry.give_up_s) {
        std::cerr << "gonio-acquire: the device fault did not clear within "
                  << Duration(retry.give_up_s) << " (--give-up-s); run " << run_id
                  << " is paused: gonio-acquire ... resume " << run_id << "\n";
        return Fail(s.error());
      }
      if (s.error().message != outage) {
        std::cout << "device fault, run " << run_id << " paused and tried again every "
                  << Duration(retry.every_s) << " for at most " << Duration(retry.give_up_s)
                  << " (--give-up-s): " << s.error().ToString() << std::endl;
        outage = s.error().message;
      }
    }
    // A signal during the wait pauses the run as it would mid-run (exit 3 below); one during the
    // next attempt, which a device that does not answer can hold for many seconds, stops the
    // point in hand (WatchSignals), until that attempt stores a point.
    g_waiting = true;
    for (double waited = 0; waited < retry.every_s && !g_stop; waited += 0.05)
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    if (g_stop) break;
  }
  const std::lock_guard reporting(g_exit);
  auto info = store.GetRun(run_id);
  if (!info.ok()) return Fail(info.error());
  if (info->status == RunStatus::kDone) {
    std::cout << "run " << run_id << " done\n";
    return 0;
  }
  std::cout << "run " << run_id << " paused after " << info->points_done
            << " points; continue with: gonio-acquire ... resume " << run_id << "\n";
  return 3;
}

// What the command line asked for.
struct Args {
  std::string config_path, samples_path = "config/samples.toml", db_path, plan_path, out;
  bool dry_run = false;
  std::int64_t run_id = 0;
  Retry retry;
  std::optional<double> cool_c;
  devices::TemperatureWait cool;
  bool run = false, resume = false, export_csv = false, status = false;
};

// Parses the command line into `a`; nullopt to go on, else the exit code (help, or 2).
std::optional<int> ParseArgs(int argc, char** argv, Args& a) {
  CLI::App app{"Run a measurement plan on the instrument into SQLite"};
  app.require_subcommand(1);
  app.add_option("-c,--config", a.config_path, "instrument config")->check(CLI::ExistingFile);
  app.add_option("--samples", a.samples_path, "specimen catalogue")->check(CLI::ExistingFile);
  app.add_option("--db", a.db_path, "SQLite database (created if missing)")->required();
  CLI::App* run_cmd = app.add_subcommand("run", "measure a plan");
  run_cmd->add_option("plan", a.plan_path)->required()->check(CLI::ExistingFile);
  run_cmd->add_flag("--dry-run", a.dry_run, "validate, list what would happen, measure nothing");
  CLI::App* resume_cmd = app.add_subcommand("resume", "continue an interrupted run");
  resume_cmd->add_option("run", a.run_id, "run id (default: the latest unfinished)");
  CLI::App* export_cmd = app.add_subcommand("export", "a run as the fitter's CSV");
  export_cmd->add_option("run", a.run_id)->required();
  export_cmd->add_option("--out", a.out)->required();
  app.add_option("--retry-s", a.retry.every_s,
                 "after a device fault, resume the paused run this often (seconds)")
      ->check(CLI::Range(0.1, 3600.0));
  app.add_option("--give-up-s", a.retry.give_up_s,
                 "stop (exit 1, the run paused) when a device fault has not cleared in this "
                 "long; 0 stops at the first")
      ->check(CLI::Range(0.0, 7.0 * 24 * 3600));
  a.cool.poll_s = 0.1;
  a.cool.cancel = &g_stop;
  app.add_option("--cool", a.cool_c,
                 "run and resume: cool the CCD to this (deg C) and wait until it holds there "
                 "before measuring")
      ->check(CLI::Range(-100.0, 30.0));
  app.add_option("--cool-hold", a.cool.hold_s, "seconds within 0.5 C that count as holding")
      ->check(CLI::Range(0.0, 3600.0));
  app.add_option("--cool-timeout", a.cool.timeout_s, "give up cooling after this long (seconds)")
      ->check(CLI::Range(1.0, 24.0 * 3600));
  CLI::App* status_cmd = app.add_subcommand("status", "a run's state");
  status_cmd->add_option("run", a.run_id)->required();
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? 0 : 2;
  }
  a.run = run_cmd->parsed();
  a.resume = resume_cmd->parsed();
  a.export_csv = export_cmd->parsed();
  a.status = status_cmd->parsed();
  return std::nullopt;
}

// `status RUN`: the run's state and its cost against its estimate.
int PrintStatus(Storage& store, std::int64_t run_id) {
  auto info = store.GetRun(run_id);
  if (!info.ok()) return Fail(info.error());
  std::cout << "run " << info->id << " (" << info->specimen << "): " << ToString(info->status)
            << ", " << info->points_done << "/" << info->points_total - info->points_skipped
            << " points, " << info->points_skipped << " skipped\n";
  if (const std::string cost = DescribeExposureAgainstEstimate(*info); !cost.empty())
    std::cout << cost << "\n";
  return 0;
}

// `run PLAN` and `resume [RUN]`: the plan checked against the instrument, the CCD cooled, the run
// created (acquisition/run_start.h, as goniod creates it) or resumed, then measured.
int RunOrResume(Storage& store, Args& a) {
  if (a.config_path.empty()) return Fail(InvalidArgument("run and resume need --config"));
  auto cfg = config::LoadInstrumentConfig(a.config_path);
  if (!cfg.ok()) return Fail(cfg.error());
  auto specimens = LoadSpecimens(a.samples_path);
  if (!specimens.ok()) return Fail(specimens.error());
  auto start = daemon::RunStartFor(*cfg, a.config_path);
  if (!start.ok()) return Fail(start.error());

  // The plan: a new one from its file, or a resumed run's own stored text.
  std::string plan_file = a.plan_path, stored_plan;
  if (a.resume) {
    auto resumed = RunToResume(store, a.run_id, a.db_path);
    if (!resumed.ok()) return Fail(resumed.error());
    if (!*resumed) return 0;
    a.run_id = (*resumed)->id;
    plan_file = "run " + std::to_string(a.run_id) + "'s stored plan";
    stored_plan = (*resumed)->plan_text;
  }
  // The devices open before the plan is checked against the camera's image: nothing moves yet.
  // A dry run opens nothing and checks the plan against the config alone.
  daemon::Instrument in;
  const HoldExitFromTeardown hold_exit;
  in.context = daemon::PlanContextOf(*cfg, *specimens);
  if (!a.dry_run) {
    auto opened = daemon::OpenInstrument(*cfg, *specimens);
    if (!opened.ok()) return Fail(opened.error());
    in = std::move(opened).value();
    g_stages = in.stages.get();
  }
  const PlanContext& ctx = in.context;
  auto plan = a.resume ? LoadPlanText(stored_plan, plan_file, ctx) : LoadPlan(plan_file, ctx);
  if (!plan.ok()) return Fail(plan.error());
  const auto points = ExpandPoints(*plan, ctx);
  std::optional<RunEstimate> estimate;
  if (a.run) {
    auto e = PrintPlanSummary(store, a.plan_path, *plan, points, *start);
    if (!e.ok()) return Fail(e.error());
    estimate = *e;
  }
  if (a.dry_run) return 0;
  // Cooled once the plan is known good and before a run is created: a camera that cannot cool,
  // or a cooling that times out or is interrupted, leaves nothing behind.
  if (a.cool_c) {
    a.cool.setpoint_c = *a.cool_c;
    if (Status s = Cool(*in.camera, a.cool); !s.ok()) return Fail(s.error());
  }
  if (a.run) {
    auto id = CreateRun(store, *start, *plan, points);
    if (!id.ok()) return Fail(id.error());
    a.run_id = *id;
    std::cout << "run " << a.run_id << " created in " << a.db_path << std::endl;
    if (Status st = RecordEstimate(store, a.run_id, *estimate); !st.ok()) return Fail(st.error());
    if (!plan->rectangle_reason.empty()) std::cout << plan->rectangle_reason << std::endl;
  } else {
    std::cout << "resuming run " << a.run_id << std::endl;
  }
  if (a.cool_c) (void)RecordCooled(store, a.run_id, *a.cool_c);
  const int code = Measure(store, in, *start, a.run_id, *plan, a.retry);
  if (g_interrupt) ExitWithoutClosing(code);
  return code;
}

}  // namespace

int main(int argc, char** argv) {
  Args a;
  if (auto code = ParseArgs(argc, argv, a)) return *code;
  // From here on a signal to a measurement pauses instead of killing: the run is stopped after
  // its current point. Blocked before any thread starts (the camera's), so that every thread
  // inherits the mask and only the watcher takes them. Export, status and a dry run keep the
  // default: a signal ends them (they change nothing, or one transaction).
  if ((a.run || a.resume) && !a.dry_run) {
    sigset_t signals;
    sigemptyset(&signals);
    sigaddset(&signals, SIGINT);
    sigaddset(&signals, SIGTERM);
    pthread_sigmask(SIG_BLOCK, &signals, nullptr);
    std::thread(WatchSignals, signals).detach();
  }
  auto db = Storage::Open(a.db_path);
  if (!db.ok()) return Fail(db.error());
  Storage& store = **db;
  if (a.export_csv) {
    Status s = store.ExportCsv(a.run_id, a.out);
    if (!s.ok()) return Fail(s.error());
    std::cout << "wrote " << a.out << "\n";
    return 0;
  }
  if (a.status) return PrintStatus(store, a.run_id);
  return RunOrResume(store, a);
}
