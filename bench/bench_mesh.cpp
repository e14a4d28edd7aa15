// Mesh loading and refinement benchmarks.
//
// A UV sphere of about 1M triangles is written once to a temporary OBJ and binary PLY; the
// benchmarks load them (bytes/s = file size per second) and refine an 8-vertex board to
// about 1M triangles.

#include <benchmark/benchmark.h>

#include <unistd.h>
#include <cmath>
#include <filesystem>
#include <numbers>

#include "pbve/core/mesh.hpp"

namespace {

namespace fs = std::filesystem;

/// UV sphere with `rings` latitude bands and `segments` longitude segments (radius 1,
/// coordinates with full double precision as an exporter would write them).
pbve::Mesh make_sphere(int rings, int segments) {
  pbve::Mesh m;
  const int nv = 2 + (rings - 1) * segments;
  m.vertices.resize(nv, 3);
  m.vertices.row(0) << 0, 0, 1;
  m.vertices.row(nv - 1) << 0, 0, -1;
  for (int r = 1; r < rings; ++r) {
    const double theta = std::numbers::pi * r / rings;
    for (int s = 0; s < segments; ++s) {
      const double phi = 2 * std::numbers::pi * s / segments;
      m.vertices.row(1 + (r - 1) * segments + s) << std::sin(theta) * std::cos(phi),
          std::sin(theta) * std::sin(phi), std::cos(theta);
    }
  }
  const int nf = 2 * segments * (rings - 1);
  m.triangles.resize(nf, 3);
  int f = 0;
  auto ring = [&](int r, int s) { return 1 + (r - 1) * segments + (s % segments); };
  for (int s = 0; s < segments; ++s) m.triangles.row(f++) << 0, ring(1, s), ring(1, s + 1);
  for (int r = 1; r < rings - 1; ++r)
    for (int s = 0; s < segments; ++s) {
      m.triangles.row(f++) << ring(r, s), ring(r + 1, s), ring(r + 1, s + 1);
      m.triangles.row(f++) << ring(r, s), ring(r + 1, s + 1), ring(r, s + 1);
    }
  for (int s = 0; s < segments; ++s)
    m.triangles.row(f++) << nv - 1, ring(rings - 1, s + 1), ring(rings - 1, s);
  m.triangle_part.assign(nf, 0);
  m.interior.assign(nf, 0);
  m.part_names = {"default"};
  return m;
}

/// The benchmark files, written once per process and removed at exit.
struct Files {
  fs::path dir;
  fs::path obj;
  fs::path ply;
  Files() {
    dir = fs::temp_directory_path() / ("pbve_bench_mesh_" + std::to_string(::getpid()));
    fs::create_directories(dir);
    const pbve::Mesh sphere = make_sphere(500, 1000);  // 998,000 triangles
    obj = dir / "sphere.obj";
    ply = dir / "sphere.ply";
    pbve::save_obj(sphere, obj);
    pbve::save_ply(sphere, ply);
  }
  ~Files() {
    std::error_code ec;
    fs::remove_all(dir, ec);
  }
};

const Files& files() {
  static const Files f;
  return f;
}

void BM_LoadObj(benchmark::State& state) {
  const Files& f = files();
  const auto bytes = static_cast<std::int64_t>(fs::file_size(f.obj));
  for (auto _ : state) {
    pbve::Mesh m = pbve::load_obj(f.obj);
    benchmark::DoNotOptimize(m.vertices.data());
    state.counters["triangles"] = m.num_triangles();
  }
  state.SetBytesProcessed(state.iterations() * bytes);
  state.counters["file_MB"] = static_cast<double>(bytes) / 1e6;
}
BENCHMARK(BM_LoadObj)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_LoadPlyBinary(benchmark::State& state) {
  const Files& f = files();
  const auto bytes = static_cast<std::int64_t>(fs::file_size(f.ply));
  for (auto _ : state) {
    pbve::Mesh m = pbve::load_ply(f.ply);
    benchmark::DoNotOptimize(m.vertices.data());
    state.counters["triangles"] = m.num_triangles();
  }
  state.SetBytesProcessed(state.iterations() * bytes);
  state.counters["file_MB"] = static_cast<double>(bytes) / 1e6;
}
BENCHMARK(BM_LoadPlyBinary)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_RefineBoard(benchmark::State& state) {
  // The paper's board: a 1 x 0.5 x 0.05 box of 8 vertices and 12 triangles, refined to edges
  // of at most 3.5 mm (in metres), which gives about 1.1M triangles.
  pbve::Mesh box;
  box.vertices.resize(8, 3);
  for (int i = 0; i < 8; ++i)
    box.vertices.row(i) << (i & 1 ? 1.0 : 0.0), (i & 2 ? 0.5 : 0.0), (i & 4 ? 0.05 : 0.0);
  box.triangles.resize(12, 3);
  box.triangles << 0, 2, 1, 1, 2, 3, 4, 5, 6, 5, 7, 6, 0, 1, 4, 1, 5, 4, 2, 6, 3, 3, 6, 7, 0, 4, 2,
      2, 4, 6, 1, 3, 5, 3, 7, 5;
  box.triangle_part.assign(12, 0);
  box.interior.assign(12, 0);
  box.part_names = {"default"};
  for (auto _ : state) {
    pbve::Mesh r = pbve::refine_mesh(box, 0.0035);
    benchmark::DoNotOptimize(r.vertices.data());
    state.counters["triangles"] = r.num_triangles();
  }
}
BENCHMARK(BM_RefineBoard)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
