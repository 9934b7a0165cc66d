// The cooled CCD's sensor and cooler against their closed forms (photon transfer, doubling
// temperature, first-order cooling).
#include <gtest/gtest.h>

#include <cmath>

#include "sim/camera/cooler.h"
#include "sim/camera/sensor.h"

namespace gonio::sim {
namespace {

SensorOptions NoHotPixels() {
  SensorOptions o;
  o.hot_pixel_fraction = 0;
  return o;
}

// Mean and variance (in ADU) of a flat field.
std::pair<double, double> FlatField(const Sensor& s, double rate, double t, double temp,
                                    std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  ExposureSettings e;
  e.exposure_s = t;
  e.temperature_c = temp;
  const cv::Mat1w img = s.Expose(cv::Mat1d(200, 200, rate), 0, 0, 1, 1, e, rng);
  cv::Scalar mean, sd;
  cv::meanStdDev(img, mean, sd);
  return {mean[0], sd[0] * sd[0]};
}

TEST(SensorTest, PhotonTransferMatchesShotAndReadNoise) {
  const Sensor s(200, 200, NoHotPixels(), 7);
  const SensorOptions& o = s.options();
  for (double electrons : {50.0, 2000.0, 30000.0}) {
    const auto [mean, var] = FlatField(s, electrons, 1.0, -60, 11);  // -60 C: no dark current
    const double expected_mean = o.bias_adu + electrons / o.gain_e_per_adu;
    const double expected_var =
        (electrons + o.read_noise_e * o.read_noise_e) / (o.gain_e_per_adu * o.gain_e_per_adu) +
        1.0 / 12;  // quantisation
    const double n = 200 * 200;
    EXPECT_NEAR(mean, expected_mean, 5 * std::sqrt(expected_var / n)) << electrons;
    // The sample variance's standard error is var * sqrt(2 / (n - 1)).
    EXPECT_NEAR(var, expected_var, 5 * expected_var * std::sqrt(2 / (n - 1))) << electrons;
  }
}

TEST(SensorTest, SaturatesAtFullWellAndNeverWraps) {
  const Sensor s(200, 200, NoHotPixels(), 7);
  const SensorOptions& o = s.options();
  std::mt19937_64 rng(1);
  ExposureSettings e;
  e.exposure_s = 10;
  const cv::Mat1w img = s.Expose(cv::Mat1d(10, 10, 1e6), 0, 0, 1, 1, e, rng);
  double lo, hi;
  cv::minMaxLoc(img, &lo, &hi);
  // Clipped at the full well (read noise still adds): bias + 60000 / 1.5 = 40500 ADU.
  EXPECT_NEAR(cv::mean(img)[0], o.bias_adu + o.full_well_e / o.gain_e_per_adu, 30);
  EXPECT_LT(hi, 65535);
  e.depth = PixelDepth::k12;  // 12 bits, 16x coarser: the full well still clips first
  const cv::Mat1w img12 = s.Expose(cv::Mat1d(10, 10, 1e6), 0, 0, 1, 1, e, rng);
  EXPECT_NEAR(cv::mean(img12)[0], o.bias_adu + o.full_well_e / (16 * o.gain_e_per_adu), 2);
  e.black_level_adu = 3500;  // a high black level: now the ADC's 4095 clips
  const cv::Mat1w clipped = s.Expose(cv::Mat1d(10, 10, 1e6), 0, 0, 1, 1, e, rng);
  cv::minMaxLoc(clipped, &lo, &hi);
  EXPECT_EQ(lo, 4095);
}

TEST(SensorTest, DarkCurrentDoublesEveryFewDegrees) {
  const Sensor s(200, 200, NoHotPixels(), 7);
  const SensorOptions& o = s.options();
  const double t = 600;  // long dark frames
  const auto [m1, v1] = FlatField(s, 0, t, o.dark_ref_c, 3);
  const auto [m2, v2] = FlatField(s, 0, t, o.dark_ref_c + o.dark_doubling_c, 4);
  const double d1 = (m1 - o.bias_adu) * o.gain_e_per_adu, d2 = (m2 - o.bias_adu) * o.gain_e_per_adu;
  EXPECT_NEAR(d1, o.dark_e_per_s_ref * t, 0.02 * o.dark_e_per_s_ref * t);
  EXPECT_NEAR(d2 / d1, 2.0, 0.03);
}

TEST(SensorTest, HotPixelsAreFixedAndAsFrequentAsConfigured) {
  SensorOptions o;
  o.hot_pixel_fraction = 1e-3;
  const Sensor s(400, 400, o, 9);
  std::mt19937_64 rng(2);
  ExposureSettings e;
  e.exposure_s = 100;
  const cv::Mat1w a = s.Expose(cv::Mat1d(400, 400, 0.0), 0, 0, 1, 1, e, rng);
  const cv::Mat1w b = s.Expose(cv::Mat1d(400, 400, 0.0), 0, 0, 1, 1, e, rng);
  // A hot pixel collects 300x the dark charge: 15000 e- against 50 e-.
  const cv::Mat hot_a = a > o.bias_adu + 5000, hot_b = b > o.bias_adu + 5000;
  const int n = cv::countNonZero(hot_a);
  EXPECT_NEAR(n, 160, 4 * std::sqrt(160.0));
  EXPECT_EQ(cv::countNonZero(hot_a != hot_b), 0);  // the same pixels in every frame
}

TEST(CoolerTest, ApproachesTheSetpointWithItsTimeConstant) {
  CoolerOptions o;
  Cooler c(o, 0);
  c.SetSetpoint(-10, 0);
  c.SetEnabled(true, 0);
  EXPECT_NEAR(c.Temperature(o.time_constant_s), -10 + 30 / std::exp(1.0), 1e-9);
  EXPECT_NEAR(c.Temperature(20 * o.time_constant_s), -10, 1e-6);
  EXPECT_EQ(c.PowerPercent(1), 100);  // pulling down: full drive
}

TEST(CoolerTest, CannotCoolBelowItsPowerLimitAndWarmsWhenItFails) {
  CoolerOptions o;
  Cooler c(o, 0);
  c.SetSetpoint(-60, 0);
  c.SetEnabled(true, 0);
  EXPECT_NEAR(c.Temperature(1e4), o.ambient_c - o.max_delta_c, 1e-6);
  c.SetFailed(true, 1e4);
  EXPECT_NEAR(c.Temperature(1e4 + o.time_constant_s), o.ambient_c - o.max_delta_c / std::exp(1.0),
              1e-9);
  EXPECT_EQ(c.PowerPercent(1e4 + 1), 0);
}

}  // namespace
}  // namespace gonio::sim
