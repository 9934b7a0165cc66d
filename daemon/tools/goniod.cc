// goniod: the daemon that owns the instrument. It opens the devices of the instrument config,
// serves the local API (docs/api.md) on 127.0.0.1, runs submitted plans one after another through
// the sweep engine into the SQLite database, and suspends runs on the conditions it is given.
//
//   goniod -c config/instrument.toml --db runs.sqlite [--port 8470] [--token-file F]
//          [--on-start resume|pause|ignore] [--temperature-setpoint C --temperature-band C]
//          [--monitor-floor W] [--port-file F]
//
// SIGTERM or SIGINT: the exposure in progress is stopped and the point in hand left pending, the
// run is left paused, the stages stop, and goniod exits 0 within about a second (docs/api.md
// has the figures). On start, a run left unfinished
// is resumed (--on-start resume, the default), held paused for the operator (pause), or left
// alone (ignore). Under systemd (Type=notify) it reports READY=1 once the API listens.
// Exit codes: 0 stopped by a signal; 1 a device, storage or bind error; 2 bad input.
#include <systemd/sd-daemon.h>

#include <CLI/CLI.hpp>
#include <csignal>
#include <fstream>
#include <future>
#include <iostream>
#include <optional>
#include <sstream>
#include <thread>

#include "acquisition/plan.h"
#include "config/instrument_config.h"
#include "daemon/api/http_api.h"
#include "daemon/instrument/instrument.h"
#include "daemon/service/controller.h"

namespace {

using namespace gonio;

int Fail(const Error& e) {
  std::cerr << "goniod: " << e.ToString() << "\n";
  return e.code == ErrorCode::kInvalidArgument ? 2 : 1;
}

std::string Timestamp() {
  const auto now = std::chrono::system_clock::now();
  const std::time_t t = std::chrono::system_clock::to_time_t(now);
  char b[32];
  std::strftime(b, sizeof b, "%F %T", std::localtime(&t));
  return b;
}

// Logs by category: the event's type ("state", "job", "progress", "suspend", "log").
void LogEvents(daemon::EventLog& events) {
  std::int64_t after = 0;
  while (!events.closed()) {
    for (const daemon::Event& e : events.After(after, std::chrono::milliseconds(500))) {
      after = e.seq;
      std::cout << Timestamp() << " [" << e.type << "] " << e.data.dump() << std::endl;
      if (e.type == "state")
        sd_notifyf(0, "STATUS=%s", e.data.value("state", std::string()).c_str());
    }
  }
}

// What the command line asked for.
struct Args {
  std::string config_path, samples_path = "config/samples.toml", db_path, token_file, port_file;
  std::string host = "127.0.0.1", on_start = "resume", plans_dir;
  int port = 8470;
  std::optional<double> setpoint, floor_w;
  double band = 2.0, poll_s = 2.0, give_up_s = 600, link_check_s = 0.5;
};

// Parses the command line into `a`; nullopt to go on, else the exit code (help, or 2).
std::optional<int> ParseArgs(int argc, char** argv, Args& a) {
  CLI::App app{"goniod: the gonioreflectometer daemon (local HTTP API, job queue, run control)"};
  app.add_option("-c,--config", a.config_path, "instrument config")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option("--samples", a.samples_path, "specimen catalogue")->check(CLI::ExistingFile);
  app.add_option("--plans", a.plans_dir, "the instrument's plans (*.toml), offered by the console")
      ->check(CLI::ExistingDirectory);
  app.add_option("--db", a.db_path, "SQLite database (created if missing)")->required();
  app.add_option("--listen", a.host,
                 "API address, numeric IPv4 (loopback unless you mean otherwise)")
      ->check(CLI::ValidIPV4)
      ->capture_default_str();
  app.add_option("--port", a.port, "API port (0: any free port)")->capture_default_str();
  app.add_option("--port-file", a.port_file, "write the bound port here once listening");
  app.add_option("--token-file", a.token_file,
                 "token for mutating calls (created 0640 if missing; default: <db>.token)");
  app.add_option("--on-start", a.on_start, "an interrupted run: resume, pause or ignore")
      ->check(CLI::IsMember({"resume", "pause", "ignore"}))
      ->capture_default_str();
  app.add_option("--temperature-setpoint", a.setpoint,
                 "suspend while the sensor is outside setpoint +- band (C)");
  app.add_option("--temperature-band", a.band, "C")->capture_default_str();
  app.add_option("--monitor-floor", a.floor_w, "suspend while the source monitor reads below (W)");
  app.add_option("--suspend-poll", a.poll_s, "seconds between checks of a suspended condition")
      ->capture_default_str();
  app.add_option("--fault-after", a.give_up_s, "seconds a suspension may last before 'fault'")
      ->capture_default_str();
  app.add_option("--link-check", a.link_check_s,
                 "seconds between checks that each device answers, while a run measures (0: off)")
      ->check(CLI::Range(0.0, 60.0))
      ->capture_default_str();
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? 0 : 2;
  }
  if (a.token_file.empty()) a.token_file = a.db_path + ".token";
  return std::nullopt;
}

// After SIGTERM or SIGINT: the run in hand is interrupted (its point left pending) and left
// paused. A worker that does not come back within kGraceS is waiting on a device that does not
// answer (its retries and reconnects can take tens of seconds): goniod then stops the stages as
// far as they answer and exits without it. The database stays consistent (every point is one
// transaction; a kill -9 loses nothing either), and the next start finds the run interrupted and
// resumes it. Returns only when the worker stopped in time.
void ShutdownWithin(daemon::Controller& controller, devices::StageController& stages) {
  constexpr double kGraceS = 2.0, kStopWaitS = 1.5;
  auto worker_done = std::async(std::launch::async, [&controller] { controller.Shutdown(); });
  if (worker_done.wait_for(std::chrono::duration<double>(kGraceS)) != std::future_status::ready) {
    std::cout << Timestamp() << " [state] the run's worker is still waiting on a device after "
              << kGraceS
              << " s (not answering?): exiting without it; the run resumes at the next start"
              << std::endl;
    const bool answered = daemon::StopStagesWithin(stages, kStopWaitS);
    std::cout << Timestamp() << " [state] "
              << (answered ? "stages stopped"
                           : "the stages did not confirm STOP: they may still be moving")
              << "; stopped without waiting for the worker" << std::endl;
    std::_Exit(0);  // the worker and the stop request are not waited for
  }
}

}  // namespace

int main(int argc, char** argv) {
  Args a;
  if (auto code = ParseArgs(argc, argv, a)) return *code;

  // Signals are taken by sigwait below: blocked here, before any thread starts, in all threads.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGTERM);
  sigaddset(&signals, SIGINT);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);

  auto cfg = config::LoadInstrumentConfig(a.config_path);
  if (!cfg.ok()) return Fail(cfg.error());
  auto specimens = acquisition::LoadSpecimens(a.samples_path);
  if (!specimens.ok()) return Fail(specimens.error());
  daemon::ReturnLargeBlocksToTheSystem();  // what a refused large request held goes back
  auto token = daemon::LoadOrCreateToken(a.token_file);
  if (!token.ok()) return Fail(token.error());
  auto db = acquisition::Storage::Open(a.db_path);
  if (!db.ok()) return Fail(db.error());

  auto instrument = daemon::OpenInstrument(*cfg, *specimens);
  if (!instrument.ok()) return Fail(instrument.error());
  daemon::Instrument& in = *instrument;
  std::cout << Timestamp() << " [device] camera " << in.camera->Identity() << ", "
            << in.context.image_width << " x " << in.context.image_height << "; "
            << cfg->axes.size() << " axes"
            << (in.monitor.monitor ? "; source monitor" : "; no source monitor") << std::endl;

  daemon::ControllerOptions co;
  auto run_start = daemon::RunStartFor(*cfg, a.config_path);
  if (!run_start.ok()) return Fail(run_start.error());
  co.run_start = std::move(run_start).value();
  co.suspenders.temperature_setpoint_c = a.setpoint;
  co.suspenders.temperature_band_c = a.band;
  co.suspenders.monitor_floor_w = a.floor_w;
  co.suspenders.poll_s = a.poll_s;
  co.suspenders.fault_give_up_s = a.give_up_s;
  co.suspenders.link_check_s = a.link_check_s;
  daemon::Controller controller(*in.stages, *in.camera, in.monitor.monitor.get(), **db, in.context,
                                co);
  std::thread logger([&controller] { LogEvents(controller.events()); });
  std::optional<bool> resume;
  if (a.on_start != "ignore") resume = a.on_start == "resume";
  if (Status s = controller.Start(resume); !s.ok()) {
    controller.Shutdown();
    logger.join();
    return Fail(s.error());
  }
  daemon::ApiOptions ao;
  ao.host = a.host;
  ao.port = a.port;
  ao.token = *token;
  ao.db_path = a.db_path;
  ao.plans_dir = a.plans_dir;
  auto api = daemon::ApiServer::Start(controller, ao);
  if (!api.ok()) {
    controller.Shutdown();
    logger.join();
    return Fail(api.error());
  }
  if (!a.port_file.empty()) std::ofstream(a.port_file) << (*api)->port() << "\n";
  std::cout << Timestamp() << " [api] listening on http://" << a.host << ":" << (*api)->port()
            << " (token in " << a.token_file << "); the console: http://" << a.host << ":"
            << (*api)->port() << "/console/" << std::endl;
  sd_notify(0, "READY=1");

  int sig = 0;
  sigwait(&signals, &sig);
  std::cout << Timestamp() << " [state] " << (sig == SIGTERM ? "SIGTERM" : "SIGINT")
            << ": stopping (the exposure in progress is abandoned, its point left pending)"
            << std::endl;
  sd_notify(0, "STOPPING=1");
  ShutdownWithin(controller, *in.stages);
  (*api)->Stop();
  logger.join();
  (void)in.stages->StopAll();
  std::cout << Timestamp() << " [state] stopped" << std::endl;
  return 0;
}
