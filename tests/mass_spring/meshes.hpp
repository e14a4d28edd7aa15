#pragma once
// Procedural meshes for the mass-spring tests: a flat grid (cloth) and an icosphere (solids).

#include <array>
#include <map>
#include <utility>
#include <vector>

#include "pbve/core/mesh.hpp"

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
  const double t = (1.0 + std::sqrt(5.0)) / 2.0;
  std::vector<Eigen::Vector3d> v = {{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0},
                                    {0, -1, t}, {0, 1, t}, {0, -1, -t}, {0, 1, -t},
                                    {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
  for (auto& p : v) p.normalize();
  std::vector<std::array<int, 3>> f = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11},
                                       {1, 5, 9},  {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                                       {3, 9, 4},  {3, 4, 2},  {3, 2, 6},   {3, 6, 8},  {3, 8, 9},
                                       {4, 9, 5},  {2, 4, 11}, {6, 2, 10},  {8, 6, 7},  {9, 8, 1}};
  for (int l = 0; l < levels; ++l) {
    std::map<std::pair<int, int>, int> mid;
    auto midpoint = [&](int a, int b) {
      const auto key = std::make_pair(std::min(a, b), std::max(a, b));
      const auto it = mid.find(key);
      if (it != mid.end()) return it->second;
      v.push_back((v[static_cast<size_t>(a)] + v[static_cast<size_t>(b)]).normalized());
      const int id = static_cast<int>(v.size()) - 1;
      mid[key] = id;
      return id;
    };
    std::vector<std::array<int, 3>> g;
    for (const auto& tri : f) {
      const int a = midpoint(tri[0], tri[1]), b = midpoint(tri[1], tri[2]),
                c = midpoint(tri[2], tri[0]);
      g.push_back({tri[0], a, c});
      g.push_back({tri[1], b, a});
      g.push_back({tri[2], c, b});
      g.push_back({a, b, c});
    }
    f = std::move(g);
  }
  Mesh m;
  m.vertices.resize(static_cast<Eigen::Index>(v.size()), 3);
  for (size_t i = 0; i < v.size(); ++i)
    m.vertices.row(static_cast<Eigen::Index>(i)) = (center + radius * v[i]).transpose();
  m.triangles.resize(static_cast<Eigen::Index>(f.size()), 3);
  for (size_t i = 0; i < f.size(); ++i)
    m.triangles.row(static_cast<Eigen::Index>(i)) << f[i][0], f[i][1], f[i][2];
  m.triangle_part.assign(f.size(), 0);
  m.part_names = {"default"};
  m.interior.assign(f.size(), 0);
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
