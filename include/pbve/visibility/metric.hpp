#pragma once
/// @file
/// The violation metric (the paper's Figure 7 measure), by primary-ray casting.

#include <cstdint>
#include <vector>

#include "pbve/core/camera.hpp"
#include "pbve/visibility/ray_scene.hpp"

namespace pbve {

/// Settings of violation_metric().
struct MetricOptions {
  /// Primary rays per pixel along each axis (supersample^2 rays per pixel), at least 1. At most
  /// 2^34 (1.7e10) rays in all: width x height x supersample^2 <= 2^34, which allows up to 236
  /// at 640x480 (minutes of casting) and 91 at 1920x1080.
  int supersample = 1;
  /// Also count samples whose first hit is the back side of a triangle as violating (for open
  /// surfaces such as a single-sheet cloth, whose back side was never observed). Off by
  /// default: the paper's definition only looks at which triangle is seen.
  bool back_faces_violate = false;
};

/// Output-frame areas, pixels^2 (sample counts divided by supersample^2).
struct ViolationMetric {
  /// 100 x violating_area_px / object_area_px; 0 when the object covers no pixel.
  double violation_pct = 0.0;
  /// Area covered by the object (any triangle is the first hit): the visible object area.
  double object_area_px = 0.0;
  /// Area whose first hit is a triangle not observed in the input frame and not interior.
  double violating_area_px = 0.0;
  /// Area whose first hit is an interior triangle (excluded from the constraint).
  double interior_area_px = 0.0;
  /// Number of primary rays cast.
  std::int64_t rays_cast = 0;
};

/// Casts one primary ray per (sub-)pixel against `simulated` (the simulated mesh, camera
/// frame) and measures the area of violating triangles.
///
/// @param camera            intrinsics and image size; the principal point may lie outside the
///                          image, but the rays must be castable (as for Camera::validate())
/// @param observed_in_input #F, v_j: 1 when triangle j is observed (visible) in the input frame
/// @param interior          #F, 1 for interior (fracture) faces, or empty for none
/// Throws InputError when a non-empty vector does not have #F entries, for a camera whose rays
/// cannot be cast (a focal length that is not positive and finite, or so short that the rays
/// through the image's edges have direction components beyond 1.844e18; a non-finite principal
/// point; an empty image), and for options.supersample < 1 or above the limit of
/// MetricOptions::supersample (2^34 rays; width x supersample and height x supersample within
/// int).
ViolationMetric violation_metric(const RayScene& simulated, const Camera& camera,
                                 const std::vector<std::uint8_t>& observed_in_input,
                                 const std::vector<std::uint8_t>& interior,
                                 const MetricOptions& options = {});

}  // namespace pbve
