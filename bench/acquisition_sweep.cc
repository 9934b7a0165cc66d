// The sweep engine's efficiency on the simulated instrument (issue #6's speed goal): the physical
// lower bound - the exposure time of every frame taken plus the motion time the stage profiles
// impose along the chosen order - divided by the run's actual time, both in simulated seconds.
// The goal is 0.95. It also reports the share of the bound that darks and ranging frames take,
// and what readout adds, so the gap can be attributed.
//
//   build-release/bench/acquisition_sweep [points_per_incidence=17] [clock_speed=100]
//   build-release/bench/acquisition_sweep soak [points=10000] [clock_speed=100]
//   ./scripts/bench.sh sweep
//
// The soak mode (issue #6: memory stays flat) measures bright geometries only and reports the
// process's resident memory after 100 points and at the end; the goal is within 10 %.
//
// Holds the GigE Vision port 3956 while it runs (one simulated camera per machine).
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>

#include "acquisition/engine.h"
#include "daemon/instrument/instrument.h"
#include "sim/instrument.h"

using namespace gonio;
using namespace gonio::acquisition;

namespace {
// Resident memory of this process, kB (Linux /proc).
long RssKb() {
  std::ifstream in("/proc/self/status");
  std::string key;
  long value = -1;
  while (in >> key) {
    if (key == "VmRSS:") {
      in >> value;
      break;
    }
    in.ignore(1 << 20, '\n');
  }
  return value;
}
}  // namespace

int main(int argc, char** argv) {
  const bool soak = argc > 1 && std::string(argv[1]) == "soak";
  const int first_arg = soak ? 2 : 1;
  const int count = argc > first_arg ? std::atoi(argv[first_arg]) : (soak ? 10000 : 17);
  const double speed = argc > first_arg + 1 ? std::atof(argv[first_arg + 1]) : 100;
  const int per_incidence = soak ? 401 : count;
  if (count < 2 || !(speed > 0)) {
    std::fprintf(stderr,
                 "usage: acquisition_sweep [points_per_incidence >= 2] [clock_speed > 0]\n"
                 "       acquisition_sweep soak [points >= 200] [clock_speed > 0]\n");
    return 2;
  }
  // The simulated instrument (two axes, the camera, the monitor), reached through the backends
  // as goniod reaches it.
  auto started = sim::Instrument::Start(sim::TwoAxisConfig(speed));
  if (!started.ok()) {
    std::fprintf(stderr, "cannot start the simulated instrument: %s\n",
                 started.error().message.c_str());
    return 1;
  }
  sim::Instrument& simulated = **started;
  const sim::Clock& clock = simulated.clock();
  config::InstrumentConfig client = simulated.ClientConfig();
  for (devices::AxisSettings& ax : client.axes) ax.speed_deg_s = 20, ax.acceleration_deg_s2 = 100;
  // The soak reads a 64 x 64 region around the rectangle: many frames, little transfer.
  devices::CameraSettings& cs = client.camera;
  if (soak) cs.roi_x = 224, cs.roi_y = 224, cs.roi_width = 64, cs.roi_height = 64;
  auto opened = daemon::OpenInstrument(client, {{"G1", "glass", 6, 1.51, std::nullopt}});
  if (!opened.ok()) {
    std::fprintf(stderr, "cannot open the backends: %s\n", opened.error().message.c_str());
    return 1;
  }
  daemon::Instrument& in = *opened;
  const std::string db_path =
      (std::filesystem::temp_directory_path() / "gonio_sweep_bench.sqlite").string();
  for (const char* ext : {"", "-wal", "-shm"}) std::filesystem::remove(db_path + ext);
  auto db = Storage::Open(db_path);
  const std::string plan_path = db_path + ".plan.toml";
  std::ofstream plan_file(plan_path);
  plan_file << "sample = \"G1\"\n[geometry]\nview_about = \"refracted\"\n";
  if (soak) {  // bright points only: 401 views within +-2 deg of each lobe's centre
    plan_file << "incidence_deg = [";
    const int incidences = (count + per_incidence - 1) / per_incidence;
    for (int k = 0; k < incidences; ++k) plan_file << (k ? ", " : "") << (k * 60.0 / incidences);
    plan_file << "]\nview_from_deg = -2\nview_to_deg = 2\nview_step_deg = 0.01\n";
  } else {
    plan_file << "incidence_deg = [0, 30, 60, 80]\nview_from_deg = -20\nview_to_deg = 20\n"
              << "view_step_deg = " << 40.0 / (per_incidence - 1) << "\n";
  }
  plan_file << "[exposure]\nframes = 4\ninitial_s = 0.05\nmax_s = 20\n"
            << (soak ? "[rectangle]\nx = 29\ny = 22\nwidth = 6\nheight = 19\n"
                     : "[rectangle]\nx = 253\ny = 246\nwidth = 6\nheight = 19\n");
  plan_file.close();
  PlanContext ctx = in.context;
  ctx.image_width = ctx.image_height = 0;  // the soak's region is smaller than the plan's frame
  auto plan = LoadPlan(plan_path, ctx);
  if (!db.ok() || !plan.ok()) {
    std::fprintf(stderr, "setup: %s\n", (!db.ok() ? db.error() : plan.error()).message.c_str());
    return 1;
  }
  auto points = ExpandPoints(*plan, ctx);
  if (soak && static_cast<int>(points.size()) > count) points.resize(count);
  auto run = (*db)->NewRun(*plan, "bench", points);
  if (!run.ok()) {
    std::fprintf(stderr, "setup: %s\n", run.error().message.c_str());
    return 1;
  }
  Engine engine(*in.stages, *in.camera, in.monitor.monitor.get(), **db,
                EngineOptions{.linear_limit_adu = 40000});
  std::atomic<bool> stop{false};
  const double t0 = clock.Now();
  long rss_100 = 0, rss_end = 0;
  const Status st = engine.Run(*run, *plan, stop, [&](const Progress& p) {
    if (p.done == 100) rss_100 = RssKb();
    rss_end = RssKb();
    if (soak && p.done % 1000 == 0)
      std::fprintf(stderr, "%d/%d points, RSS %ld kB\n", p.done, p.total, rss_end);
  });
  const double elapsed = clock.Now() - t0;
  if (!st.ok()) {
    std::fprintf(stderr, "run failed: %s\n", st.error().message.c_str());
    return 1;
  }
  const EngineStats& e = engine.stats();
  // Motion bound along the order: EstimateSeconds with zero exposure counts only the profiles.
  const double motion = EstimateSeconds(*plan, points, client.axes, 0.0);
  const double bound = e.exposure_s + motion;
  const int all_frames = e.frames + e.ranging_frames + e.dark_frames;
  const auto size = in.camera->ImageSize();
  const int pixels = size.ok() ? size->area() : 512 * 512;
  const double readout = all_frames * simulated.camera()->sensor().ReadoutSeconds(pixels);
  // The readouts that overlapped a move are inside the motion bound already.
  const double readout_alone =
      (all_frames - e.overlapped_readouts) * simulated.camera()->sensor().ReadoutSeconds(pixels);
  std::printf("# Sweep efficiency on the simulated instrument (acquisition_sweep %s%d %g)\n\n",
              soak ? "soak " : "", count, speed);
  std::printf("| quantity | value |\n|---|---|\n");
  std::printf("| points | %d |\n", e.points);
  std::printf("| frames: averaged / ranging / dark | %d / %d / %d |\n", e.frames, e.ranging_frames,
              e.dark_frames);
  std::printf("| exposure, all frames (sim s) | %.1f |\n", e.exposure_s);
  std::printf("| of which darks (sim s) | %.1f |\n", e.dark_exposure_s);
  std::printf("| motion bound along the order (sim s) | %.1f |\n", motion);
  std::printf("| readout, all frames (sim s) | %.1f |\n", readout);
  std::printf("| of which overlapped with the next move: frames (retaken) | %d (%d) |\n",
              e.overlapped_readouts, e.retaken_frames);
  std::printf("| run time (sim s) | %.1f |\n", elapsed);
  std::printf("| **efficiency: (exposure + motion) / run time** | **%.3f** |\n", bound / elapsed);
  std::printf("| efficiency counting the readouts not overlapped as physical | %.3f |\n",
              (bound + readout_alone) / elapsed);
  std::printf("| useful share: averaged frames' exposure / run time | %.3f |\n",
              (e.exposure_s - e.dark_exposure_s) / elapsed);
  if (e.points >= 100)
    std::printf("| resident memory after 100 points / at the end (kB) | %ld / %ld (%+.1f %%) |\n",
                rss_100, rss_end, 100.0 * (rss_end - rss_100) / rss_100);
  for (const char* ext : {"", "-wal", "-shm", ".plan.toml"}) std::filesystem::remove(db_path + ext);
  return 0;
}
