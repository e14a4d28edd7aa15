#pragma once
// Implementation details of RayScene shared by the visibility sources.

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <sstream>
#include <string>

#include <embree3/rtcore.h>
#include <tbb/blocked_range2d.h>
#include <tbb/parallel_for.h>

#include "core/ray_limits.hpp"
#include "pbve/core/error.hpp"
#include "pbve/visibility/ray_scene.hpp"

namespace pbve {

struct RayScene::Impl {
  std::shared_ptr<RTCDeviceTy> device;  // process-wide device
  RTCScene scene = nullptr;
  RTCGeometry geometry = nullptr;
  float* vertex_buffer = nullptr;  // owned by the geometry, #V x 3 floats (+ padding)
  Vertices vertices;
  Triangles triangles;

  Impl();
  ~Impl();
  Impl(const Impl&) = delete;
  Impl& operator=(const Impl&) = delete;
  void release();
  void build(const Vertices& v, const Triangles& t);
  void refit(const Vertices& v, UpdateMode mode);
  void commit();
};

namespace detail {

/// Throws InputError unless the camera's rays can be cast: positive finite focal lengths, a
/// finite principal point (which may lie outside the image: a camera for a part of it), a
/// positive image size, and ray direction components over the image within
/// max_ray_component (see Camera::validate()). Embree aborts the process on a ray outside
/// these (its assertions are on). `function` names the caller in the message.
inline void check_ray_camera(const Camera& camera, const char* function) {
  const auto message = [&](const std::string& what) {
    std::ostringstream s;
    s << function << ": " << what << " (fx " << camera.fx << ", fy " << camera.fy << ", cx "
      << camera.cx << ", cy " << camera.cy << ", " << camera.width << "x" << camera.height << ")";
    return s.str();
  };
  if (!(camera.fx > 0.0) || !(camera.fy > 0.0) || !std::isfinite(camera.fx) ||
      !std::isfinite(camera.fy) || !std::isfinite(camera.cx) || !std::isfinite(camera.cy) ||
      camera.width <= 0 || camera.height <= 0)
    throw InputError(
        message("the camera needs positive finite focal lengths, a finite principal point and a "
                "positive image size"));
  const double slope = std::max(farthest_edge_px(camera.cx, camera.width) / camera.fx,
                                farthest_edge_px(camera.cy, camera.height) / camera.fy);
  if (!(slope <= max_ray_component)) {
    std::ostringstream s;
    s << "the camera's rays through the image's edges would have direction components up to "
      << slope << ", beyond the " << max_ray_component << " ray casting accepts";
    throw InputError(message(s.str()));
  }
}

/// Most rays one primary-ray query casts: 2^34, about 1.7e10 (cast_primary() would store 16
/// bytes per ray, 256 GiB; violation_metric() stores nothing per ray, but would cast for minutes).
inline constexpr long long max_primary_rays = 1LL << 34;

/// Throws InputError unless `supersample` samples per pixel along each axis of `camera`'s
/// image (already checked by check_ray_camera()) can be cast by for_each_primary(): supersample
/// >= 1, both sides of the sample grid (width x supersample, height x supersample) within int,
/// and at most max_primary_rays samples in all. `function` names the caller in the message.
inline void check_primary_rays(const Camera& camera, int supersample, const char* function) {
  if (supersample < 1)
    throw InputError(std::string(function) + ": supersample must be at least 1, got " +
                     std::to_string(supersample));
  const long long w = static_cast<long long>(camera.width) * supersample;
  const long long h = static_cast<long long>(camera.height) * supersample;
  // The product is formed only once both factors are known to be within int: no overflow.
  if (w > std::numeric_limits<int>::max() || h > std::numeric_limits<int>::max() ||
      w * h > max_primary_rays)
    throw InputError(
        std::string(function) + ": supersample " + std::to_string(supersample) + " of a " +
        std::to_string(camera.width) + "x" + std::to_string(camera.height) +
        " image gives too many rays (at most 2^34 = " + std::to_string(max_primary_rays) + ")");
}

/// Side length (in samples) of the square tiles processed as one parallel task.
inline constexpr int primary_tile = 16;

/// Casts the primary rays of the (supersample x supersample per pixel) grid of `camera` in
/// 4 x 4 packets (rtcIntersect16, coherent context) over tiles processed in parallel (TBB).
/// For every sample calls visit(local, x, y, triangle, u, v, depth, ng_dot_dir) with triangle -1
/// on a miss; ng_dot_dir is the dot product of Embree's geometric normal and the ray direction.
/// `local` is the reference returned by make_local(), called once per parallel task (e.g. a
/// thread-local accumulator). `visit` runs concurrently from several threads: it may only
/// write per-sample or task-local state.
template <class MakeLocal, class Visit>
void for_each_primary(const RayScene::Impl& impl, const Camera& camera, int supersample,
                      const MakeLocal& make_local, const Visit& visit) {
  const int width = camera.width * supersample;
  const int height = camera.height * supersample;
  if (width <= 0 || height <= 0) return;
  const double inv_ss = 1.0 / supersample;
  const float inf = std::numeric_limits<float>::infinity();
  tbb::parallel_for(
      tbb::blocked_range2d<int>(0, (height + primary_tile - 1) / primary_tile, 1, 0,
                                (width + primary_tile - 1) / primary_tile, 1),
      [&](const tbb::blocked_range2d<int>& range) {
        auto& local = make_local();
        RTCIntersectContext context;
        rtcInitIntersectContext(&context);
        context.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
        alignas(64) RTCRayHit16 packet;
        alignas(64) int valid[16];
        for (int ty = range.rows().begin(); ty != range.rows().end(); ++ty) {
          for (int tx = range.cols().begin(); tx != range.cols().end(); ++tx) {
            const int x_end = std::min(width, (tx + 1) * primary_tile);
            const int y_end = std::min(height, (ty + 1) * primary_tile);
            for (int py = ty * primary_tile; py < y_end; py += 4) {
              for (int px = tx * primary_tile; px < x_end; px += 4) {
                for (int k = 0; k < 16; ++k) {
                  const int x = px + (k & 3);
                  const int y = py + (k >> 2);
                  valid[k] = (x < width && y < height) ? -1 : 0;
                  const double pix_x = (x + 0.5) * inv_ss - 0.5;
                  const double pix_y = (y + 0.5) * inv_ss - 0.5;
                  packet.ray.org_x[k] = 0.0f;
                  packet.ray.org_y[k] = 0.0f;
                  packet.ray.org_z[k] = 0.0f;
                  packet.ray.tnear[k] = 0.0f;
                  packet.ray.dir_x[k] = static_cast<float>((pix_x - camera.cx) / camera.fx);
                  packet.ray.dir_y[k] = static_cast<float>((pix_y - camera.cy) / camera.fy);
                  packet.ray.dir_z[k] = 1.0f;
                  packet.ray.time[k] = 0.0f;
                  packet.ray.tfar[k] = inf;
                  packet.ray.mask[k] = 0xFFFFFFFFu;
                  packet.ray.id[k] = static_cast<unsigned>(k);
                  packet.ray.flags[k] = 0;
                  packet.hit.geomID[k] = RTC_INVALID_GEOMETRY_ID;
                  packet.hit.primID[k] = RTC_INVALID_GEOMETRY_ID;
                }
                rtcIntersect16(valid, impl.scene, &context, &packet);
                for (int k = 0; k < 16; ++k) {
                  if (!valid[k]) continue;
                  const int x = px + (k & 3);
                  const int y = py + (k >> 2);
                  if (packet.hit.geomID[k] == RTC_INVALID_GEOMETRY_ID) {
                    visit(local, x, y, -1, 0.0f, 0.0f, inf, 0.0f);
                  } else {
                    const float ng_dot_dir = packet.hit.Ng_x[k] * packet.ray.dir_x[k] +
                                             packet.hit.Ng_y[k] * packet.ray.dir_y[k] +
                                             packet.hit.Ng_z[k] * packet.ray.dir_z[k];
                    visit(local, x, y, static_cast<int>(packet.hit.primID[k]), packet.hit.u[k],
                          packet.hit.v[k], packet.ray.tfar[k], ng_dot_dir);
                  }
                }
              }
            }
          }
        }
      });
}

}  // namespace detail
}  // namespace pbve
