// gonio-sim: serves the simulated instrument on loopback until interrupted - the rotation stages
// over Modbus TCP and, optionally, Modbus RTU on a pty (docs/stage_register_map.md), the cooled
// CCD over GigE Vision (docs/camera_features.md), and the source monitor over the USBTMC socket
// transport (docs/source_monitor.md), looking at the sample of the config file through the
// bench's scene, with the config's fault plan.
//
//   gonio-sim                                 # defaults: 3 axes on :5020, camera, monitor :5021
//   gonio-sim --config config/sim.toml        # every key documented in that example
//   gonio-sim --port 0 --port-file p.txt      # the OS picks the Modbus port; scripts read p.txt
//   gonio-sim --rtu-link /tmp/gonio-rtu       # Modbus RTU too, on a pty linked there
#include <CLI/CLI.hpp>
#include <atomic>
#include <chrono>
#include <csignal>
#include <fstream>
#include <iostream>
#include <thread>

#include "sim/instrument.h"
#include "sim/sim_config.h"

namespace {
std::atomic<bool> g_stop{false};
void OnSignal(int) { g_stop = true; }
}  // namespace

int main(int argc, char** argv) {
  using namespace gonio::sim;
  CLI::App app{"Simulated gonioreflectometer devices on 127.0.0.1"};
  std::string config_path, port_file, monitor_port_file, rtu_link;
  int port = -1, monitor_port = -1;
  double speed = 0;
  bool no_camera = false;
  app.add_option("--config", config_path, "TOML file (config/sim.toml documents every key)")
      ->check(CLI::ExistingFile);
  app.add_option("--port", port, "Modbus TCP port on 127.0.0.1, 0: any free port (overrides)")
      ->check(CLI::Range(0, 65535));
  app.add_option("--speed", speed, "simulated seconds per real second (overrides)")
      ->check(CLI::PositiveNumber);
  app.add_flag("--no-camera", no_camera, "serve the stages only (GVCP port 3956 left free)");
  app.add_option("--port-file", port_file, "write the chosen Modbus port to this file");
  app.add_option("--rtu-link", rtu_link, "serve Modbus RTU on a pty too, symlinked at this path");
  app.add_option("--monitor-port", monitor_port,
                 "source monitor socket on 127.0.0.1, 0: any free port (overrides)")
      ->check(CLI::Range(0, 65535));
  app.add_option("--monitor-port-file", monitor_port_file,
                 "write the chosen source monitor port to this file");
  std::string truth_log;
  app.add_option("--truth-log", truth_log,
                 "append one CSV line per frame: the stages' true angles, shutter, lamp (to check "
                 "read-backs against; bench/coverage/truth_angles.py)");
  CLI11_PARSE(app, argc, argv);

  SimConfig cfg = DefaultSimConfig();
  if (!config_path.empty()) {
    auto loaded = LoadSimConfig(config_path);
    if (!loaded) {
      std::cerr << "gonio-sim: error: " << loaded.error().message << "\n";
      return 2;
    }
    cfg = std::move(loaded).value();
  }
  if (port >= 0) cfg.modbus_port = port;
  if (speed > 0) cfg.clock_speed = speed;
  if (no_camera) cfg.camera_enabled = false;
  if (!rtu_link.empty()) cfg.rtu_link = rtu_link;
  if (monitor_port >= 0) cfg.monitor_port = monitor_port;
  if (!truth_log.empty()) cfg.camera.truth_log = truth_log;

  auto started = Instrument::Start(cfg);
  if (!started) {
    std::cerr << "gonio-sim: error: " << started.error().message << "\n";
    return 1;
  }
  Instrument& sim = **started;
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  // The Modbus port file last: scripts wait for it, then read the others.
  if (!monitor_port_file.empty() && sim.monitor())
    std::ofstream(monitor_port_file) << sim.monitor()->port() << "\n";
  if (!port_file.empty()) std::ofstream(port_file) << sim.modbus_port() << "\n";
  std::cout << "gonio-sim: stage controller (" << cfg.axes.size() << " axes, unit ids 1.."
            << cfg.axes.size() << ") on Modbus TCP 127.0.0.1:" << sim.modbus_port();
  if (sim.rtu())
    std::cout << " and Modbus RTU " << sim.rtu()->pty_path() << " (" << cfg.rtu_link << ")";
  if (sim.camera())
    std::cout << "; camera " << cfg.camera.serial << " on GigE Vision " << cfg.camera.address;
  if (sim.monitor()) std::cout << "; source monitor on 127.0.0.1:" << sim.monitor()->port();
  std::cout << "; sample " << sim.scene().truth().Name() << "; clock x" << cfg.clock_speed;
  if (!sim.faults().empty()) std::cout << "; " << cfg.faults.size() << " planned fault(s)";
  std::cout << "; Ctrl-C stops" << std::endl;
  std::size_t reported = 0;
  while (!g_stop) {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    const auto fired = sim.faults().Fired();  // the operator sees each injected fault as it happens
    for (; reported < fired.size(); ++reported) {
      const FiredFault& f = fired[reported];
      std::cout << "gonio-sim: fault " << ToString(f.kind)
                << (f.target.empty() ? "" : " on " + f.target) << " at t=" << f.time_s << " s"
                << std::endl;
    }
  }
  started->reset();  // the camera first, then the servers (Instrument's destructor)
  std::cout << "gonio-sim: stopped" << std::endl;
  return 0;
}
