#include "daemon/service/frame_view.h"

#include <algorithm>
#include <chrono>
#include <ctime>

namespace gonio::daemon {
namespace {

std::string UtcIsoNow() {
  const std::time_t t = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buf;
}

}  // namespace

FrameView Downscale(const cv::Mat1w& image, int max_side, double linear_limit) {
  FrameView v;
  v.frame_width = image.cols;
  v.frame_height = image.rows;
  if (image.empty()) return v;
  max_side = std::max(1, max_side);
  const int longest = std::max(image.cols, image.rows);
  v.scale = (longest + max_side - 1) / max_side;
  v.width = (image.cols + v.scale - 1) / v.scale;
  v.height = (image.rows + v.scale - 1) / v.scale;
  v.pixels.assign(static_cast<std::size_t>(v.width) * v.height, 0);
  // Block sums by row, then one pass per block row: the frame is read once, in order.
  std::vector<double> sum(v.width);
  std::vector<int> count(v.width);
  std::vector<char> saturated(v.width);
  v.min = 65535;
  for (int by = 0; by < v.height; ++by) {
    std::fill(sum.begin(), sum.end(), 0.0);
    std::fill(count.begin(), count.end(), 0);
    std::fill(saturated.begin(), saturated.end(), 0);
    const int y1 = std::min(image.rows, (by + 1) * v.scale);
    for (int y = by * v.scale; y < y1; ++y) {
      const std::uint16_t* row = image.ptr<std::uint16_t>(y);
      for (int x = 0; x < image.cols; ++x) {
        const int bx = x / v.scale;
        sum[bx] += row[x];
        ++count[bx];
        if (row[x] >= linear_limit) {
          saturated[bx] = 1;
          ++v.saturated_pixels;
        }
      }
    }
    for (int bx = 0; bx < v.width; ++bx) {
      std::uint16_t& out = v.pixels[static_cast<std::size_t>(by) * v.width + bx];
      if (saturated[bx]) {
        out = kSaturatedMark;
        continue;
      }
      // A mean of pixels below the limit stays below it, and so below the mark.
      out = static_cast<std::uint16_t>(std::min(65534.0, sum[bx] / count[bx] + 0.5));
      v.min = std::min(v.min, out);
      v.max = std::max(v.max, out);
    }
  }
  if (v.min > v.max) v.min = v.max;  // every block saturated
  return v;
}

std::shared_ptr<const FrameView> LatestFrame::Put(const cv::Mat1w& image, double linear_limit,
                                                  FrameView about) {
  FrameView v = Downscale(image, max_side_, linear_limit);
  v.source = std::move(about.source);
  v.run = about.run;
  v.point = about.point;
  v.exposure_s = about.exposure_s;
  v.rectangle = about.rectangle;
  v.at = UtcIsoNow();
  std::lock_guard lock(mu_);
  v.seq = ++seq_;
  latest_ = std::make_shared<const FrameView>(std::move(v));
  return latest_;
}

std::shared_ptr<const FrameView> LatestFrame::Get() const {
  std::lock_guard lock(mu_);
  return latest_;
}

}  // namespace gonio::daemon
