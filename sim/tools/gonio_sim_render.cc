// gonio-sim-render: what the simulated camera sees in a rectangle, noise-free, at given stage
// angles: the scene of a gonio-sim config rendered as the camera renders it (at the lamp's nominal
// output; the sensor pixels around the rectangle, within 1e-5 of a whole frame's), averaged over
// the rectangle. A diagnostic for coverage runs
// (bench/coverage/value_check.py): a point's stored value against what the scene put into its
// rectangle at the angles the truth log says the stages were at.
//
//   gonio-sim-render --config sim.toml --rect X,Y,W,H < angles.csv > rates.csv
//
// Input: one line per geometry, "sample_deg,arm_deg[,beam_blocked]" (a first line that is not
// numbers is a header; any other is an error naming its line).
// Output: "sample_deg,arm_deg,beam_blocked,rate_e_per_s": the rectangle's mean photo-electron rate
// per sensor pixel.
#include <CLI/CLI.hpp>
#include <algorithm>
#include <cctype>
#include <iomanip>
#include <iostream>
#include <sstream>
#include <string>

#include "sim/scene/scene.h"
#include "sim/sim_config.h"
#include "sim/truth/ground_truth.h"

int main(int argc, char** argv) {
  using namespace gonio::sim;
  CLI::App app{"The simulated camera's noise-free rectangle mean at given stage angles"};
  std::string config_path;
  std::vector<int> rect;
  app.add_option("--config", config_path, "gonio-sim's TOML file")->check(CLI::ExistingFile);
  app.add_option("--rect", rect, "the rectangle: x,y,width,height in sensor pixels")
      ->required()
      ->delimiter(',')
      ->expected(4);
  CLI11_PARSE(app, argc, argv);

  SimConfig cfg = DefaultSimConfig();
  if (!config_path.empty()) {
    auto loaded = LoadSimConfig(config_path);
    if (!loaded) {
      std::cerr << "gonio-sim-render: error: " << loaded.error().message << "\n";
      return 2;
    }
    cfg = std::move(loaded).value();
  }
  const ImageRegion region = cfg.camera.sensor;
  const int x = rect[0], y = rect[1], w = rect[2], h = rect[3];
  if (w <= 0 || h <= 0 || x < 0 || y < 0 || x + w > region.width || y + h > region.height) {
    std::cerr << "gonio-sim-render: error: the rectangle " << x << "," << y << "," << w << "," << h
              << " is not inside the " << region.width << " x " << region.height << " image\n";
    return 2;
  }
  // The sensor pixels around the rectangle only (a whole frame takes seconds): a block on the grid
  // of 8 that Render interpolates a wide lobe's aperture factor on, with 8 pixels to spare.
  ImageRegion around = region;
  around.offset_x = std::max(0, (x / 8 - 1) * 8);
  around.offset_y = std::max(0, (y / 8 - 1) * 8);
  around.width = std::min(region.width, ((x + w + 7) / 8 + 1) * 8) - around.offset_x;
  around.height = std::min(region.height, ((y + h + 7) / 8 + 1) * 8) - around.offset_y;
  const Scene scene(cfg.bench, MicrofacetTruth(cfg.sample_model, cfg.sample_alpha, cfg.sample_eta),
                    cfg.scene);
  std::cout << "sample_deg,arm_deg,beam_blocked,rate_e_per_s\n" << std::setprecision(12);
  std::string line;
  for (int n = 1; std::getline(std::cin, line); ++n) {
    const bool numeric = !line.empty() && (std::isdigit(static_cast<unsigned char>(line[0])) ||
                                           line[0] == '-' || line[0] == '+' || line[0] == '.');
    if (line.empty() || (n == 1 && !numeric)) continue;  // a blank line, or the first a header
    std::istringstream in(line);
    StageAngles a;
    char comma = 0;
    int blocked = 0;
    if (!(in >> a.sample_deg >> comma >> a.arm_deg) || comma != ',') {
      std::cerr << "gonio-sim-render: error: stdin:" << n << ": expected sample_deg,arm_deg\n";
      return 2;
    }
    if (in >> comma >> blocked) a.beam_blocked = blocked != 0;
    const cv::Mat1d rates = scene.Render(a, around);
    const double mean =
        cv::mean(rates(cv::Rect(x - around.offset_x, y - around.offset_y, w, h)))[0];
    std::cout << a.sample_deg << ',' << a.arm_deg << ',' << (a.beam_blocked ? 1 : 0) << ',' << mean
              << '\n';
  }
  return 0;
}
