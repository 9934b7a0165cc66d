// gonio-sim: serves the simulated instrument's devices on loopback until interrupted. So far the
// rotation stages over Modbus TCP (docs/stage_register_map.md); the camera, the source monitor
// and the config file arrive with issue #4.
//
//   gonio-sim --axes 3 --port 5020            # real time; Ctrl-C stops it
//   gonio-sim --port 0 --port-file p.txt      # the OS picks the port; scripts read it from p.txt
#include <CLI/CLI.hpp>
#include <atomic>
#include <chrono>
#include <csignal>
#include <fstream>
#include <iostream>
#include <thread>

#include "sim/clock.h"
#include "sim/stage/axis.h"
#include "sim/stage/modbus_tcp_server.h"

namespace {
std::atomic<bool> g_stop{false};
void OnSignal(int) { g_stop = true; }
}  // namespace

int main(int argc, char** argv) {
  using namespace gonio::sim;
  CLI::App app{"Simulated gonioreflectometer devices on 127.0.0.1"};
  int axes = 3, port = 5020;
  double speed = 1.0;
  std::string port_file;
  app.add_option("--axes", axes, "rotation-stage axes (Modbus unit ids 1..N)")
      ->check(CLI::Range(1, 8))
      ->capture_default_str();
  app.add_option("--port", port, "Modbus TCP port on 127.0.0.1 (0: any free port)")
      ->check(CLI::Range(0, 65535))
      ->capture_default_str();
  app.add_option("--speed", speed, "simulated seconds per real second")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_option("--port-file", port_file, "write the chosen port to this file");
  CLI11_PARSE(app, argc, argv);

  ScaledClock clock(speed);
  std::vector<std::unique_ptr<SimulatedAxis>> owned;
  std::vector<SimulatedAxis*> raw;
  for (int k = 0; k < axes; ++k) {
    owned.push_back(std::make_unique<SimulatedAxis>(clock));
    raw.push_back(owned.back().get());
  }
  auto server = StageModbusTcpServer::Start(raw, port);
  if (!server) {
    std::cerr << "gonio-sim: error: " << server.error().message << "\n";
    return 1;
  }
  std::signal(SIGINT, OnSignal);
  std::signal(SIGTERM, OnSignal);
  if (!port_file.empty()) std::ofstream(port_file) << (*server)->port() << "\n";
  std::cout << "gonio-sim: stage controller (" << axes << " axes, unit ids 1.." << axes
            << ") on Modbus TCP 127.0.0.1:" << (*server)->port() << ", clock x" << speed
            << "; Ctrl-C stops" << std::endl;
  while (!g_stop) std::this_thread::sleep_for(std::chrono::milliseconds(50));
  std::cout << "gonio-sim: stopped" << std::endl;
  return 0;
}
