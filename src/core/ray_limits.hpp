#pragma once
// Internal: the largest ray components pbve's ray casting (Embree 3, single precision) accepts,
// shared by Camera::validate() and the RayScene queries.

#include <algorithm>
#include <cmath>

namespace pbve::detail {

/// Largest magnitude of a ray origin or direction component that Embree traces. Its traversal
/// asserts |component| <= FLT_LARGE = 1.844e18 for every ray (Ray::valid() in its
/// kernels/common/ray.h; about sqrt(FLT_MAX) / 10: the product of two such numbers is still
/// finite in float) and aborts the process when a ray fails it: a NaN or infinite component, and
/// also a finite float above this bound (a direction of 1e20 aborts as an infinite one does). Rays
/// are checked against it before they are handed to Embree.
inline constexpr double max_ray_component = 1.844e18;

/// True when `x` is a number Embree accepts as a ray component (false for NaN).
inline bool ray_component_ok(double x) {
  return std::abs(x) <= max_ray_component;
}

/// The largest |u - c| over the pixel coordinates u in [-0.5, size - 0.5] along one image axis
/// with principal point c (pixels): the ray direction component (u - c) / f is at most this over
/// f in magnitude over the image. Every sample pbve casts, supersampled or not, lies inside its
/// pixel, so within this range. At most `size` when c lies in the image.
inline double farthest_edge_px(double c, int size) {
  return std::max(std::abs(c + 0.5), std::abs(size - 0.5 - c));
}

}  // namespace pbve::detail
