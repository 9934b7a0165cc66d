// The latest camera frame, downscaled for the operator's console: what the sensor
// saw at the last point measured, or at the last snap between runs. One frame is kept; a new one
// replaces it. Readers get an immutable copy, so the API threads never wait on the engine.
#pragma once

#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "acquisition/plan.h"

namespace gonio::daemon {

// Each output pixel is the mean of a block of `scale` x `scale` frame pixels (the blocks at the
// right and bottom edges may be smaller). A block with any pixel at or above the linear limit is
// kSaturatedMark instead, so that a saturated pixel is never averaged out of sight.
inline constexpr std::uint16_t kSaturatedMark = 65535;

struct FrameView {
  std::uint64_t seq = 0;            // 1, 2, ... in this process; a new frame, a new number
  std::string source;               // "run" or "snap"
  std::optional<std::int64_t> run;  // the run whose point it was
  std::optional<int> point;         // the point's index
  double exposure_s = 0;
  std::string at;                         // UTC, ISO 8601
  int frame_width = 0, frame_height = 0;  // the camera's frames (region and binning applied)
  int scale = 1;                          // frame pixels per view pixel, each way
  int width = 0, height = 0;              // the view
  int saturated_pixels = 0;               // of the frame, at or above the linear limit
  std::uint16_t min = 0, max = 0;         // of the view, saturated blocks left out of max
  std::optional<acquisition::Rectangle> rectangle;  // the run's, frame pixels
  std::vector<std::uint16_t> pixels;                // row-major, width x height
};

// Downscales `image` so that neither side exceeds max_side (scale = the smallest integer that
// does it). `linear_limit` is in ADU.
FrameView Downscale(const cv::Mat1w& image, int max_side, double linear_limit);

class LatestFrame {
 public:
  explicit LatestFrame(int max_side = 512) : max_side_(max_side) {}
  // Downscales and keeps `image` (the caller's buffer is not kept), numbering it; returns it as
  // kept (a later Put may already have replaced it for Get).
  std::shared_ptr<const FrameView> Put(const cv::Mat1w& image, double linear_limit,
                                       FrameView about);
  std::shared_ptr<const FrameView> Get() const;  // null before the first frame

 private:
  int max_side_;
  mutable std::mutex mu_;
  std::shared_ptr<const FrameView> latest_;
  std::uint64_t seq_ = 0;
};

}  // namespace gonio::daemon
