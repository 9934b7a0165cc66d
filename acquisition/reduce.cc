#include "acquisition/reduce.h"

#include <algorithm>
#include <cmath>

namespace gonio::acquisition {

void RectAccumulator::Add(const cv::Mat1w& frame) {
  const cv::Mat1w roi = frame(rect_);
  cv::Mat1d d;
  roi.convertTo(d, CV_64F);
  if (n_ == 0) {
    sum_ = cv::Mat1d::zeros(rect_.size());
    sum2_ = cv::Mat1d::zeros(rect_.size());
  }
  sum_ += d;
  sum2_ += d.mul(d);
  const double m = cv::mean(d)[0];
  frame_sum_ += m;
  frame_sum2_ += m * m;
  double lo = 0, hi = 0;
  cv::minMaxLoc(roi, &lo, &hi);
  max_ = std::max(max_, hi);
  saturated_ += cv::countNonZero(roi >= clip_);
  ++n_;
}

double RectAccumulator::Mean() const { return n_ ? frame_sum_ / n_ : 0; }

double RectAccumulator::FrameMeansSd() const {
  if (n_ < 2) return 0;
  const double m = frame_sum_ / n_;
  return std::sqrt(std::max(0.0, (frame_sum2_ - n_ * m * m) / (n_ - 1)));
}

double RectAccumulator::PixelVariance() const {
  if (n_ < 2) return 0;
  // Per pixel: (sum2 - sum^2 / n) / (n - 1); pooled: their mean over the rectangle.
  const cv::Mat1d v = (sum2_ - sum_.mul(sum_) / n_) / (n_ - 1);
  return std::max(0.0, cv::mean(v)[0]);
}

}  // namespace gonio::acquisition
