// Rendering benchmark: texturing the simulated mesh from the input frame, the fail-safe fill
// and compositing over the plate (Renderer::render), for a 10,000-triangle torus at 640x480 and
// 1280x720. The torus covers about a quarter of the frame (same framing at both sizes); the
// simulated mesh is the aligned one turned by 0.5 rad, so about a third of the visible
// triangles are unobserved in the input and take the fail-safe fill. Wall-clock time
// (rendering is parallel); "fps" is frames per second.

#include <benchmark/benchmark.h>

#include <cmath>
#include <numbers>

#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "pbve/render/renderer.hpp"
#include "pbve/visibility/visibility.hpp"

namespace {

/// Torus (major radius R, minor r) with nu x nv quads = 2 nu nv triangles.
pbve::Mesh make_torus(double R, double r, int nu, int nv) {
  pbve::Mesh m;
  m.vertices.resize(nu * nv, 3);
  for (int i = 0; i < nu; ++i)
    for (int j = 0; j < nv; ++j) {
      const double a = 2 * std::numbers::pi * i / nu, b = 2 * std::numbers::pi * j / nv;
      m.vertices.row(i * nv + j) << (R + r * std::cos(b)) * std::cos(a),
          (R + r * std::cos(b)) * std::sin(a), r * std::sin(b);
    }
  m.triangles.resize(2 * nu * nv, 3);
  int k = 0;
  for (int i = 0; i < nu; ++i)
    for (int j = 0; j < nv; ++j) {
      const int a = i * nv + j, b = ((i + 1) % nu) * nv + j;
      const int c = ((i + 1) % nu) * nv + (j + 1) % nv, d = i * nv + (j + 1) % nv;
      m.triangles.row(k++) << a, b, c;
      m.triangles.row(k++) << a, c, d;
    }
  m.triangle_part.assign(static_cast<size_t>(m.triangles.rows()), 0);
  m.part_names = {"default"};
  m.interior.assign(static_cast<size_t>(m.triangles.rows()), 0);
  return m;
}

pbve::Vertices place(const pbve::Vertices& v, const Eigen::Matrix3d& R, const Eigen::Vector3d& t) {
  return ((v * R.transpose()).rowwise() + t.transpose()).eval();
}

void BM_RenderFrame(benchmark::State& state) {
  const int width = static_cast<int>(state.range(0)), height = static_cast<int>(state.range(1));
  pbve::Camera camera;
  camera.fx = camera.fy = 600.0 * height / 480.0;
  camera.cx = (width - 1) / 2.0;
  camera.cy = (height - 1) / 2.0;
  camera.width = width;
  camera.height = height;
  const pbve::Mesh mesh = make_torus(0.25, 0.1, 100, 50);  // 10,000 triangles
  const Eigen::Matrix3d tilt = Eigen::AngleAxisd(1.0, Eigen::Vector3d::UnitX()).toRotationMatrix();
  const pbve::Vertices aligned = place(mesh.vertices, tilt, {0.0, 0.0, 1.4});
  const pbve::Vertices simulated = place(
      mesh.vertices,
      Eigen::AngleAxisd(0.5, Eigen::Vector3d(0.3, 1, 0).normalized()).toRotationMatrix() * tilt,
      {0.03, 0.02, 1.4});
  const std::vector<std::uint8_t> observed =
      pbve::compute_visibility(pbve::RayScene(aligned, mesh.triangles), camera).visible;
  cv::Mat input(height, width, CV_8UC3), plate(height, width, CV_8UC3), output;
  cv::randu(input, cv::Scalar::all(0), cv::Scalar::all(255));
  cv::randu(plate, cv::Scalar::all(0), cv::Scalar::all(255));
  pbve::Renderer renderer(mesh, camera);
  for (auto _ : state) {
    renderer.render(input, aligned, simulated, observed, plate, cv::Mat(), output);
    benchmark::DoNotOptimize(output.data);
  }
  const pbve::RenderStats& s = renderer.stats();
  state.counters["fps"] = benchmark::Counter(1.0, benchmark::Counter::kIsIterationInvariantRate);
  state.counters["covered_px"] = static_cast<double>(s.covered_pixels);
  state.counters["edge_px"] = static_cast<double>(s.edge_pixels);
  state.counters["fill_samples"] = static_cast<double>(s.fallback_samples);
}
BENCHMARK(BM_RenderFrame)
    ->Args({640, 480})
    ->Args({1280, 720})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
