// Image reduction: the fixed rectangle of each frame accumulated over the frames of one point.
// The noise of the rectangle's mean is estimated from the pooled per-pixel variance between
// frames (many degrees of freedom, so the uncertainties are honest with a few frames),
// independent of the scene's gradient across the rectangle. Each pixel is taken relative to its
// frame's mean first, so that what all pixels share (the lamp's flicker and its drift during the
// point) is not counted as pixel noise: the engine budgets the lamp apart, and the monitor
// normalisation removes the drift. The frames' common scatter is estimated from successive
// differences (von Neumann 1941: E[sum (x_k+1 - x_k)^2] = 2 (n - 1) var for independent
// scatter), which a slow drift moves less than the spread about the mean (for a linear drift over
// 4 frames, 2.5 times less). Frames are not retained: two small double images per point.
#pragma once

#include <span>
#include <vector>

#include <opencv2/core.hpp>

namespace gonio::acquisition {

class RectAccumulator {
 public:
  // `clip_adu`: values at or above count as saturated.
  RectAccumulator(cv::Rect rect, double clip_adu) : rect_(rect), clip_(clip_adu) {}

  // Adds the rectangle of one frame (precondition: the rectangle lies inside the frame).
  void Add(const cv::Mat1w& frame);

  int frames() const { return n_; }
  int pixels() const { return rect_.area(); }
  double Mean() const;          // over pixels and frames, ADU
  double FrameMeansSd() const;  // sd of the frames' rectangle means (0 for one frame)
  // The same from successive differences: the frames' means' scatter without a drift (0 for one
  // frame).
  double FrameMeansVariance() const;
  // Pooled per-pixel variance between frames, what the pixels share left out (needs 2 frames).
  double PixelVariance() const;
  // The per-pixel variance of the first frame from its own pixels, for a point of one frame
  // (which has no variance between frames): FrameSpatialVariance. -1 before a frame or for a
  // rectangle of one pixel.
  double FirstFrameSpatialVariance() const { return first_spatial_var_; }
  double Max() const { return max_; }           // the brightest pixel seen
  int Saturated() const { return saturated_; }  // pixels at or above clip, summed over frames

 private:
  cv::Rect rect_;
  double clip_;
  int n_ = 0;
  cv::Mat1d rel_sum_, rel_sum2_;  // per pixel, relative to its frame's mean: sum, sum of squares
  double frame_sum_ = 0, frame_sum2_ = 0, frame_dsum2_ = 0, last_mean_ = 0;  // frames' means
  double max_ = 0;
  int saturated_ = 0;
  double first_spatial_var_ = -1;
};

// The per-pixel noise variance of one frame's rectangle (ADU^2) from its own pixels: the shot
// noise of the signal and the dark, and the read noise, without a second frame. Second differences
// x[i-1] - 2 x[i] + x[i+1] along each direction of 3 or more pixels (variance 6 sigma^2 for
// independent pixels; a lobe's gradient across the rectangle cancels, and its curvature over 3
// pixels is far below the noise); for a rectangle of at most 2 x 2, first differences less their
// mean. The mean of their squares within 3.5 sigma of a first guess from their median, so that a
// hot pixel does not count. A pattern fixed in the sensor (a real CCD's photo-response
// non-uniformity, about 1 %) counts as noise here, which errs high. -1 for a single pixel.
double FrameSpatialVariance(const cv::Mat1d& rect);

// The weighted least-squares fit of a sequence by a non-increasing one (the pool-adjacent-
// violators algorithm: Barlow, Bartholomew, Bremner and Brunk 1972): adjacent entries that rise
// are replaced by their weighted mean until none does. The engine fits the lamp's per-exposure
// estimates with it, in order of increasing exposure: flicker averages over a longer exposure,
// so its variance there is no larger, and an exposure met by a point or two borrows from its
// neighbours where its own estimate would rise above theirs. Preconditions: equal sizes, weights
// > 0.
std::vector<double> NonIncreasingFit(std::span<const double> values,
                                     std::span<const double> weights);

}  // namespace gonio::acquisition
