#pragma once
/// @file
/// A ray-casting scene over one triangle set in camera coordinates (Embree 3 behind a pimpl).

#include <cstdint>
#include <limits>
#include <memory>
#include <vector>

#include <Eigen/Core>

#include "pbve/core/camera.hpp"
#include "pbve/core/mesh.hpp"

namespace pbve {

/// First hits of the primary rays through a regular grid of (sub-)pixel sample positions.
///
/// The grid has `width` x `height` = (camera width x supersample) x (camera height x
/// supersample) samples, stored row-major (index = y * width + x). Sample (x, y) lies at pixel
/// position ((x + 0.5) / supersample - 0.5, (y + 0.5) / supersample - 0.5), i.e. the
/// supersample x supersample samples of a pixel are the centres of a regular sub-grid of the
/// pixel's square; with supersample = 1 they are the pixel centres (integer coordinates).
struct PrimaryHits {
  int width = 0;        ///< samples per row (camera width x supersample)
  int height = 0;       ///< sample rows (camera height x supersample)
  int supersample = 1;  ///< samples per pixel along each axis
  /// #samples, triangle id of the first hit, -1 where the ray misses the mesh.
  std::vector<std::int32_t> triangle;
  /// #samples, barycentric coordinates of the hit: point = (1 - u - v) a + u b + v c for the
  /// triangle (a, b, c) as listed in the triangle array; undefined where triangle is -1.
  std::vector<float> u, v;
  /// #samples, camera-frame depth z of the hit (mesh units); +infinity where missed.
  std::vector<float> depth;

  /// Pixel coordinates of sample (x, y).
  Eigen::Vector2d sample_position(int x, int y) const {
    return {(x + 0.5) / supersample - 0.5, (y + 0.5) / supersample - 0.5};
  }
  /// Number of samples that hit the mesh.
  std::int64_t hit_count() const;
};

/// First hit of one ray.
struct RayHit {
  std::int32_t triangle = -1;  ///< triangle id, -1 for a miss
  float u = 0.0f;              ///< barycentric coordinate of vertex b
  float v = 0.0f;              ///< barycentric coordinate of vertex c
  float t = 0.0f;              ///< ray parameter of the hit (distance in units of |direction|)
};

/// How RayScene::update() brings the acceleration structure up to date.
enum class UpdateMode {
  refit,    ///< keep the hierarchy, recompute its boxes (cheap; quality degrades under large
            ///< deformation)
  rebuild,  ///< build a new hierarchy
};

/// An Embree scene over one triangle set (all parts of an object in one geometry; triangle ids
/// are row indices of the triangle array), positions in camera coordinates (mesh units).
///
/// Positions change every frame: update() refits the hierarchy (Embree's refit path) instead
/// of rebuilding it. Queries are const and may run concurrently from several threads; they
/// parallelize internally with TBB. The scene keeps a copy of the vertices and triangles it
/// was given (vertices(), triangles()); Embree itself intersects single-precision copies.
/// Both sides of every triangle are hit (no back-face culling).
class RayScene {
 public:
  /// An empty scene (every ray misses).
  RayScene();
  /// Builds the scene. Throws InputError for indices out of range or non-finite positions.
  RayScene(const Vertices& vertices, const Triangles& triangles);
  ~RayScene();
  /// A moved-from RayScene may only be assigned to or destroyed.
  RayScene(RayScene&&) noexcept;
  RayScene& operator=(RayScene&&) noexcept;
  RayScene(const RayScene&) = delete;
  RayScene& operator=(const RayScene&) = delete;

  /// Replaces the mesh (new topology): builds a new hierarchy.
  void set_mesh(const Vertices& vertices, const Triangles& triangles);
  /// New positions for the same triangles (#V by 3, same #V). Throws InputError on a size
  /// mismatch or non-finite positions.
  void update(const Vertices& vertices, UpdateMode mode = UpdateMode::refit);

  int num_vertices() const;
  int num_triangles() const;
  /// #V by 3, the positions of the last set_mesh()/update().
  const Vertices& vertices() const;
  /// #F by 3.
  const Triangles& triangles() const;

  /// First hits of arbitrary rays: `origins` and `directions` are #R by 3 (camera frame);
  /// hits with t in [t_min, t_max] (in units of the direction's length) are reported.
  /// Throws InputError when the numbers of rows differ, t_min or t_max is NaN, or a component
  /// of an origin or direction is not a number of magnitude at most 1.844e18 (the largest
  /// Embree traces; the message names the first such ray).
  std::vector<RayHit> intersect(const Eigen::Ref<const Eigen::MatrixX3d>& origins,
                                const Eigen::Ref<const Eigen::MatrixX3d>& directions,
                                double t_min = 0.0,
                                double t_max = std::numeric_limits<double>::infinity()) const;

  /// For rays from the camera centre (the origin) towards `targets` (#R by 3): 1 where
  /// something is hit with t in (0, t_max), t = 1 being the target itself. t_max slightly
  /// below 1 asks "is the target hidden?". Throws InputError when t_max is NaN or a component
  /// of a target is not a number of magnitude at most 1.844e18 (naming the first such target).
  std::vector<std::uint8_t> occluded_from_origin(const Eigen::Ref<const Eigen::MatrixX3d>& targets,
                                                 double t_max) const;

  /// One primary ray per (sub-)pixel of `camera` (camera at the origin): the first hit
  /// triangle, barycentrics and depth. `supersample` >= 1 samples per pixel along each axis.
  /// Throws InputError for a camera whose rays cannot be cast (see violation_metric()) and for
  /// more than 2^34 samples (width x height x supersample^2; each side within int).
  PrimaryHits cast_primary(const Camera& camera, int supersample = 1) const;

  /// Implementation access for pbve's own sources (opaque outside them).
  struct Impl;
  const Impl& impl() const { return *m_impl; }

 private:
  std::unique_ptr<Impl> m_impl;
};

}  // namespace pbve
