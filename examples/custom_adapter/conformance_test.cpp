// The custom adapter passes the same conformance suite as the built-in engines.

#include "pbve/testing/simulator_conformance.hpp"
#include "spring_particles.hpp"

namespace {

// A 6 x 6 sheet of 5 cm cells, anchored at two corners.
pbve::testing::ConformanceCase sheet_case() {
  pbve::Mesh mesh;
  const int n = 6;
  mesh.vertices.resize(n * n, 3);
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) mesh.vertices.row(j * n + i) << 0.05 * i, 0.05 * j, 1.0;
  mesh.triangles.resize(2 * (n - 1) * (n - 1), 3);
  int f = 0;
  for (int j = 0; j + 1 < n; ++j)
    for (int i = 0; i + 1 < n; ++i) {
      const int a = j * n + i;
      mesh.triangles.row(f++) << a, a + 1, a + n + 1;
      mesh.triangles.row(f++) << a, a + n + 1, a + n;
    }
  pbve::testing::ConformanceCase c;
  c.name = "sheet";
  c.make = [mesh] {
    return std::make_unique<example::SpringParticles>(mesh, mesh.vertices, std::vector<int>{0, 5});
  };
  // f = m a probe: T = 20 x 1e-5 s is far below the spring period 2 pi sqrt(m / k) = 20 ms.
  c.fma_dt = 1e-5;
  // The large step keeps its default (0.25 s): the adapter takes as many substeps as symplectic
  // Euler's stability needs.
  return c;
}

INSTANTIATE_TEST_SUITE_P(CustomAdapter, SimulatorConformance, ::testing::Values(sheet_case()),
                         pbve::testing::case_name);

}  // namespace
