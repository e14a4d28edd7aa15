// Visibility (with occlusion) and the violation metric on tori of 1k, 10k and 100k triangles
// seen at 640 x 480. Counters: rays/s over all rays cast (occlusion rays, primary rays).

#include <cmath>
#include <numbers>

#include <benchmark/benchmark.h>
#include <Eigen/Geometry>

#include "pbve/testing/shapes.hpp"
#include "pbve/visibility/metric.hpp"
#include "pbve/visibility/visibility.hpp"

namespace {

using pbve::testing::Shape;

// A torus tilted 60 degrees towards the camera, filling most of the 640 x 480 image, so that
// its inner side is partly hidden by the near part of the ring (self-occlusion).
Shape bench_torus(int triangles) {
  int nu = 25, nv = 20;  // 1000
  if (triangles == 10000) nu = 100, nv = 50;
  if (triangles == 100000) nu = 250, nv = 200;
  const Eigen::Matrix3d rotation =
      Eigen::AngleAxisd(std::numbers::pi / 3.0, Eigen::Vector3d::UnitX()).toRotationMatrix();
  return pbve::testing::make_torus(1.0, 0.35, nu, nv, rotation, {0.0, 0.0, 3.2});
}

void BM_VisibilityOcclusion(benchmark::State& state) {
  const Shape torus = bench_torus(static_cast<int>(state.range(0)));
  pbve::RayScene scene(torus.vertices, torus.triangles);
  const pbve::Camera camera;
  pbve::VisibilityOptions options;  // occlusion, 4 samples per triangle
  pbve::TriangleVisibility vis;     // reused across iterations, as across frames
  std::int64_t rays = 0;
  for (auto _ : state) {
    pbve::compute_visibility(scene, camera, options, vis);
    rays += vis.rays_cast;
    benchmark::DoNotOptimize(vis.visible.data());
  }
  state.counters["rays/s"] =
      benchmark::Counter(static_cast<double>(rays), benchmark::Counter::kIsRate);
  state.counters["triangles"] = static_cast<double>(torus.triangles.rows());
}

void BM_VisibilityRefitAndOcclusion(benchmark::State& state) {
  // One frame of a deforming mesh: refit the hierarchy, then visibility with occlusion.
  const Shape torus = bench_torus(static_cast<int>(state.range(0)));
  pbve::RayScene scene(torus.vertices, torus.triangles);
  const pbve::Camera camera;
  pbve::Vertices moved = torus.vertices;
  pbve::TriangleVisibility vis;
  std::int64_t rays = 0, frame = 0;
  for (auto _ : state) {
    const double wobble = 0.01 * std::sin(0.1 * static_cast<double>(++frame));
    for (Eigen::Index i = 0; i < moved.rows(); ++i)
      moved(i, 2) = torus.vertices(i, 2) + wobble * torus.vertices(i, 0);
    scene.update(moved);
    pbve::compute_visibility(scene, camera, {}, vis);
    rays += vis.rays_cast;
    benchmark::DoNotOptimize(vis.visible.data());
  }
  state.counters["rays/s"] =
      benchmark::Counter(static_cast<double>(rays), benchmark::Counter::kIsRate);
}

void BM_ViolationMetric(benchmark::State& state) {
  const Shape torus = bench_torus(static_cast<int>(state.range(0)));
  pbve::RayScene scene(torus.vertices, torus.triangles);
  const pbve::Camera camera;
  // A mix of observed and unobserved triangles (the count does not depend on it).
  std::vector<std::uint8_t> observed(static_cast<size_t>(torus.triangles.rows()));
  for (size_t j = 0; j < observed.size(); ++j) observed[j] = (j / 7) % 3 != 0;
  std::int64_t rays = 0;
  for (auto _ : state) {
    const auto m = pbve::violation_metric(scene, camera, observed, {});
    rays += m.rays_cast;
    benchmark::DoNotOptimize(m.violation_pct);
  }
  state.counters["rays/s"] =
      benchmark::Counter(static_cast<double>(rays), benchmark::Counter::kIsRate);
}

void BM_CastPrimary(benchmark::State& state) {
  const Shape torus = bench_torus(static_cast<int>(state.range(0)));
  pbve::RayScene scene(torus.vertices, torus.triangles);
  const pbve::Camera camera;
  std::int64_t rays = 0;
  for (auto _ : state) {
    const auto hits = scene.cast_primary(camera, 1);
    rays += static_cast<std::int64_t>(hits.triangle.size());
    benchmark::DoNotOptimize(hits.triangle.data());
  }
  state.counters["rays/s"] =
      benchmark::Counter(static_cast<double>(rays), benchmark::Counter::kIsRate);
}

}  // namespace

BENCHMARK(BM_VisibilityOcclusion)
    ->Arg(1000)
    ->Arg(10000)
    ->Arg(100000)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_VisibilityRefitAndOcclusion)
    ->Arg(1000)
    ->Arg(10000)
    ->Arg(100000)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_ViolationMetric)
    ->Arg(1000)
    ->Arg(10000)
    ->Arg(100000)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_CastPrimary)
    ->Arg(1000)
    ->Arg(10000)
    ->Arg(100000)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

BENCHMARK_MAIN();
