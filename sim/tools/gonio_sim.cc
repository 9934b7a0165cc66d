// gonio-sim: serves the simulated instrument on loopback until interrupted - the rotation stages
// over Modbus TCP (docs/stage_register_map.md) and the cooled CCD over GigE Vision
// (docs/camera_features.md), looking at the sample of the config file through the bench's scene.
//
//   gonio-sim                                 # defaults: 3 axes on :5020, camera on 127.0.0.1
//   gonio-sim --config config/sim.toml        # every key documented in that example
//   gonio-sim --port 0 --port-file p.txt      # the OS picks the Modbus port; scripts read p.txt
#include <CLI/CLI.hpp>
#include <atomic>
#include <chrono>
#include <csignal>
#include <fstream>
#include <iostream>
#include <thread>

#include "sim/camera/camera.h"
#include "sim/clock.h"
#include "sim/sim_config.h"
#include "sim/stage/axis.h"
#include "sim/stage/modbus_tcp_server.h"
#include "sim/truth/ground_truth.h"

namespace {
std::atomic<bool> g_stop{false};
void OnSignal(int) { g_stop = true; }
}  // namespace

int main(int argc, char** argv) {
  using namespace gonio::sim;
  CLI::App app{"Simulated gonioreflectometer devices on 127.0.0.1"};
  std::string config_path, port_file;
  int port = -1;
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

  ScaledClock clock(cfg.clock_speed);
  std::vector<std::unique_ptr<SimulatedAxis>> owned;
  std::vector<SimulatedAxis*> raw;
  for (const AxisConfig& a : cfg.axes) {
    owned.push_back(std::make_unique<SimulatedAxis>(clock, a.options));
    raw.push_back(owned.back().get());
  }
  auto server = StageModbusTcpServer::Start(raw, cfg.modbus_port);
  if (!server) {
    std::cerr << "gonio-sim: error: " << server.error().message << "\n";
    return 1;
  }
  const Lamp lamp(cfg.lamp, cfg.seed);
  const Scene scene(cfg.bench, MicrofacetTruth(cfg.sample_model, cfg.sample_alpha, cfg.sample_eta),
                    cfg.scene);
  std::unique_ptr<SimulatedCamera> camera;
  if (cfg.camera_enabled) {
    auto angles = [&cfg, &raw] {
      std::vector<double> steps;
      for (const SimulatedAxis* a : raw) steps.push_back(a->PositionSteps());
      return AnglesFromSteps(cfg.axes, steps);
    };
    auto cam = SimulatedCamera::StartGigE(clock, scene, angles, lamp, cfg.camera);
    if (!cam) {
      std::cerr << "gonio-sim: error: " << cam.error().message << "\n";
      return 1;
    }
    camera = std::move(cam).value();
  }
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  if (!port_file.empty()) std::ofstream(port_file) << (*server)->port() << "\n";
  std::cout << "gonio-sim: stage controller (" << cfg.axes.size() << " axes, unit ids 1.."
            << cfg.axes.size() << ") on Modbus TCP 127.0.0.1:" << (*server)->port();
  if (camera)
    std::cout << "; camera " << cfg.camera.serial << " on GigE Vision " << cfg.camera.address;
  std::cout << "; sample " << scene.truth().Name() << "; clock x" << cfg.clock_speed
            << "; Ctrl-C stops" << std::endl;
  while (!g_stop) std::this_thread::sleep_for(std::chrono::milliseconds(50));
  camera.reset();  // stop the GigE camera before the stages it reads
  std::cout << "gonio-sim: stopped" << std::endl;
  return 0;
}
