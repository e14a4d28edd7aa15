#pragma once
/// @file
/// Per-triangle visibility from the camera: the paper's back-face test plus occlusion.
///
/// Camera at the origin, OpenCV axes. For triangle j = (a, b, c) with normal
/// n_j = (b - a) x (c - a) and centroid c_j, the facing value is
/// \f[ s_j = \frac{\langle n_j, c_j \rangle}{|n_j|\,|c_j|} \in [-1, 1], \f]
/// negative when the triangle faces the camera (the paper's test: visible iff
/// <n_j, c_j> < 0). Note <n_j, c_j> = <n_j, a> = det[a, b, c].

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "pbve/core/camera.hpp"
#include "pbve/core/mesh.hpp"
#include "pbve/visibility/ray_scene.hpp"

namespace pbve {

/// Settings of compute_visibility().
struct VisibilityOptions {
  /// Test occlusion by ray casting (true) or only the paper's back-face test (false).
  bool occlusion = true;
  /// Sample points per triangle for the occlusion and image-bounds tests. Rounded down to a
  /// square k^2 (at least 1): the triangle is split into k^2 congruent sub-triangles and the
  /// samples are their centroids, so each sample stands for 1/k^2 of the triangle's area. The
  /// pattern contains the centroid when k is not a multiple of 3 (k = 1, 2, 4, 5, ...).
  int samples_per_triangle = 4;
  /// A front-facing triangle is visible when visible_fraction >= this value (0 < value <= 1).
  double min_visible_fraction = 0.5;
  /// Sample points projecting outside the image ([-0.5, width - 0.5] x [-0.5, height - 0.5])
  /// do not count as visible: texture outside the frame is unknown.
  bool clip_to_image = true;
  /// A sample is hidden when something is hit closer than (1 - depth_tolerance) times its
  /// distance; the tolerance absorbs single-precision ray-triangle round-off.
  double depth_tolerance = 1e-4;
};

/// Per-triangle visibility; every vector has #F entries.
struct TriangleVisibility {
  /// 1 when the triangle is visible: all vertices in front of the camera (z > 0), front-facing
  /// (<n_j, c_j> < 0) and visible_fraction >= min_visible_fraction.
  std::vector<std::uint8_t> visible;
  /// Fraction of the triangle's sample points that are seen (inside the image when clipping,
  /// not hidden when testing occlusion); 1 for a front-facing triangle when neither test runs,
  /// 0 for triangles that are back-facing or (partly) behind the camera.
  Eigen::VectorXd visible_fraction;
  /// Area of the triangle's projection, pixels^2 (absolute value, unclipped, not reduced by
  /// occlusion); 0 when a vertex has z <= 0. For z > 0 the signed area in pixel coordinates is
  /// fx fy det[a, b, c] / (2 z_a z_b z_c), negative for front-facing triangles.
  Eigen::VectorXd projected_area_px;
  /// Facing value s_j (see the file comment); 0 for degenerate triangles.
  Eigen::VectorXd facing;
  /// Number of occlusion rays cast.
  std::int64_t rays_cast = 0;

  int num_triangles() const { return static_cast<int>(visible.size()); }
  int visible_count() const;
};

/// Facing values s_j, #F (see the file comment); 0 for degenerate triangles or centroids at
/// the camera centre.
Eigen::VectorXd facing_values(const Vertices& vertices, const Triangles& triangles);

/// Absolute projected areas in pixels^2, #F (0 when a vertex has z <= 0).
Eigen::VectorXd projected_areas_px(const Vertices& vertices, const Triangles& triangles,
                                   const Camera& camera);

/// Visibility of the triangles of `scene` (its current positions) seen by `camera`.
TriangleVisibility compute_visibility(const RayScene& scene, const Camera& camera,
                                      const VisibilityOptions& options = {});

/// As above, writing into `result`: its buffers are reused, so calling this every frame on a
/// mesh of constant size allocates nothing.
void compute_visibility(const RayScene& scene, const Camera& camera,
                        const VisibilityOptions& options, TriangleVisibility& result);

/// Refits `scene` to `vertices` (same triangles) and computes the visibility.
TriangleVisibility compute_visibility(RayScene& scene, const Vertices& vertices,
                                      const Camera& camera, const VisibilityOptions& options = {});

/// Visibility without a ray scene: requires options.occlusion == false (throws
/// std::invalid_argument otherwise).
TriangleVisibility compute_visibility(const Vertices& vertices, const Triangles& triangles,
                                      const Camera& camera, const VisibilityOptions& options);

/// The sample pattern of VisibilityOptions::samples_per_triangle: k^2 rows of barycentric
/// weights (w_a, w_b, w_c), each row summing to 1.
Eigen::MatrixX3d triangle_sample_pattern(int samples_per_triangle);

}  // namespace pbve
