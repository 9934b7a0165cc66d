// The rectangle's noise estimates: pixel noise and the frames' common scatter, with and without a
// drift of the lamp during the point (which the monitor normalisation removes, so it is not
// noise).
#include "acquisition/reduce.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

namespace gonio::acquisition {
namespace {

// `frames` frames of a 20 x 20 rectangle: level * (1 + drift * k + common_k) + pixel noise.
RectAccumulator Accumulate(int frames, double level, double drift, double common_sd,
                           double pixel_sd, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> unit(0, 1);
  RectAccumulator acc(cv::Rect(5, 5, 20, 20), 65535);
  for (int k = 0; k < frames; ++k) {
    const double common = drift * k + common_sd * unit(rng);
    cv::Mat1w f(30, 30);
    for (int y = 0; y < f.rows; ++y)
      for (int x = 0; x < f.cols; ++x)
        f(y, x) = cv::saturate_cast<std::uint16_t>(level * (1 + common) + pixel_sd * unit(rng));
    acc.Add(f);
  }
  return acc;
}

TEST(RectAccumulator, PixelNoiseIsEstimatedWithAndWithoutADrift) {
  // 400 pixels x 7 differences: the estimate is within a few % of 25^2.
  for (const double drift : {0.0, 0.02}) {
    const auto acc = Accumulate(8, 20000, drift, 0, 25, 1);
    EXPECT_NEAR(acc.PixelVariance(), 625, 0.1 * 625) << "drift " << drift;
  }
  // The drift is in the frames' spread about their mean: 2 % a frame over 8 frames is 0.049 of
  // the level (980 ADU), far above the pixel noise's 1.25 ADU.
  const auto drifting = Accumulate(8, 20000, 0.02, 0, 25, 1);
  EXPECT_GT(drifting.FrameMeansSd(), 500);
  // Successive differences see a constant step (400 ADU) as a variance of 400^2 / 2: a linear
  // drift is not zero for them, but 6 times smaller than about the mean over 8 frames.
  EXPECT_NEAR(drifting.FrameMeansVariance(), 400.0 * 400 / 2, 0.05 * 400 * 400 / 2);
  EXPECT_LT(drifting.FrameMeansVariance(), 0.2 * std::pow(drifting.FrameMeansSd(), 2));
  // A 5 % common fluctuation is not pixel noise either.
  EXPECT_NEAR(Accumulate(8, 20000, 0, 0.05, 25, 2).PixelVariance(), 625, 0.1 * 625);
}

// A point of one frame has no variance between frames: its pixel noise comes from the frame's own
// pixels. A lobe across the rectangle (a gradient of 1 % a pixel and a curvature), shot noise
// (variance 0.75 ADU per ADU of level) and read noise, one hot pixel; averaged over 400 frames the
// estimate is within 5 % of the pixels' true variance for the demo's 6 x 19 px and antiglare's
// 2 x 6 px rectangle. The dark's variance, which the engine took before, has no shot noise.
TEST(RectAccumulator, OneFramesPixelNoiseComesFromItsOwnPixels) {
  std::mt19937 rng(5);
  std::normal_distribution<double> unit(0, 1);
  for (const auto& [w, h] : {std::pair{6, 19}, std::pair{2, 6}}) {
    double estimated = 0, truth = 0, clean = 0;
    constexpr int kFrames = 400;
    for (int k = 0; k < kFrames; ++k) {
      RectAccumulator acc(cv::Rect(2, 2, w, h), 65535), noiseless(cv::Rect(2, 2, w, h), 65535);
      cv::Mat1w f(h + 4, w + 4), g(h + 4, w + 4);
      double var_sum = 0;
      for (int y = 0; y < f.rows; ++y)
        for (int x = 0; x < f.cols; ++x) {
          const double level = 20000 * (1 + 0.01 * x + 0.005 * y + 2e-4 * x * x);
          const double var = 0.75 * level + 100;
          if (x >= 2 && x < 2 + w && y >= 2 && y < 2 + h) var_sum += var;
          f(y, x) = cv::saturate_cast<std::uint16_t>(level + std::sqrt(var) * unit(rng));
          g(y, x) = cv::saturate_cast<std::uint16_t>(level);
        }
      f(3, 3) = 65000;  // a hot pixel
      acc.Add(f);
      noiseless.Add(g);
      estimated += acc.FirstFrameSpatialVariance() / kFrames;
      truth += var_sum / (w * h) / kFrames;
      clean = std::max(clean, noiseless.FirstFrameSpatialVariance());
    }
    EXPECT_NEAR(estimated / truth, 1.0, 0.05)
        << w << " x " << h << ": " << estimated << " vs " << truth;
    // The lobe alone (rounded to whole ADU) is not noise.
    EXPECT_LT(clean, 0.01 * truth) << w << " x " << h;
  }
  // One pixel has no neighbours to compare with.
  RectAccumulator single(cv::Rect(1, 1, 1, 1), 65535);
  single.Add(cv::Mat1w(3, 3, std::uint16_t{1000}));
  EXPECT_LT(single.FirstFrameSpatialVariance(), 0);
}

// A small rectangle: each frame's mean, which every pixel is taken relative to, holds 1/P of
// each pixel's own noise. Antiglare's auto rectangle is 2 x 6 px: uncorrected, the pixel
// variance came out 11/12 of the truth. Uniform pixels with read-like noise, and a lobe's
// gradient across the rectangle (levels 1 to 4) with shot noise, 4000 points of 4 frames each.
TEST(RectAccumulator, PixelNoiseOfASmallRectangleIsNotShortByThePixelsShareOfTheMean) {
  std::mt19937 rng(11);
  std::normal_distribution<double> unit(0, 1);
  for (const bool gradient : {false, true}) {
    double sum = 0, truth = 0;
    constexpr int kPoints = 4000;
    for (int point = 0; point < kPoints; ++point) {
      RectAccumulator acc(cv::Rect(3, 3, 2, 6), 65535);
      double mean_var = 0;
      for (int k = 0; k < 4; ++k) {
        cv::Mat1w f(10, 10, std::uint16_t(0));
        for (int y = 3; y < 9; ++y)
          for (int x = 3; x < 5; ++x) {
            const double level = gradient ? 5000.0 * (1 + (y - 3) * 0.6) : 20000.0;
            const double var = gradient ? level : 625.0;  // shot (e- = ADU), or read
            if (k == 0) mean_var += var / 12;
            f(y, x) = cv::saturate_cast<std::uint16_t>(level + std::sqrt(var) * unit(rng));
          }
        acc.Add(f);
      }
      sum += acc.PixelVariance() / kPoints;
      truth += mean_var / kPoints;
    }
    // 4000 x 12 x 3 degrees of freedom: the mean is good to about 0.5 %.
    EXPECT_NEAR(sum / truth, 1.0, 0.02) << (gradient ? "a gradient, shot noise" : "uniform");
  }
}

TEST(RectAccumulator, TheFramesCommonScatterIsFoundAbovePixelNoise) {
  // 1 % common fluctuation (200 ADU) on 20000: many draws of 5 frames, pooled as the engine does.
  double excess = 0, weight = 0;
  for (unsigned seed = 0; seed < 400; ++seed) {
    const auto acc = Accumulate(5, 20000, 0, 0.01, 25, seed);
    excess += 4 * (acc.FrameMeansVariance() - acc.PixelVariance() / 400);
    weight += 4;
  }
  EXPECT_NEAR(std::sqrt(excess / weight), 200, 0.05 * 200);
}

// NonIncreasingFit against the definition: among all splits of the sequence into runs, each
// replaced by its weighted mean, the one with non-increasing means and the least weighted sum of
// squares (enumerated; the isotonic fit is always such a split).
TEST(NonIncreasingFit, IsTheLeastSquaresNonIncreasingSequence) {
  EXPECT_EQ(NonIncreasingFit(std::vector<double>{3, 2, 1}, std::vector<double>{1, 1, 1}),
            (std::vector<double>{3, 2, 1}));  // already in order: unchanged
  EXPECT_EQ(NonIncreasingFit(std::vector<double>{1, 3, 2}, std::vector<double>{1, 1, 1}),
            (std::vector<double>{2, 2, 2}));
  const auto weighted = NonIncreasingFit(std::vector<double>{0, 1}, std::vector<double>{3, 1});
  EXPECT_DOUBLE_EQ(weighted[0], 0.25);
  EXPECT_DOUBLE_EQ(weighted[1], 0.25);
  std::mt19937_64 rng(7);
  std::normal_distribution<double> z(0, 1);
  std::uniform_real_distribution<double> u(0.1, 10);
  for (int trial = 0; trial < 200; ++trial) {
    const int n = 1 + trial % 7;
    std::vector<double> v(n), w(n);
    for (int i = 0; i < n; ++i) v[i] = z(rng) - 0.3 * i, w[i] = u(rng);
    const auto fit = NonIncreasingFit(v, w);
    ASSERT_EQ(fit.size(), v.size());
    double best = 1e300;
    std::vector<double> best_fit;
    for (unsigned cuts = 0; cuts < (1u << (n - 1)); ++cuts) {  // bit i: a run ends after i
      std::vector<double> f(n);
      double prev = 1e300, sse = 0;
      bool ordered = true;
      for (int a = 0; a < n && ordered;) {
        int b = a;
        while (b < n - 1 && !(cuts >> b & 1u)) ++b;
        double sw = 0, swv = 0;
        for (int i = a; i <= b; ++i) sw += w[i], swv += w[i] * v[i];
        const double m = swv / sw;
        ordered = m <= prev;
        prev = m;
        for (int i = a; i <= b; ++i) f[i] = m, sse += w[i] * (v[i] - m) * (v[i] - m);
        a = b + 1;
      }
      if (ordered && sse < best) best = sse, best_fit = f;
    }
    for (int i = 0; i < n; ++i) EXPECT_NEAR(fit[i], best_fit[i], 1e-12) << "trial " << trial;
  }
}

}  // namespace
}  // namespace gonio::acquisition
