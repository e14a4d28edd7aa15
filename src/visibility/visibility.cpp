#include "pbve/visibility/visibility.hpp"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <stdexcept>
#include <string>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <Eigen/Geometry>

#include "pbve/core/error.hpp"
#include "visibility/ray_scene_impl.hpp"

namespace pbve {
namespace {

// Triangles per parallel task.
constexpr Eigen::Index triangle_grain = 256;

struct TriangleGeometry {
  Eigen::Vector3d a, b, c;
  double det = 0.0;     // det[a, b, c] = <n, centroid>
  double facing = 0.0;  // s_j
  double area_px = 0.0;
  bool in_front = false;  // all vertices z > 0
  bool front = false;     // in front, non-degenerate and det < 0
};

TriangleGeometry triangle_geometry(const Vertices& vertices, const Triangles& triangles,
                                   Eigen::Index j, const Camera* camera) {
  TriangleGeometry g;
  g.a = vertices.row(triangles(j, 0)).transpose();
  g.b = vertices.row(triangles(j, 1)).transpose();
  g.c = vertices.row(triangles(j, 2)).transpose();
  const Eigen::Vector3d n = (g.b - g.a).cross(g.c - g.a);
  const Eigen::Vector3d centroid = (g.a + g.b + g.c) / 3.0;
  g.det = n.dot(centroid);
  const double scale = std::sqrt(n.squaredNorm() * centroid.squaredNorm());
  g.facing = scale > 0.0 ? g.det / scale : 0.0;
  g.in_front = g.a.z() > 0.0 && g.b.z() > 0.0 && g.c.z() > 0.0;
  g.front = g.in_front && scale > 0.0 && g.det < 0.0;
  if (camera && g.in_front)
    g.area_px = std::abs(camera->fx * camera->fy * g.det / (2.0 * g.a.z() * g.b.z() * g.c.z()));
  return g;
}

void check_options(const VisibilityOptions& options) {
  if (options.samples_per_triangle < 1)
    throw InputError("samples_per_triangle must be at least 1, got " +
                     std::to_string(options.samples_per_triangle));
  if (!(options.min_visible_fraction > 0.0 && options.min_visible_fraction <= 1.0))
    throw InputError("min_visible_fraction must lie in (0, 1], got " +
                     std::to_string(options.min_visible_fraction));
  if (!(options.depth_tolerance >= 0.0 && options.depth_tolerance < 1.0))
    throw InputError("depth_tolerance must lie in [0, 1), got " +
                     std::to_string(options.depth_tolerance));
}

bool inside_image(const Camera& camera, const Eigen::Vector3d& p) {
  const Eigen::Vector2d px = camera.project(p);
  return px.x() >= -0.5 && px.x() <= camera.width - 0.5 && px.y() >= -0.5 &&
         px.y() <= camera.height - 0.5;
}

// Shared implementation; `impl` is null for the back-face-only path.
void visibility_impl(const RayScene::Impl* impl, const Vertices& vertices,
                     const Triangles& triangles, const Camera& camera,
                     const VisibilityOptions& options, TriangleVisibility& result) {
  check_options(options);
  detail::check_ray_camera(camera, "compute_visibility()");
  const Eigen::Index nf = triangles.rows();
  // Every entry is written below; resizing to the same size keeps the buffers.
  result.visible.resize(static_cast<size_t>(nf));
  result.visible_fraction.resize(nf);
  result.projected_area_px.resize(nf);
  result.facing.resize(nf);

  const bool occlusion = options.occlusion && impl != nullptr;
  const Eigen::MatrixX3d pattern = triangle_sample_pattern(options.samples_per_triangle);
  const int ns = static_cast<int>(pattern.rows());
  const float t_max = static_cast<float>(1.0 - options.depth_tolerance);
  std::atomic<std::int64_t> rays{0};

  tbb::parallel_for(
      tbb::blocked_range<Eigen::Index>(0, nf, triangle_grain),
      [&](const tbb::blocked_range<Eigen::Index>& range) {
        // Pending occlusion rays of this task: target point and owning triangle.
        alignas(64) RTCRay16 packet;
        alignas(64) int valid[16];
        Eigen::Index owner[16];
        int pending = 0;
        std::int64_t local_rays = 0;
        RTCIntersectContext context;
        rtcInitIntersectContext(&context);
        context.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
        std::vector<int> seen(static_cast<size_t>(range.size()), 0);

        auto flush = [&]() {
          if (pending == 0) return;
          // Embree's 16-wide queries on an 8-wide ISA may read the masked-off lanes too (and
          // assert on them in builds with assertions): give them a copy of lane 0, whose result
          // is ignored, rather than the previous flush's rays or uninitialised memory.
          for (int k = pending; k < 16; ++k) {
            packet.org_x[k] = packet.org_x[0];
            packet.org_y[k] = packet.org_y[0];
            packet.org_z[k] = packet.org_z[0];
            packet.dir_x[k] = packet.dir_x[0];
            packet.dir_y[k] = packet.dir_y[0];
            packet.dir_z[k] = packet.dir_z[0];
            packet.tnear[k] = packet.tnear[0];
            packet.tfar[k] = packet.tfar[0];
            packet.time[k] = packet.time[0];
            packet.mask[k] = packet.mask[0];
            packet.id[k] = static_cast<unsigned>(k);
            packet.flags[k] = packet.flags[0];
          }
          for (int k = 0; k < 16; ++k) valid[k] = k < pending ? -1 : 0;
          rtcOccluded16(valid, impl->scene, &context, &packet);
          for (int k = 0; k < pending; ++k)
            if (packet.tfar[k] >= 0.0f) ++seen[static_cast<size_t>(owner[k] - range.begin())];
          local_rays += pending;
          pending = 0;
        };

        for (Eigen::Index j = range.begin(); j != range.end(); ++j) {
          const TriangleGeometry g = triangle_geometry(vertices, triangles, j, &camera);
          result.facing[j] = g.facing;
          result.projected_area_px[j] = g.area_px;
          if (!g.front) continue;
          // The projection of a triangle in front of the camera is the triangle of its projected
          // vertices: when these are inside the (convex) image, so are all samples.
          const bool clip =
              options.clip_to_image && !(inside_image(camera, g.a) && inside_image(camera, g.b) &&
                                         inside_image(camera, g.c));
          if (!occlusion && !clip) {
            seen[static_cast<size_t>(j - range.begin())] = ns;
            continue;
          }
          for (int s = 0; s < ns; ++s) {
            const Eigen::Vector3d p =
                pattern(s, 0) * g.a + pattern(s, 1) * g.b + pattern(s, 2) * g.c;
            if (clip && !inside_image(camera, p)) continue;
            if (!occlusion) {
              ++seen[static_cast<size_t>(j - range.begin())];
              continue;
            }
            packet.org_x[pending] = packet.org_y[pending] = packet.org_z[pending] = 0.0f;
            packet.dir_x[pending] = static_cast<float>(p.x());
            packet.dir_y[pending] = static_cast<float>(p.y());
            packet.dir_z[pending] = static_cast<float>(p.z());
            packet.tnear[pending] = 0.0f;
            packet.tfar[pending] = t_max;
            packet.time[pending] = 0.0f;
            packet.mask[pending] = 0xFFFFFFFFu;
            packet.id[pending] = static_cast<unsigned>(pending);
            packet.flags[pending] = 0;
            owner[pending] = j;
            if (++pending == 16) flush();
          }
        }
        flush();
        for (Eigen::Index j = range.begin(); j != range.end(); ++j) {
          const double fraction =
              static_cast<double>(seen[static_cast<size_t>(j - range.begin())]) / ns;
          result.visible_fraction[j] = fraction;
          result.visible[static_cast<size_t>(j)] =
              fraction > 0.0 && fraction >= options.min_visible_fraction ? 1 : 0;
        }
        rays += local_rays;
      });
  result.rays_cast = rays.load();
}

}  // namespace

int TriangleVisibility::visible_count() const {
  int count = 0;
  for (std::uint8_t v : visible) count += v;
  return count;
}

Eigen::MatrixX3d triangle_sample_pattern(int samples_per_triangle) {
  const int k = std::max(1, static_cast<int>(std::floor(std::sqrt(samples_per_triangle + 0.5))));
  Eigen::MatrixX3d pattern(k * k, 3);
  int row = 0;
  // Lattice coordinates (i, l) in units of 1/k along the edges a->b and a->c; upright
  // sub-triangles have corners (i, l), (i + 1, l), (i, l + 1), inverted ones (i + 1, l),
  // (i, l + 1), (i + 1, l + 1).
  for (int i = 0; i < k; ++i) {
    for (int l = 0; l + i < k; ++l) {
      const double wb = (i + 1.0 / 3.0) / k, wc = (l + 1.0 / 3.0) / k;
      pattern.row(row++) << 1.0 - wb - wc, wb, wc;
      if (i + l + 1 < k) {
        const double vb = (i + 2.0 / 3.0) / k, vc = (l + 2.0 / 3.0) / k;
        pattern.row(row++) << 1.0 - vb - vc, vb, vc;
      }
    }
  }
  return pattern;
}

Eigen::VectorXd facing_values(const Vertices& vertices, const Triangles& triangles) {
  check_triangle_indices(triangles, vertices.rows(), "facing_values");
  Eigen::VectorXd s(triangles.rows());
  for (Eigen::Index j = 0; j < triangles.rows(); ++j)
    s[j] = triangle_geometry(vertices, triangles, j, nullptr).facing;
  return s;
}

Eigen::VectorXd projected_areas_px(const Vertices& vertices, const Triangles& triangles,
                                   const Camera& camera) {
  check_triangle_indices(triangles, vertices.rows(), "projected_areas_px");
  Eigen::VectorXd a(triangles.rows());
  for (Eigen::Index j = 0; j < triangles.rows(); ++j)
    a[j] = triangle_geometry(vertices, triangles, j, &camera).area_px;
  return a;
}

void compute_visibility(const RayScene& scene, const Camera& camera,
                        const VisibilityOptions& options, TriangleVisibility& result) {
  visibility_impl(&scene.impl(), scene.vertices(), scene.triangles(), camera, options, result);
}

TriangleVisibility compute_visibility(const RayScene& scene, const Camera& camera,
                                      const VisibilityOptions& options) {
  TriangleVisibility result;
  compute_visibility(scene, camera, options, result);
  return result;
}

TriangleVisibility compute_visibility(RayScene& scene, const Vertices& vertices,
                                      const Camera& camera, const VisibilityOptions& options) {
  scene.update(vertices);
  return compute_visibility(static_cast<const RayScene&>(scene), camera, options);
}

TriangleVisibility compute_visibility(const Vertices& vertices, const Triangles& triangles,
                                      const Camera& camera, const VisibilityOptions& options) {
  if (options.occlusion)
    throw std::invalid_argument(
        "compute_visibility() without a RayScene needs options.occlusion == false");
  for (Eigen::Index j = 0; j < triangles.rows(); ++j)
    for (int k = 0; k < 3; ++k)
      if (triangles(j, k) < 0 || triangles(j, k) >= vertices.rows())
        throw InputError("vertex index out of range", {}, 0, "triangle " + std::to_string(j));
  TriangleVisibility result;
  visibility_impl(nullptr, vertices, triangles, camera, options, result);
  return result;
}

}  // namespace pbve
