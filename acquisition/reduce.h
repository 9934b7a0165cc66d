// Image reduction: the fixed rectangle of each frame accumulated over the frames of one point.
// Per pixel it keeps the sum and the sum of squares, so that the noise of the rectangle's mean is
// estimated from the pooled per-pixel variance between frames (many degrees of freedom, so the
// uncertainties are honest with a few frames), independent of the scene's gradient across the
// rectangle. Frames are not retained: only two small double images per point.
#pragma once

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
  double Mean() const;                 // over pixels and frames, ADU
  double FrameMeansSd() const;         // sd of the frames' rectangle means (0 for one frame)
  double PixelVariance() const;        // pooled per-pixel variance between frames (needs 2 frames)
  double Max() const { return max_; }  // the brightest pixel seen
  int Saturated() const { return saturated_; }  // pixels at or above clip, summed over frames

 private:
  cv::Rect rect_;
  double clip_;
  int n_ = 0;
  cv::Mat1d sum_, sum2_;
  double frame_sum_ = 0, frame_sum2_ = 0;  // of the frames' means
  double max_ = 0;
  int saturated_ = 0;
};

}  // namespace gonio::acquisition
