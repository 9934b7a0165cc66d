// The console's view of a frame (daemon/service/frame_view.h): block means, saturated pixels never
// averaged away, the scale chosen so that neither side exceeds the bound, and a new number per
// frame kept.
#include "daemon/service/frame_view.h"

#include <gtest/gtest.h>

#include <numeric>

namespace gonio::daemon {
namespace {

TEST(FrameView, BlocksAreMeansAndTheScaleKeepsBothSidesWithinTheBound) {
  cv::Mat1w image(600, 1000);
  for (int y = 0; y < image.rows; ++y)
    for (int x = 0; x < image.cols; ++x) image(y, x) = static_cast<std::uint16_t>(x + 2 * y);
  const FrameView v = Downscale(image, 512, 40000);
  EXPECT_EQ(v.scale, 2);  // 1000 / 512 rounded up
  EXPECT_EQ(v.width, 500);
  EXPECT_EQ(v.height, 300);
  EXPECT_EQ(v.frame_width, 1000);
  EXPECT_EQ(v.frame_height, 600);
  ASSERT_EQ(v.pixels.size(), 500u * 300u);
  // Block (bx, by) holds x in {2bx, 2bx+1}, y in {2by, 2by+1}: mean x + 2y = 2bx + 0.5 + 4by + 1.
  for (int by : {0, 7, 299})
    for (int bx : {0, 13, 499})
      EXPECT_EQ(v.pixels[by * 500 + bx], static_cast<int>(2 * bx + 4 * by + 1.5 + 0.5))
          << bx << "," << by;
  EXPECT_EQ(v.min, 2);  // (0+1+2+3)/4 = 1.5, rounded half up
  EXPECT_EQ(v.saturated_pixels, 0);
}

TEST(FrameView, OneSaturatedPixelMarksItsBlockAndIsCounted) {
  cv::Mat1w image(513, 513, std::uint16_t{100});
  image(300, 17) = 50000;   // above the 40000 ADU linear limit
  image(512, 512) = 40000;  // at it: also past the linear range (the last, partial block)
  const FrameView v = Downscale(image, 256, 40000);
  EXPECT_EQ(v.scale, 3);
  EXPECT_EQ(v.width, 171);
  EXPECT_EQ(v.saturated_pixels, 2);
  EXPECT_EQ(v.pixels[100 * v.width + 5], kSaturatedMark);
  EXPECT_EQ(v.pixels[170 * v.width + 170], kSaturatedMark);
  EXPECT_EQ(v.pixels[100 * v.width + 6], 100);
  EXPECT_EQ(v.max, 100);  // the marked blocks are not values
  EXPECT_EQ(std::count(v.pixels.begin(), v.pixels.end(), kSaturatedMark), 2);
}

TEST(FrameView, ASmallFrameIsKeptWholeAndEachPutIsANewFrame) {
  cv::Mat1w image(4, 6, std::uint16_t{7});
  LatestFrame latest(512);
  EXPECT_EQ(latest.Get(), nullptr);
  FrameView snap;
  snap.source = "snap";
  snap.exposure_s = 0.5;
  latest.Put(image, 65535, snap);
  auto first = latest.Get();
  ASSERT_NE(first, nullptr);
  EXPECT_EQ(first->scale, 1);
  EXPECT_EQ(first->width, 6);
  EXPECT_EQ(first->height, 4);
  EXPECT_EQ(first->source, "snap");
  EXPECT_EQ(first->exposure_s, 0.5);
  EXPECT_FALSE(first->at.empty());
  image(0, 0) = 9;  // the view is a copy: the camera's buffer may be reused
  EXPECT_EQ(first->pixels[0], 7);
  FrameView point;
  point.source = "run";
  point.run = 3;
  point.point = 12;
  const auto put = latest.Put(image, 65535, point);
  auto second = latest.Get();
  EXPECT_EQ(put, second);  // what Put returns is what it kept
  EXPECT_GT(second->seq, first->seq);
  EXPECT_EQ(second->pixels[0], 9);
  EXPECT_EQ(first->pixels[0], 7);  // a reader's copy is not changed under it
  EXPECT_EQ(*second->run, 3);
}

}  // namespace
}  // namespace gonio::daemon
