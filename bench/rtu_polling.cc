// Stage polling on an RS-485 line (issue #19): three axes (slaves 1-3) over Modbus RTU on a pty
// throttled to the line's rate (StageModbusRtuServer::SetLineRate: each request and reply take
// their characters' time, one at a time, as on a half-duplex bus), moved together through a sweep
// by the real driver at several poll intervals. The simulated controllers latch their inputs and
// hold READY off 0.05 s after each motion, as the AZ family does. Prints, per interval, the
// sweep's time against its kinematic time (the profiles, settling and READY delay alone), the
// requests per second on the line and the share of the line they took.
//
//   build/bench/rtu_polling [baud=115200] [steps=10]
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <vector>

#include "backends/modbus_stage.h"
#include "sim/clock.h"
#include "sim/stage/axis.h"
#include "sim/stage/modbus_rtu_server.h"

namespace {

using namespace gonio;

// A trapezoidal (or triangular) profile's duration: distance d at peak speed v, acceleration a.
double ProfileS(double d, double v, double a) {
  return d >= v * v / a ? d / v + v / a : 2 * std::sqrt(d / a);
}

}  // namespace

int main(int argc, char** argv) {
  const int baud = argc > 1 ? std::atoi(argv[1]) : 115200;
  const int steps = argc > 2 ? std::atoi(argv[2]) : 10;
  sim::ScaledClock clock{1.0};
  const double v = 20, a = 100, settle = 0.05, ready_delay = 0.05;  // deg/s, deg/s^2, s, s
  const double step_deg[3] = {2, 4, 6};  // sample, arm, azimuth per sweep step
  const char* names[3] = {"sample", "arm", "azimuth"};
  std::printf(
      "rtu_polling: 3 axes on one %d-baud RTU line, %d sweep steps of %g/%g/%g deg at "
      "%g deg/s\n\n",
      baud, steps, step_deg[0], step_deg[1], step_deg[2], v);
  std::printf(
      "| poll interval ms | sweep s | kinematic s | ratio | requests/s | line busy |\n"
      "|---|---|---|---|---|---|\n");
  for (const double poll : {0.005, 0.02, 0.05}) {
    std::vector<std::unique_ptr<sim::SimulatedAxis>> axes;
    std::vector<sim::SimulatedAxis*> raw;
    for (const char* n : names) {
      sim::AxisOptions o;
      o.settle_s = settle;
      o.latched_inputs = true;
      o.ready_delay_s = ready_delay;
      axes.push_back(std::make_unique<sim::SimulatedAxis>(clock, o, n));
      raw.push_back(axes.back().get());
    }
    auto server = sim::StageModbusRtuServer::Start(raw, {}, nullptr, &clock);
    if (!server.ok()) {
      std::fprintf(stderr, "rtu_polling: %s\n", server.error().ToString().c_str());
      return 1;
    }
    (*server)->SetLineRate(baud);
    devices::ModbusLink link;
    link.kind = devices::ModbusTransport::kRtu;
    link.device = (*server)->pty_path();
    link.baud = baud;
    link.poll_interval_s = poll;
    std::vector<devices::AxisSettings> settings;
    for (int k = 0; k < 3; ++k) {
      devices::AxisSettings s{.name = names[k], .slave_id = k + 1};
      s.min_deg = -360, s.max_deg = 360, s.speed_deg_s = v, s.acceleration_deg_s2 = a;
      settings.push_back(s);
    }
    auto stages = backends::ModbusStageController::Open(link, settings);
    if (!stages.ok()) {
      std::fprintf(stderr, "rtu_polling: %s\n", stages.error().ToString().c_str());
      return 1;
    }
    const int r0 = (*server)->requests();
    const double busy0 = (*server)->line_busy_s();
    const auto t0 = std::chrono::steady_clock::now();
    double kinematic = 0;
    for (int i = 1; i <= steps; ++i) {
      std::vector<std::pair<std::string, double>> targets;
      double longest = 0;
      for (int k = 0; k < 3; ++k) {
        targets.emplace_back(names[k], i * step_deg[k]);
        longest = std::max(longest, ProfileS(step_deg[k], v, a));
      }
      // The profile, then IN-POS after settling; READY (ready_delay after the end) gates the next.
      kinematic += longest + std::max(settle, ready_delay);
      if (Status s = (*stages)->MoveTo(targets); !s.ok()) {
        std::fprintf(stderr, "rtu_polling: step %d: %s\n", i, s.error().ToString().c_str());
        return 1;
      }
    }
    const double took =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const int requests = (*server)->requests() - r0;
    const double busy = (*server)->line_busy_s() - busy0;
    std::printf("| %.0f | %.2f | %.2f | %.3f | %.0f | %.0f %% |\n", poll * 1e3, took, kinematic,
                took / kinematic, requests / took, 100 * busy / took);
  }
  std::printf("\nratio: the sweep's time over its kinematic time (1 = polling costs nothing).\n");
  return 0;
}
