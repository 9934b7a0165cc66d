// gonio-hw: check each device of the instrument by hand, through the same drivers the daemon
// uses. It reads the instrument config and opens only the device asked for.
//
//   gonio-hw -c config/instrument.toml camera info
//   gonio-hw -c config/instrument.toml camera snap --exposure 0.2 --out frame.png
//       --roi 240,240,32,32    (statistics over a region)
//   gonio-hw -c config/instrument.toml camera cool --setpoint -20 --hold 30
//   gonio-hw -c config/instrument.toml stage status | home | stop
//   gonio-hw -c config/instrument.toml stage move sample=30 arm=210
//   gonio-hw -c config/instrument.toml stage reset sample
//   gonio-hw -c config/instrument.toml monitor read --count 5
//
// Exit codes: 0 done; 1 a device failed (the message says how); 2 bad command line or config.
#include <CLI/CLI.hpp>
#include <cstdio>
#include <iostream>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <sstream>

#include "config/instrument_config.h"
#include "daemon/instrument/instrument.h"

namespace {

using namespace gonio;

int Fail(const Error& e) {
  std::cerr << "gonio-hw: " << e.ToString() << "\n";
  return e.code == ErrorCode::kInvalidArgument ? 2 : 1;
}

Result<cv::Rect> ParseRoi(const std::string& text, const cv::Size& image) {
  if (text.empty()) return cv::Rect(0, 0, image.width, image.height);
  int x, y, w, h;
  char tail;
  if (std::sscanf(text.c_str(), "%d,%d,%d,%d%c", &x, &y, &w, &h, &tail) != 4)
    return InvalidArgument("--roi '" + text + "' must be x,y,width,height");
  const cv::Rect r(x, y, w, h);
  if (w <= 0 || h <= 0 || (r & cv::Rect(0, 0, image.width, image.height)) != r)
    return InvalidArgument("--roi '" + text + "' is not inside the " + std::to_string(image.width) +
                           "x" + std::to_string(image.height) + " image");
  return r;
}

int CameraCommand(const config::InstrumentConfig& cfg, const std::string& action, double exposure,
                  const std::string& out, const std::string& roi_text, double setpoint,
                  double tolerance, double hold, double timeout, bool off) {
  auto cam = daemon::OpenCamera(cfg);
  if (!cam.ok()) return Fail(cam.error());
  devices::Camera& c = **cam;
  const devices::CameraCapabilities caps = c.Capabilities();
  if (action == "info") {
    auto e = c.Exposure();
    if (!e.ok()) return Fail(e.error());
    std::cout << "camera: " << c.Identity() << "\n"
              << "exposure: " << *e << " s\n";
    if (caps.temperature) {
      auto t = c.TemperatureC();
      if (!t.ok()) return Fail(t.error());
      std::cout << "sensor temperature: " << *t << " C\n";
    }
    // What the camera lacks is a capability, not an error.
    std::cout << "has: temperature " << (caps.temperature ? "yes" : "no") << ", cooler "
              << (caps.cooler ? "yes" : "no") << ", shutter " << (caps.shutter ? "yes" : "no")
              << ", exposure-end status " << (caps.exposure_end ? "yes" : "no")
              << ", timestamp latch " << (caps.frame_stamps ? "yes" : "no") << "\n";
    if (!caps.Missing().empty()) std::cout << "note: " << caps.Missing() << "\n";
    return 0;
  }
  if (action == "snap") {
    if (Status s = c.SetExposure(exposure); !s.ok()) return Fail(s.error());
    auto f = c.Snap();
    if (!f.ok()) return Fail(f.error());
    auto roi = ParseRoi(roi_text, f->image.size());
    if (!roi.ok()) return Fail(roi.error());
    const cv::Mat1w view = f->image(*roi);
    cv::Scalar mean, sd;
    cv::meanStdDev(view, mean, sd);
    double lo = 0, hi = 0;
    cv::minMaxLoc(view, &lo, &hi);
    const int full = cfg.camera.pixel_format == "Mono12" ? 4095 : 65535;
    const int saturated = cv::countNonZero(view >= full);
    std::cout << "frame " << f->image.cols << "x" << f->image.rows << ", exposure " << f->exposure_s
              << " s, attempts " << f->attempts << "\n"
              << "roi " << roi->x << "," << roi->y << " " << roi->width << "x" << roi->height
              << ": mean " << mean[0] << " ADU, sd " << sd[0] << ", min " << lo << ", max " << hi
              << ", pixels " << view.total() << ", saturated " << saturated << "\n";
    if (!out.empty()) {
      // 16-bit PNG or TIFF, chosen by the extension; the frame is written as it came.
      if (!cv::imwrite(out, f->image)) return Fail(Error{ErrorCode::kIo, "cannot write " + out});
      std::cout << "wrote " << out << "\n";
    }
    return 0;
  }
  if (action == "cool") {
    if (!caps.cooler) {
      std::cout << "this camera has no cooler: nothing to cool\n";
      return 0;
    }
    if (off) {
      Status s = c.SetCooling(false, 20);
      return s.ok() ? 0 : Fail(s.error());
    }
    devices::TemperatureWait w;
    w.setpoint_c = setpoint;
    w.tolerance_c = tolerance;
    w.hold_s = hold;
    w.timeout_s = timeout;
    std::cout << "cooling to " << setpoint << " C (+- " << tolerance << ", held " << hold
              << " s)..." << std::endl;
    Status s = c.CoolAndWait(w);
    if (!s.ok()) return Fail(s.error());
    if (auto t = c.TemperatureC(); t.ok()) std::cout << "stable at " << *t << " C\n";
    return 0;
  }
  return Fail(InvalidArgument("unknown camera action '" + action + "'"));
}

int StageCommand(const config::InstrumentConfig& cfg, const std::string& action,
                 const std::vector<std::string>& args) {
  auto st = daemon::OpenStages(cfg);
  if (!st.ok()) return Fail(st.error());
  devices::StageController& c = **st;
  auto print = [&](const std::string& name) {
    auto s = c.ReadStatus(name);
    if (!s.ok()) return Fail(s.error());
    char line[160];
    std::snprintf(line, sizeof line, "%-8s %10.4f deg  %s%s%s%s alarm 0x%02X", name.c_str(),
                  s->position_deg, s->ready ? "READY " : "", s->moving ? "MOVE " : "",
                  s->in_position ? "IN-POS " : "", s->homed ? "HOME-END" : "", s->alarm);
    std::cout << line << "\n";
    return 0;
  };
  if (action == "status") {
    int rc = 0;
    if (args.empty()) {
      for (const auto& a : c.axes()) rc = std::max(rc, print(a.name));
    } else {
      for (const auto& a : args) rc = std::max(rc, print(a));
    }
    return rc;
  }
  if (action == "home") {
    Status s = c.Home(args);
    if (!s.ok()) return Fail(s.error());
    for (const auto& a : c.axes()) print(a.name);
    return 0;
  }
  if (action == "move") {
    std::vector<std::pair<std::string, double>> targets;
    for (const std::string& a : args) {
      const auto eq = a.find('=');
      char* end = nullptr;
      const double deg = eq == std::string::npos ? 0 : std::strtod(a.c_str() + eq + 1, &end);
      if (eq == std::string::npos || end == a.c_str() + eq + 1 || *end != '\0')
        return Fail(InvalidArgument("'" + a + "' must be axis=degrees"));
      targets.emplace_back(a.substr(0, eq), deg);
    }
    if (targets.empty()) return Fail(InvalidArgument("move needs axis=degrees"));
    Status s = c.MoveTo(targets);
    if (!s.ok()) return Fail(s.error());
    for (const auto& [name, deg] : targets) print(name);
    return 0;
  }
  if (action == "reset") {
    for (const std::string& a : args)
      if (Status s = c.ResetAlarm(a); !s.ok()) return Fail(s.error());
    return 0;
  }
  if (action == "stop") {
    Status s = c.StopAll();
    return s.ok() ? 0 : Fail(s.error());
  }
  return Fail(InvalidArgument("unknown stage action '" + action + "'"));
}

int MonitorCommand(const config::InstrumentConfig& cfg, const std::string& action, int count) {
  if (!cfg.monitor.enabled) return Fail(InvalidArgument("no [monitor] in the configuration"));
  auto m = daemon::OpenMonitor(cfg);
  if (!m.ok()) return Fail(m.error());
  if (action == "idn") {
    auto id = m->monitor->Identity();
    if (!id.ok()) return Fail(id.error());
    std::cout << *id << "\n";
    return 0;
  }
  if (action == "read") {
    for (int i = 0; i < count; ++i) {
      auto p = m->monitor->PowerW();
      if (!p.ok()) return Fail(p.error());
      std::printf("%.6e W\n", *p);
    }
    return 0;
  }
  return Fail(InvalidArgument("unknown monitor action '" + action + "'"));
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Check the instrument's devices by hand (camera, stages, source monitor)"};
  app.require_subcommand(1);
  std::string config_path;
  app.add_option("-c,--config", config_path, "instrument config (config/instrument.toml)")
      ->required()
      ->check(CLI::ExistingFile);

  std::string cam_action, out, roi;
  double exposure = 0.1, setpoint = -20, tolerance = 0.5, hold = 30, timeout = 900;
  bool off = false;
  CLI::App* cam = app.add_subcommand("camera", "info | snap | cool");
  cam->add_option("action", cam_action)->required()->check(CLI::IsMember({"info", "snap", "cool"}));
  cam->add_option("--exposure", exposure, "seconds (snap)")->check(CLI::PositiveNumber);
  cam->add_option("--out", out, "16-bit PNG or TIFF to write (snap)");
  cam->add_option("--roi", roi, "x,y,width,height for the statistics (snap)");
  cam->add_option("--setpoint", setpoint, "deg C (cool)");
  cam->add_option("--tolerance", tolerance, "deg C (cool)")->check(CLI::PositiveNumber);
  cam->add_option("--hold", hold, "seconds within tolerance (cool)")->check(CLI::NonNegativeNumber);
  cam->add_option("--timeout", timeout, "seconds (cool)")->check(CLI::PositiveNumber);
  cam->add_flag("--off", off, "switch the cooler off (cool)");

  std::string stage_action;
  std::vector<std::string> stage_args;
  CLI::App* stage = app.add_subcommand("stage", "status | home | move | reset | stop");
  stage->add_option("action", stage_action)
      ->required()
      ->check(CLI::IsMember({"status", "home", "move", "reset", "stop"}));
  stage->add_option("args", stage_args, "axis names, or axis=degrees for move");

  std::string mon_action;
  int count = 1;
  CLI::App* mon = app.add_subcommand("monitor", "idn | read");
  mon->add_option("action", mon_action)->required()->check(CLI::IsMember({"idn", "read"}));
  mon->add_option("--count", count, "readings (read)")->check(CLI::Range(1, 100000));

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? 0 : 2;
  }
  auto cfg = gonio::config::LoadInstrumentConfig(config_path);
  if (!cfg.ok()) return Fail(cfg.error());
  if (*cam)
    return CameraCommand(*cfg, cam_action, exposure, out, roi, setpoint, tolerance, hold, timeout,
                         off);
  if (*stage) return StageCommand(*cfg, stage_action, stage_args);
  return MonitorCommand(*cfg, mon_action, count);
}
