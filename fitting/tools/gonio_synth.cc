// gonio-synth: writes a synthetic sweep (fitting/synthetic.h) as a samples CSV, to try gonio-fit
// without an instrument and to feed the benchmark peers the same data.
//
//   gonio-synth out.csv --model ggx --width 0.394 --scale 0.755 --incidences 0,30,60,80
#include <CLI/CLI.hpp>
#include <iostream>

#include "fitting/samples_csv.h"
#include "fitting/synthetic.h"

int main(int argc, char** argv) {
  using namespace gonio::fitting;
  CLI::App app{"Write a synthetic BTDF*cos (or BRDF*cos) sweep of a known model as CSV"};
  SyntheticSweep spec;
  std::string out, model = "beckmann";
  app.add_option("out", out, "CSV file to write")->required();
  app.add_option("--model", model, "beckmann, ggx, phong or sun2008")->capture_default_str();
  app.add_option("--width", spec.width, "alpha, exponent or s")->capture_default_str();
  app.add_option("--scale", spec.scale, "k")->capture_default_str();
  app.add_option("--eta", spec.eta)->capture_default_str();
  app.add_option("--incidences", spec.theta_l_deg, "theta_l in degrees")->delimiter(',');
  std::string side = "transmission";
  app.add_option("--side", side, "transmission or reflection (the camera on the light side)")
      ->check(CLI::IsMember({"transmission", "reflection"}))
      ->capture_default_str();
  app.add_option("--step", spec.theta_v_step, "view step (deg)")->capture_default_str();
  app.add_option("--fine-step", spec.fine_step, "finer view step near the peak (deg, 0: none)");
  app.add_option("--fine-half-width", spec.fine_half_width, "half width of the fine region (deg)");
  app.add_option("--peak-electrons", spec.peak_electrons, "signal level; <= 0: noise-free")
      ->capture_default_str();
  app.add_option("--read-noise", spec.read_noise_electrons, "electrons rms")->capture_default_str();
  app.add_option("--seed", spec.seed)->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  auto family = ParseFamily(model);
  if (!family) {
    std::cerr << "gonio-synth: error: --model: unknown model '" << model << "'\n";
    return 2;
  }
  if (!(spec.width > 0) || !(spec.scale > 0) || !(spec.eta > 1) || !(spec.theta_v_step > 0)) {
    std::cerr << "gonio-synth: error: width, scale and step must be > 0 and eta > 1\n";
    return 2;
  }
  if (side == "reflection" && !HasBrdf(*family)) {
    std::cerr << "gonio-synth: error: --model " << model << " has no BRDF (transmission only)\n";
    return 2;
  }
  spec.model.family = *family;
  spec.reflection = side == "reflection";
  const auto samples = MakeSyntheticSweep(spec);
  if (auto s = WriteSamplesCsv(out, samples); !s) {
    std::cerr << "gonio-synth: error: " << s.error().message << "\n";
    return 1;
  }
  std::cout << "gonio-synth: wrote " << samples.size() << " samples to " << out << "\n";
  return 0;
}
