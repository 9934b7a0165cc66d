// The fixed image rectangle's trade (docs/scene.md): a larger rectangle averages more pixels (less
// noise per frame) but sees a wider spread of view directions through the hemisphere, which biases
// the sample away from k f_t cos at the nominal geometry. Prints, per sample and geometry, the
// rectangle mean over the nominal value for several rectangles and sample thicknesses (sphere
// centre offsets), and the scene's rendering cost. Run: scripts/bench.sh scene
#include <chrono>
#include <cmath>
#include <cstdio>

#include "sim/scene/scene.h"
#include "sim/truth/ground_truth.h"

using namespace gonio::sim;

namespace {

// Mean over a w x h mm rectangle at the pole (0.05 mm pixels), relative to the nominal value.
double RectRatio(const Scene& scene, const StageAngles& a, double w_mm, double h_mm) {
  ImageRegion r;
  r.sensor_width = r.sensor_height = 2048;
  r.mm_per_pixel = 0.05;
  r.width = static_cast<int>(std::lround(w_mm / r.mm_per_pixel));
  r.height = static_cast<int>(std::lround(h_mm / r.mm_per_pixel));
  r.offset_x = 1024 - r.width / 2;
  r.offset_y = 1024 - r.height / 2;
  const double mean = cv::mean(scene.Render(a, r))[0] - scene.options().stray_lens_e_per_s;
  const NominalGeometry g = Nominal(scene.bench(), a);
  return mean / (scene.options().electrons_per_s_per_unit * scene.truth().BtdfCos(g.l, g.v));
}

}  // namespace

int main() {
  struct Sample {
    const char* name;
    double alpha;
  };
  const Sample samples[] = {{"ground", 0.344}, {"antiglare", 0.023}};
  std::printf(
      "| sample | thickness mm | theta_i | theta_v - Snell | 3x10 mm | 10x3 mm | 1x3 mm |"
      " 0.3x0.3 mm |\n|---|---|---|---|---|---|---|---|\n");
  for (const Sample& s : samples) {
    for (double thickness : {6.0, 3.0, 9.0}) {
      BenchGeometry b;
      b.sample_thickness_mm = thickness;
      SceneOptions o;
      o.aperture_tolerance = 1e9;  // point values: the geometry alone
      const Scene scene(b, MicrofacetTruth("beckmann", s.alpha, 1.51), o);
      for (double ti : {0.0, 30.0, 60.0}) {
        const double tt = std::asin(std::sin(ti * M_PI / 180) / 1.51) * 180 / M_PI;
        for (double dv : {0.0, 10.0}) {
          if (s.alpha < 0.1 && dv > 0) continue;  // the narrow lobe is dark 10 deg away
          const StageAngles a = StageAnglesFor(ti, -tt + dv);
          std::printf("| %s | %g | %g | %g | %.4f | %.4f | %.4f | %.4f |\n", s.name, thickness, ti,
                      dv, RectRatio(scene, a, 3, 10), RectRatio(scene, a, 10, 3),
                      RectRatio(scene, a, 1, 3), RectRatio(scene, a, 0.3, 0.3));
        }
      }
    }
  }
  // Cost: one 512 x 512 frame of the ground-glass scene (the camera renders once per geometry).
  const Scene scene(BenchGeometry{}, MicrofacetTruth("beckmann", 0.344, 1.51));
  const ImageRegion full;
  const auto t0 = std::chrono::steady_clock::now();
  const int n = 5;
  for (int k = 0; k < n; ++k) scene.Render(StageAnglesFor(30, -10 + k), full);
  const double ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count() / n;
  std::printf("\nrender 512x512 ground glass: %.1f ms per geometry\n", ms);
}
