// The cooled CCD's sensor: photo-electrons in, 16-bit counts out. Every term that the acquisition
// engine (#6) must handle is here and nothing more: shot noise, dark current that doubles every
// few degrees C, hot pixels, read noise, bias, full well and saturation, the ADC's range.
//
//   counts = clip(round(bias + (min(N, full_well) + read) / gain_e_per_adu), 0, adc_max)
//   N ~ Poisson(t * (signal_rate + dark(T) * (1 + hot)))
//   dark(T) = dark_ref * 2^((T - T_ref) / doubling)
#pragma once

#include <cstdint>
#include <random>

#include <opencv2/core.hpp>

namespace gonio::sim {

struct SensorOptions {
  double gain_e_per_adu = 1.5;  // at Gain = 0 dB; Gain (dB) divides it by 10^(dB/20)
  double bias_adu = 500;        // the BlackLevel feature's default
  double read_noise_e = 8;
  double full_well_e = 60000;
  double dark_e_per_s_ref = 0.5;  // per sensor pixel at dark_ref_c
  double dark_ref_c = -20;
  double dark_doubling_c = 6;
  double hot_pixel_fraction = 1e-4;    // fixed at power-up from the seed
  double hot_pixel_factor = 300;       // their dark current, in units of a normal pixel's
  double readout_pixel_rate_hz = 1e6;  // readout time = pixels / rate
};

enum class PixelDepth { k12, k16 };  // Mono12 (4095, 16x coarser gain) or Mono16 (65535)

struct ExposureSettings {
  double exposure_s = 0.01;
  double gain_db = 0;
  double black_level_adu = 500;
  double temperature_c = -20;
  PixelDepth depth = PixelDepth::k16;
};

class Sensor {
 public:
  Sensor(int sensor_width, int sensor_height, SensorOptions options, std::uint64_t seed);

  const SensorOptions& options() const { return o_; }
  double DarkCurrent(double temperature_c) const;  // e-/s per normal pixel
  double ReadoutSeconds(int pixels) const { return pixels / o_.readout_pixel_rate_hz; }

  // One frame. rate: e-/s per output pixel (the scene's Render, already binned), covering
  // sensor pixels from (offset_x, offset_y) with the given binning (for hot pixels and dark).
  cv::Mat1w Expose(const cv::Mat1d& rate, int offset_x, int offset_y, int binning_h, int binning_v,
                   const ExposureSettings& s, std::mt19937_64& rng) const;

 private:
  int width_, height_;
  SensorOptions o_;
  cv::Mat1b hot_;  // 1 where a sensor pixel is hot
};

}  // namespace gonio::sim
