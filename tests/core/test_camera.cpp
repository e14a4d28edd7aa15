#include "pbve/core/camera.hpp"

#include <cmath>
#include <limits>
#include <string>

#include <gtest/gtest.h>

#include "pbve/core/error.hpp"

namespace {

using pbve::Camera;

Camera test_camera() {
  Camera cam;
  cam.fx = 612.5;
  cam.fy = 598.25;
  cam.cx = 318.0;
  cam.cy = 243.5;
  cam.width = 640;
  cam.height = 480;
  return cam;
}

TEST(Camera, ProjectBackProjectRoundTrip) {
  const Camera cam = test_camera();
  const Eigen::Vector3d points[] = {{0.1, -0.2, 1.5}, {-0.3, 0.25, 0.8}, {0.0, 0.0, 2.0}};
  for (const auto& p : points) {
    const Eigen::Vector2d px = cam.project(p);
    const Eigen::Vector3d back = cam.back_project(px, p.z());
    // Two multiplications and divisions per coordinate: a few ulps of the magnitude.
    EXPECT_LT((back - p).norm(), 1e-14) << p.transpose();
  }
}

TEST(Camera, PrincipalPointProjectsFromOpticalAxis) {
  const Camera cam = test_camera();
  const Eigen::Vector2d px = cam.project({0.0, 0.0, 3.0});
  EXPECT_DOUBLE_EQ(px.x(), cam.cx);
  EXPECT_DOUBLE_EQ(px.y(), cam.cy);
}

TEST(Camera, RayDirectionIsUnitAndThroughPixel) {
  const Camera cam = test_camera();
  const Eigen::Vector2d px(100.0, 400.0);
  const Eigen::Vector3d d = cam.ray_direction(px);
  EXPECT_NEAR(d.norm(), 1.0, 1e-15);
  const Eigen::Vector2d reprojected = cam.project(d * 4.0);
  EXPECT_NEAR(reprojected.x(), px.x(), 1e-12);
  EXPECT_NEAR(reprojected.y(), px.y(), 1e-12);
}

TEST(Camera, IntrinsicMatrixMatchesProjection) {
  const Camera cam = test_camera();
  const Eigen::Matrix3d K = cam.K();
  Eigen::Matrix3d expected;
  expected << 612.5, 0, 318.0, 0, 598.25, 243.5, 0, 0, 1;
  EXPECT_EQ(K, expected);
  const Eigen::Vector3d p(0.2, -0.1, 1.7);
  const Eigen::Vector3d h = K * p;
  EXPECT_NEAR(h.x() / h.z(), cam.project(p).x(), 1e-12);
  EXPECT_NEAR(h.y() / h.z(), cam.project(p).y(), 1e-12);
}

TEST(Camera, ValidateAcceptsDefaultsAndCornerPrincipalPoint) {
  EXPECT_NO_THROW(Camera{}.validate());
  Camera cam = test_camera();
  cam.cx = -0.5;
  cam.cy = cam.height - 0.5;
  EXPECT_NO_THROW(cam.validate());
}

void expect_invalid(const Camera& cam, const std::string& key) {
  try {
    cam.validate();
    FAIL() << "expected InputError for " << key;
  } catch (const pbve::InputError& e) {
    EXPECT_EQ(e.key(), key);
    EXPECT_NE(std::string(e.what()).find(key), std::string::npos) << e.what();
  }
}

TEST(Camera, ValidateNamesTheBadField) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  Camera cam = test_camera();
  cam.fx = 0.0;
  expect_invalid(cam, "camera.fx");
  cam = test_camera();
  cam.fy = -1.0;
  expect_invalid(cam, "camera.fy");
  cam = test_camera();
  cam.fx = nan;
  expect_invalid(cam, "camera.fx");
  cam = test_camera();
  cam.cx = std::numeric_limits<double>::infinity();
  expect_invalid(cam, "camera.cx");
  cam = test_camera();
  cam.cx = 700.0;
  expect_invalid(cam, "camera.cx");
  cam = test_camera();
  cam.cy = -3.0;
  expect_invalid(cam, "camera.cy");
  cam = test_camera();
  cam.width = 0;
  expect_invalid(cam, "camera.width");
  cam = test_camera();
  cam.height = -480;
  expect_invalid(cam, "camera.height");
}

// The ray through pixel (u, v) has direction ((u - cx) / fx, (v - cy) / fy, 1); Embree aborts on
// a component beyond 1.844e18, finite or not. With cx = 318 in a 640-pixel row, the farthest
// edge (u = 639.5) is 321.5 px away: fx must be at least 321.5 / 1.844e18 = 1.7435e-16. With
// cy = 243.5 in 480 rows, the farthest edge (v = -0.5) is 244 px away: fy >= 1.3232e-16.
TEST(Camera, ValidateRefusesFocalLengthsTooShortForTheRaysThroughTheImage) {
  const double fx_min = 321.5 / 1.844e18, fy_min = 244.0 / 1.844e18;
  Camera cam = test_camera();
  cam.fx = 1e-40;
  expect_invalid(cam, "camera.fx");
  cam = test_camera();
  cam.fy = 1e-40;
  expect_invalid(cam, "camera.fy");
  cam = test_camera();
  cam.fx = std::numeric_limits<double>::denorm_min();  // 321.5 / fx overflows a double
  expect_invalid(cam, "camera.fx");
  cam = test_camera();
  cam.fx = 0.99 * fx_min;
  expect_invalid(cam, "camera.fx");
  cam.fx = 1.01 * fx_min;
  EXPECT_NO_THROW(cam.validate());
  cam = test_camera();
  cam.fy = 0.99 * fy_min;
  expect_invalid(cam, "camera.fy");
  cam.fy = 1.01 * fy_min;
  EXPECT_NO_THROW(cam.validate());
  // The bound follows the principal point: at the left edge, the right edge is 640 px away.
  cam = test_camera();
  cam.cx = -0.5;
  cam.fx = 1.01 * fx_min;
  expect_invalid(cam, "camera.fx");
  cam.fx = 1.01 * 640.0 / 1.844e18;
  EXPECT_NO_THROW(cam.validate());
  // The message gives the least focal length and the value.
  cam = test_camera();
  cam.fx = 1e-40;
  try {
    cam.validate();
    FAIL() << "expected InputError";
  } catch (const pbve::InputError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("at least 1.74349e-16"), std::string::npos) << what;
    EXPECT_NE(what.find("got 1e-40"), std::string::npos) << what;
  }
  // A long focal length only makes the components small: no bound.
  cam = test_camera();
  cam.fx = cam.fy = 1e300;
  EXPECT_NO_THROW(cam.validate());
}

}  // namespace
