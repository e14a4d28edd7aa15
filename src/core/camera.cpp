#include "pbve/core/camera.hpp"

#include <cmath>
#include <sstream>

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
}

Eigen::Matrix3d Camera::K() const {
  Eigen::Matrix3d k;
  k << fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0;
  return k;
}

}  // namespace pbve
