#pragma once
// Procedural meshes for the mass-spring tests: a flat grid (cloth) and an icosphere (solids).

#include <array>
#include <map>
#include <utility>
#include <vector>

#include "pbve/core/mesh.hpp"
#include "pbve/edit/synth.hpp"

namespace pbve::test {

/// A flat n by n vertex grid of side `size` metres in the z = `depth` plane (camera frame),
/// x right and y down; vertex (i, j) has index j * n + i. Triangles face the camera (-z).
inline Mesh grid_mesh(int n, double size, double depth = 1.0) {
  Mesh m;
  m.vertices.resize(n * n, 3);
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i)
      m.vertices.row(j * n + i) << size * i / (n - 1) - 0.5 * size, size * j / (n - 1) - 0.5 * size,
          depth;
  m.triangles.resize(2 * (n - 1) * (n - 1), 3);
  int f = 0;
  for (int j = 0; j + 1 < n; ++j)
    for (int i = 0; i + 1 < n; ++i) {
      const int a = j * n + i, b = a + 1, c = a + n, d = c + 1;
      // Alternate the diagonal for an isotropic pattern.
      if ((i + j) % 2 == 0) {
        m.triangles.row(f++) << a, c, b;
        m.triangles.row(f++) << b, c, d;
      } else {
        m.triangles.row(f++) << a, c, d;
        m.triangles.row(f++) << a, d, b;
      }
    }
  m.triangle_part.assign(static_cast<size_t>(m.triangles.rows()), 0);
  m.part_names = {"default"};
  m.interior.assign(static_cast<size_t>(m.triangles.rows()), 0);
  return m;
}

/// An icosphere of the given radius (metres) centred at `center`, `levels` subdivisions,
/// counter-clockwise seen from outside.
inline Mesh icosphere(int levels, double radius, const Eigen::Vector3d& center) {
  Mesh m = pbve::make_icosphere(radius, levels);
  m.vertices.rowwise() += center.transpose();
  return m;
}

/// Lengths of every triangle edge (each edge once per triangle side), metres.
inline std::vector<double> edge_lengths(const Vertices& x, const Triangles& t) {
  std::vector<double> out;
  for (Eigen::Index f = 0; f < t.rows(); ++f)
    for (int e = 0; e < 3; ++e) out.push_back((x.row(t(f, e)) - x.row(t(f, (e + 1) % 3))).norm());
  return out;
}

}  // namespace pbve::test
