#include "pbve/visibility/metric.hpp"

#include <string>

#include <tbb/enumerable_thread_specific.h>

#include "pbve/core/error.hpp"
#include "visibility/ray_scene_impl.hpp"

namespace pbve {
namespace {

struct Counts {
  std::int64_t covered = 0, violating = 0, interior = 0, rays = 0;
};

}  // namespace

ViolationMetric violation_metric(const RayScene& simulated, const Camera& camera,
                                 const std::vector<std::uint8_t>& observed_in_input,
                                 const std::vector<std::uint8_t>& interior,
                                 const MetricOptions& options) {
  const size_t nf = static_cast<size_t>(simulated.num_triangles());
  if (observed_in_input.size() != nf)
    throw InputError("observed_in_input has " + std::to_string(observed_in_input.size()) +
                     " entries, the mesh has " + std::to_string(nf) + " triangles");
  if (!interior.empty() && interior.size() != nf)
    throw InputError("interior has " + std::to_string(interior.size()) + " entries, the mesh has " +
                     std::to_string(nf) + " triangles");
  detail::check_ray_camera(camera, "violation_metric()");
  detail::check_primary_rays(camera, options.supersample, "violation_metric()");

  // Per triangle: 0 = fine, 1 = violating, 2 = interior (one lookup per ray).
  std::vector<std::uint8_t> kind(nf, 0);
  for (size_t j = 0; j < nf; ++j) {
    if (!interior.empty() && interior[j])
      kind[j] = 2;
    else if (!observed_in_input[j])
      kind[j] = 1;
  }
  const bool back_faces_violate = options.back_faces_violate;
  tbb::enumerable_thread_specific<Counts> counts;
  detail::for_each_primary(
      simulated.impl(), camera, options.supersample, [&]() -> Counts& { return counts.local(); },
      [&](Counts& c, int, int, int tri, float, float, float, float ng_dot_dir) {
        ++c.rays;
        if (tri < 0) return;
        ++c.covered;
        const std::uint8_t k = kind[static_cast<size_t>(tri)];
        // Embree's geometric normal is (b - a) x (c - a) for the triangle (a, b, c) (checked by
        // the tests): a positive dot product with the ray direction means the ray meets the
        // back side.
        if (k == 2)
          ++c.interior;
        else if (k == 1 || (back_faces_violate && ng_dot_dir > 0.0f))
          ++c.violating;
      });
  Counts total;
  for (const Counts& c : counts) {
    total.covered += c.covered;
    total.violating += c.violating;
    total.interior += c.interior;
    total.rays += c.rays;
  }
  const double pixel_per_sample =
      1.0 / (static_cast<double>(options.supersample) * options.supersample);
  ViolationMetric m;
  m.object_area_px = total.covered * pixel_per_sample;
  m.violating_area_px = total.violating * pixel_per_sample;
  m.interior_area_px = total.interior * pixel_per_sample;
  m.violation_pct = total.covered > 0 ? 100.0 * total.violating / total.covered : 0.0;
  m.rays_cast = total.rays;
  return m;
}

}  // namespace pbve
