#include "sim/camera/sensor.h"

#include <algorithm>
#include <cmath>

namespace gonio::sim {

Sensor::Sensor(int sensor_width, int sensor_height, SensorOptions options, std::uint64_t seed)
    : width_(sensor_width),
      height_(sensor_height),
      o_(options),
      hot_(sensor_height, sensor_width, std::uint8_t{0}) {
  std::mt19937_64 rng(seed ^ 0x484f54ull);
  std::bernoulli_distribution hot(o_.hot_pixel_fraction);
  for (int j = 0; j < height_; ++j)
    for (int i = 0; i < width_; ++i) hot_(j, i) = hot(rng) ? 1 : 0;
}

double Sensor::DarkCurrent(double temperature_c) const {
  return o_.dark_e_per_s_ref * std::exp2((temperature_c - o_.dark_ref_c) / o_.dark_doubling_c);
}

cv::Mat1w Sensor::Expose(const cv::Mat1d& rate, int offset_x, int offset_y, int binning_h,
                         int binning_v, const ExposureSettings& s, std::mt19937_64& rng) const {
  const double dark = DarkCurrent(s.temperature_c);
  const double adc_max = s.depth == PixelDepth::k16 ? 65535 : 4095;
  const double gain =
      o_.gain_e_per_adu * (s.depth == PixelDepth::k16 ? 1 : 16) / std::pow(10.0, s.gain_db / 20);
  // A binned pixel collects its sensor pixels' charge (full well per sensor pixel, summed).
  const double full_well = o_.full_well_e * binning_h * binning_v;
  std::normal_distribution<double> unit(0, 1);
  cv::Mat1w out(rate.rows, rate.cols);
  for (int j = 0; j < rate.rows; ++j) {
    for (int i = 0; i < rate.cols; ++i) {
      int n_pixels = 0, n_hot = 0;
      for (int dj = 0; dj < binning_v; ++dj) {
        for (int di = 0; di < binning_h; ++di) {
          const int col = offset_x + i * binning_h + di, row = offset_y + j * binning_v + dj;
          if (col >= width_ || row >= height_) continue;
          ++n_pixels;
          n_hot += hot_(row, col);
        }
      }
      const double mean_e =
          s.exposure_s * (rate(j, i) + dark * (n_pixels + n_hot * (o_.hot_pixel_factor - 1)));
      // Poisson shot noise: exact for small means, its normal limit above 1000 e-.
      double electrons;
      if (mean_e < 1000) {
        electrons = std::poisson_distribution<long>(mean_e)(rng);
      } else {
        electrons = std::max(0.0, mean_e + std::sqrt(mean_e) * unit(rng));
      }
      electrons = std::min(electrons, full_well);
      const double counts = s.black_level_adu + (electrons + o_.read_noise_e * unit(rng)) / gain;
      out(j, i) = static_cast<std::uint16_t>(std::clamp(std::round(counts), 0.0, adc_max));
    }
  }
  return out;
}

}  // namespace gonio::sim
