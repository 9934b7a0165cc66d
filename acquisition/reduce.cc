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
    first_spatial_var_ = FrameSpatialVariance(d);
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

double FrameSpatialVariance(const cv::Mat1d& rect) {
  std::vector<double> scaled;  // each difference squared over its variance in units of sigma^2
  auto second = [&](int n, int lines, auto at) {
    for (int l = 0; l < lines && n >= 3; ++l)
      for (int i = 1; i + 1 < n; ++i) {
        const double d = at(l, i - 1) - 2 * at(l, i) + at(l, i + 1);
        scaled.push_back(d * d / 6);
      }
  };
  auto first = [&](int n, int lines, auto at) {
    if (n != 2) return;
    std::vector<double> d;
    for (int l = 0; l < lines; ++l) d.push_back(at(l, 1) - at(l, 0));
    double mean = 0;  // the gradient, where there are lines to take it from
    if (lines >= 2)
      for (double x : d) mean += x / lines;
    const double var = lines >= 2 ? 2 * (1 - 1.0 / lines) : 2;
    for (double x : d) scaled.push_back((x - mean) * (x - mean) / var);
  };
  auto row = [&](int r, int i) { return rect(r, i); };
  auto col = [&](int c, int i) { return rect(i, c); };
  second(rect.cols, rect.rows, row);
  second(rect.rows, rect.cols, col);
  if (scaled.empty()) first(rect.cols, rect.rows, row), first(rect.rows, rect.cols, col);
  if (scaled.empty()) return -1;
  // A first guess from the median, then the mean of what lies within 3.5 sigma of it: a hot
  // pixel's differences fall out, the noise's lose 0.05 % of their variance.
  std::vector<double> sorted = scaled;
  const auto mid = sorted.begin() + static_cast<std::ptrdiff_t>(sorted.size() / 2);
  std::nth_element(sorted.begin(), mid, sorted.end());
  const double guess = *mid / 0.4549;  // the median of chi-square with 1 dof
  double sum = 0;
  int kept = 0;
  for (double x : scaled)
    if (x <= 12 * guess) sum += x, ++kept;
  return kept > 0 ? sum / kept : guess;
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
