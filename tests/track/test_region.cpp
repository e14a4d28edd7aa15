// Contour offsets along one line (the region tracker's per-line estimate).

#include "track/region.hpp"

#include <stdexcept>
#include <vector>

#include <gtest/gtest.h>

namespace pbve::track_detail {
namespace {

// A white object left of the column boundary at x = 63.5 on a black background, and a colour
// model that has seen both.
struct HalfImage {
  cv::Mat bgr{64, 128, CV_8UC3, cv::Scalar(0, 0, 0)};
  ColourModel model;
  HalfImage() {
    bgr.colRange(0, 64).setTo(cv::Scalar(255, 255, 255));
    model.update(std::vector<cv::Vec3b>(50, cv::Vec3b(255, 255, 255)),
                 std::vector<cv::Vec3b>(50, cv::Vec3b(0, 0, 0)), 1.0);
  }
};

ContourPoint point_at(double x) {
  ContourPoint c;
  c.point = Eigen::Vector3d::Zero();
  c.pixel = {x, 32.0};    // the middle row
  c.normal = {1.0, 0.0};  // outwards: towards the background
  return c;
}

TEST(RegionLine, FindsTheBoundaryTwoPixelsOutwards) {
  const HalfImage im;
  const LineEstimate e = estimate_line(im.bgr, im.model, point_at(61.5), LineOptions{});
  ASSERT_TRUE(e.valid);
  // Offsets are whole segments (1 pixel at scale 1): the mean is within half a segment.
  EXPECT_NEAR(e.mean_px, 2.0, 0.5);
  EXPECT_GT(e.inner_foreground, 0.9);
  EXPECT_GT(e.outer_background, 0.9);
}

TEST(RegionLine, OffsetsBeyondTheWorkArraysAreAnError) {
  const HalfImage im;
  LineOptions o;
  o.range = 32;  // 65 offsets: more than the line's work arrays hold
  o.context = 0;
  EXPECT_THROW(estimate_line(im.bgr, im.model, point_at(61.5), o), std::invalid_argument);
  o.range = 20;
  o.context = 13;  // 33 segments either way
  EXPECT_THROW(estimate_line(im.bgr, im.model, point_at(61.5), o), std::invalid_argument);
  o.context = 12;  // the largest line: 32 segments either way, 41 offsets
  const LineEstimate e = estimate_line(im.bgr, im.model, point_at(61.5), o);
  ASSERT_TRUE(e.valid);
  EXPECT_NEAR(e.mean_px, 2.0, 0.5);
}

}  // namespace
}  // namespace pbve::track_detail
