#include "acquisition/reduce.h"

#include <algorithm>
#include <cmath>

namespace gonio::acquisition {

void RectAccumulator::Add(const cv::Mat1w& frame) {
  const cv::Mat1w roi = frame(rect_);
  cv::Mat1d d;
  roi.convertTo(d, CV_64F);
  const double m = cv::mean(d)[0];
  // Each pixel relative to its frame's mean: what every pixel shares (the lamp, its drift) drops
  // out, and pixel noise is left.
  const cv::Mat1d rel = d / std::max(m, 1.0);
  if (n_ == 0) {
    rel_sum_ = cv::Mat1d::zeros(rect_.size());
    rel_sum2_ = cv::Mat1d::zeros(rect_.size());
  } else {
    frame_dsum2_ += (m - last_mean_) * (m - last_mean_);
  }
  rel_sum_ += rel;
  rel_sum2_ += rel.mul(rel);
  last_mean_ = m;
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

double RectAccumulator::FrameMeansVariance() const {
  return n_ < 2 ? 0 : frame_dsum2_ / (2.0 * (n_ - 1));
}

double RectAccumulator::PixelVariance() const {
  if (n_ < 2) return 0;
  // Per pixel: (sum2 - sum^2 / n) / (n - 1) of the relative values; pooled: their mean over the
  // rectangle, back in ADU^2 at the mean level.
  const cv::Mat1d v = (rel_sum2_ - rel_sum_.mul(rel_sum_) / n_) / (n_ - 1);
  const double level = Mean();
  // Dividing by the frame's mean also takes out each pixel's own share of that mean: with r_p a
  // pixel's level over the rectangle's and noise of variance proportional to the level (shot),
  // what is left is (1 - mean(r_p^2) / P) of it, P pixels (11/12 for a uniform 2 x 6 px
  // rectangle, antiglare's: sigma_stat was 4 % short). Corrected; a rectangle whose light is in
  // so few pixels that half its noise moves the mean is taken at half.
  const cv::Mat1d r = rel_sum_ / n_;
  const double keep = std::max(0.5, 1 - cv::mean(r.mul(r))[0] / rect_.area());
  return std::max(0.0, cv::mean(v)[0]) * level * level / keep;
}

std::vector<double> NonIncreasingFit(std::span<const double> values,
                                     std::span<const double> weights) {
  struct Block {
    double mean, weight;
    std::size_t n;
  };
  std::vector<Block> blocks;
  for (std::size_t i = 0; i < values.size(); ++i) {
    blocks.push_back({values[i], weights[i], 1});
    // A block above the one before it violates the order: merge them, and again backwards.
    while (blocks.size() > 1 && blocks.back().mean > blocks[blocks.size() - 2].mean) {
      const Block b = blocks.back();
      blocks.pop_back();
      Block& a = blocks.back();
      a.mean = (a.mean * a.weight + b.mean * b.weight) / (a.weight + b.weight);
      a.weight += b.weight;
      a.n += b.n;
    }
  }
  std::vector<double> out;
  out.reserve(values.size());
  for (const Block& b : blocks) out.insert(out.end(), b.n, b.mean);
  return out;
}

}  // namespace gonio::acquisition
