#include "pbve/core/camera.hpp"

#include <cmath>
#include <sstream>

#include "core/ray_limits.hpp"
#include "pbve/core/error.hpp"

namespace pbve {

namespace {

std::string describe(double value) {
  std::ostringstream s;
  s << value;
  return s.str();
}

void require_finite_positive(double value, const char* key) {
  if (!std::isfinite(value))
    throw InputError("must be a finite number, got " + describe(value), {}, 0, key);
  if (value <= 0.0) throw InputError("must be positive, got " + describe(value), {}, 0, key);
}

// The ray through pixel (u, v) has the direction ((u - cx) / fx, (v - cy) / fy, 1), handed to
// Embree in single precision. Over the image u runs through [-0.5, width - 0.5], so the largest
// |x component| is max(cx + 0.5, width - 0.5 - cx) / fx, and Embree aborts the process on a
// component beyond detail::max_ray_component (1.844e18: an infinite one, and a finite float
// above it too). Hence the least focal length fx = max(cx + 0.5, width - 0.5 - cx) / 1.844e18:
// 1.7e-16 for a 640-pixel-wide image with cx in its middle, 3.5e-16 with cx at an edge; likewise
// fy with cy and height. A long focal length only makes the components small (they underflow to
// 0, which Embree accepts): there is no upper bound to derive from the rays.
void require_rays_in_range(double f, double c, int size, const char* key) {
  const double edge_px = detail::farthest_edge_px(c, size);
  if (!(edge_px / f <= detail::max_ray_component))
    throw InputError("must be at least " + describe(edge_px / detail::max_ray_component) +
                         " for this image, got " + describe(f) +
                         ": the ray through the image's edge, " + describe(edge_px) +
                         " px from the principal point, would have a direction component of " +
                         describe(edge_px / f) + ", beyond the " +
                         describe(detail::max_ray_component) + " ray casting accepts",
                     {}, 0, key);
}

}  // namespace

void Camera::validate() const {
  require_finite_positive(fx, "camera.fx");
  require_finite_positive(fy, "camera.fy");
  if (width <= 0)
    throw InputError("must be positive, got " + std::to_string(width), {}, 0, "camera.width");
  if (height <= 0)
    throw InputError("must be positive, got " + std::to_string(height), {}, 0, "camera.height");
  if (!std::isfinite(cx)) throw InputError("must be a finite number", {}, 0, "camera.cx");
  if (!std::isfinite(cy)) throw InputError("must be a finite number", {}, 0, "camera.cy");
  // The image covers [-0.5, width - 0.5] x [-0.5, height - 0.5] in pixel coordinates.
  if (cx < -0.5 || cx > width - 0.5)
    throw InputError("principal point x " + describe(cx) + " lies outside the image (width " +
                         std::to_string(width) + ")",
                     {}, 0, "camera.cx");
  if (cy < -0.5 || cy > height - 0.5)
    throw InputError("principal point y " + describe(cy) + " lies outside the image (height " +
                         std::to_string(height) + ")",
                     {}, 0, "camera.cy");
  require_rays_in_range(fx, cx, width, "camera.fx");
  require_rays_in_range(fy, cy, height, "camera.fy");
}

Eigen::Matrix3d Camera::K() const {
  Eigen::Matrix3d k;
  k << fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0;
  return k;
}

}  // namespace pbve
