// goniod's API under load while a sweep runs (issue #7, "Speed"): the latency of GET /status at
// a steady request rate during a simulated sweep (percentiles), and how much that load slows the
// sweep (the same plan measured with and without it). The controller, the API and the simulated
// instrument run in-process on the real drivers (one GigE camera per machine: run alone).
//
//   build/bench/api_latency [requests_per_s=50] [clients=2] [clock_speed=100]
//
// Then, idle, the latency of GET /status with 0, 8, 16 and 100 event-stream clients connected
// (issue #18: 16 are admitted, the rest get 503; 8 used to take every thread), and what refused
// requests cost in memory: the process's resident memory (the daemon's API is in-process) after
// 100 mutations of 100 MB refused with 401, and after 5 request lines of 100 MB (cpp-httplib 0.11
// reads a line whole before its 8 KiB limit answers 414), with the peak while they came.
//
// Prints the percentiles in milliseconds and the slowdown as a ratio; shared, noisy machines make
// single runs rough: repeat and compare ratios.
#include <httplib.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "daemon/api/http_api.h"
#include "daemon/instrument/instrument.h"
#include "daemon/service/controller.h"
#include "sim/instrument.h"
#include "tests/support/raw_http.h"

namespace {

using namespace gonio;
using Clock = std::chrono::steady_clock;

constexpr const char* kPlan = R"(sample = "ground-glass-G1"
[geometry]
incidence_deg = [0, 30]
view_about = "refracted"
view_from_deg = -12
view_to_deg = 12
view_step_deg = 3
[exposure]
frames = 4
initial_s = 0.05
[rectangle]
x = 253
y = 246
width = 6
height = 19
)";

// The process's resident memory now and its peak since the last ResetPeak(), in MiB.
std::pair<double, double> Resident() {
  std::ifstream in("/proc/self/status");
  double rss = 0, hwm = 0;
  for (std::string line; std::getline(in, line);) {
    if (line.rfind("VmRSS:", 0) == 0) rss = std::atof(line.c_str() + 6) / 1024;
    if (line.rfind("VmHWM:", 0) == 0) hwm = std::atof(line.c_str() + 6) / 1024;
  }
  return {rss, hwm};
}
void ResetPeak() { std::ofstream("/proc/self/clear_refs") << "5"; }

// Sends `head` and then `bytes` zeros in 1 MiB pieces on a new connection, stopping when the
// server closes; returns the reply's status line.
std::string SendLarge(int port, const std::string& head, std::size_t bytes) {
  const int fd = gonio::testing::ConnectLoopback(port);
  if (fd < 0) return "(no connection)";
  const std::string chunk(1 << 20, 'a');
  bool open = ::send(fd, head.data(), head.size(), MSG_NOSIGNAL) > 0;
  for (std::size_t sent = 0; open && sent < bytes; sent += chunk.size())
    open = ::send(fd, chunk.data(), chunk.size(), MSG_NOSIGNAL) > 0;
  if (open) ::send(fd, "\r\n\r\n", 4, MSG_NOSIGNAL);
  ::shutdown(fd, SHUT_WR);
  std::string reply;
  char c = 0;
  ssize_t got = 0;
  while ((got = ::recv(fd, &c, 1, 0)) == 1 && c != '\r') reply += c;
  const int err = errno;
  ::close(fd);
  if (reply.empty())
    return got < 0 ? std::string("(no reply: ") + std::strerror(err) + ")" : "(closed)";
  return reply;
}

double Percentile(std::vector<double> v, double p) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<std::size_t>(p * (v.size() - 1) + 0.5))];
}

}  // namespace

int main(int argc, char** argv) {
  const double rate = argc > 1 ? std::atof(argv[1]) : 50;
  const int clients = argc > 2 ? std::atoi(argv[2]) : 2;
  const double speed = argc > 3 ? std::atof(argv[3]) : 100;
  // As goniod does (GONIO_BENCH_GLIBC_DEFAULT=1: glibc's adaptive threshold, for comparison).
  if (std::getenv("GONIO_BENCH_GLIBC_DEFAULT") == nullptr) daemon::ReturnLargeBlocksToTheSystem();
  auto simulated = sim::Instrument::Start(sim::TwoAxisConfig(speed));
  if (!simulated.ok()) {
    std::fprintf(stderr, "api_latency: the simulated instrument did not start: %s\n",
                 simulated.error().ToString().c_str());
    return 1;
  }
  config::InstrumentConfig client = (*simulated)->ClientConfig();
  client.camera.gain_db = 12;
  for (devices::AxisSettings& a : client.axes) a.speed_deg_s = 30, a.acceleration_deg_s2 = 300;
  auto inst = daemon::OpenInstrument(client, {{"ground-glass-G1", "glass", 6, 1.51, std::nullopt}});
  if (!inst.ok()) {
    std::fprintf(stderr, "api_latency: %s\n", inst.error().ToString().c_str());
    return 1;
  }
  const std::string db_path =
      (std::filesystem::temp_directory_path() / "gonio_api_latency.sqlite").string();
  for (const char* ext : {"", "-wal", "-shm"}) std::filesystem::remove(db_path + ext);
  auto db = acquisition::Storage::Open(db_path);
  if (!db.ok()) return 1;
  const acquisition::PlanContext& ctx = inst->context;
  daemon::ControllerOptions co;
  co.run_start.engine.linear_limit_adu = 40000;
  daemon::Controller controller(*inst->stages, *inst->camera, inst->monitor.monitor.get(), **db,
                                ctx, co);
  if (!controller.Start().ok()) return 1;
  const std::string token = daemon::NewToken();
  auto api = daemon::ApiServer::Start(
      controller, {.host = "127.0.0.1", .port = 0, .token = token, .db_path = db_path});
  if (!api.ok()) return 1;
  const int port = (*api)->port();

  // One sweep, timed from submit to idle; with `load`, clients poll /status meanwhile.
  auto sweep = [&](bool load, std::vector<double>* latencies_ms, int* errors) {
    std::atomic<bool> done{false};
    std::vector<std::thread> threads;
    std::vector<std::vector<double>> per(clients);
    std::atomic<int> failed{0};
    if (load)
      for (int c = 0; c < clients; ++c)
        threads.emplace_back([&, c] {
          httplib::Client cli("127.0.0.1", port);
          const auto period = std::chrono::duration<double>(clients / rate);
          auto next = Clock::now();
          while (!done) {
            const auto t0 = Clock::now();
            auto r = cli.Get("/api/v1/status");
            const double ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
            if (!r || r->status != 200)
              ++failed;
            else
              per[c].push_back(ms);
            next += std::chrono::duration_cast<Clock::duration>(period);
            std::this_thread::sleep_until(next);
          }
        });
    const auto t0 = Clock::now();
    auto job = controller.Submit("bench.toml", kPlan);
    if (!job.ok() || !controller.WaitIdle(600)) std::fprintf(stderr, "api_latency: sweep failed\n");
    const double seconds = std::chrono::duration<double>(Clock::now() - t0).count();
    done = true;
    for (auto& t : threads) t.join();
    if (latencies_ms != nullptr)
      for (const auto& v : per) latencies_ms->insert(latencies_ms->end(), v.begin(), v.end());
    if (errors != nullptr) *errors = failed;
    return seconds;
  };

  sweep(false, nullptr, nullptr);  // warm-up: the camera's first frames, page cache
  const double quiet = sweep(false, nullptr, nullptr);
  std::vector<double> lat;
  int errors = 0;
  const double loaded = sweep(true, &lat, &errors);
  const double quiet2 = sweep(false, nullptr, nullptr);
  const double base = 0.5 * (quiet + quiet2);
  std::printf("api_latency: %d clients at %.0f requests/s in all, clock x%.0f, 18-point sweep\n",
              clients, rate, speed);
  std::printf("  GET /api/v1/status during the sweep: %zu requests, %d failed\n", lat.size(),
              errors);
  std::printf("  latency ms: p50 %.2f  p95 %.2f  p99 %.2f  max %.2f\n", Percentile(lat, 0.5),
              Percentile(lat, 0.95), Percentile(lat, 0.99), Percentile(lat, 1.0));
  std::printf("  sweep: %.2f s without load (two runs: %.2f, %.2f), %.2f s with it: ratio %.3f\n",
              base, quiet, quiet2, loaded, loaded / base);
  // /status with stream clients connected (cumulative: 8, then 8 more, then 84 more).
  std::printf(
      "\n| stream clients connected | admitted | GET /status p50 ms | p99 ms | max ms | "
      "failed |\n|---|---|---|---|---|---|\n");
  std::vector<std::unique_ptr<testing::EventStreamClient>> streams;
  int admitted = 0;
  for (const int want : {0, 8, 16, 100}) {
    while (static_cast<int>(streams.size()) < want) {
      streams.push_back(std::make_unique<testing::EventStreamClient>(port));
      admitted += streams.back()->admitted() ? 1 : 0;
    }
    std::vector<double> ms;
    int failed = 0;
    for (int k = 0; k < 200; ++k) {
      httplib::Client cli("127.0.0.1", port);
      cli.set_read_timeout(5);
      const auto t0 = Clock::now();
      auto r = cli.Get("/api/v1/status");
      if (!r || r->status != 200) {
        ++failed;
        continue;
      }
      ms.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
    }
    std::printf("| %d | %d | %.2f | %.2f | %.2f | %d |\n", want, admitted, Percentile(ms, 0.5),
                Percentile(ms, 0.99), Percentile(ms, 1.0), failed);
    errors += failed;
  }
  streams.clear();

  // Refused requests: the memory they leave behind, and the peak while they came.
  std::printf(
      "\n| refused requests | reply | resident MiB before | peak | after |\n"
      "|---|---|---|---|---|\n");
  auto refused = [&](const char* what, int n, const std::string& head, std::size_t bytes) {
    const double before = Resident().first;
    ResetPeak();
    std::string reply;
    for (int k = 0; k < n; ++k) reply = SendLarge(port, head, bytes);
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
    const auto [after, peak] = Resident();
    std::printf("| %s | %s | %.0f | %.0f | %.0f |\n", what, reply.c_str(), before, peak, after);
  };
  refused("100 x POST /api/v1/jobs, 100 MB body, no token", 100,
          "POST /api/v1/jobs HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 100000000\r\n"
          "Content-Type: application/json\r\n\r\n",
          100'000'000);
  refused("5 x request line of 100 MB", 5, "GET /", 100'000'000);
  controller.Shutdown();
  (*api)->Stop();
  for (const char* ext : {"", "-wal", "-shm"}) std::filesystem::remove(db_path + ext);
  return errors == 0 ? 0 : 1;
}
