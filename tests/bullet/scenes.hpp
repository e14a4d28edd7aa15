#pragma once
// Small Bullet scenes shared by the Bullet adapter tests.

#include <map>
#include <tuple>
#include <vector>

#include "mass_spring/meshes.hpp"
#include "pbve/bullet/bullet.hpp"
#include "pbve/core/mesh.hpp"

namespace pbve::test {

/// The two meshes as one (b's vertex ids shifted by a's vertex count).
inline Mesh join(const Mesh& a, const Mesh& b) {
  Mesh m;
  m.vertices.resize(a.vertices.rows() + b.vertices.rows(), 3);
  m.vertices << a.vertices, b.vertices;
  m.triangles.resize(a.triangles.rows() + b.triangles.rows(), 3);
  m.triangles << a.triangles, (b.triangles.array() + a.num_vertices()).matrix();
  m.triangle_part.assign(static_cast<size_t>(m.triangles.rows()), 0);
  m.part_names = {"default"};
  m.interior.assign(static_cast<size_t>(m.triangles.rows()), 0);
  return m;
}

/// The closed surface of a union of cubic cells of side `size` (cell (i, j, k) spans
/// origin + size * [i, i+1] x [j, j+1] x [k, k+1]), counter-clockwise seen from outside. Cells
/// must not touch along an edge or a corner only.
inline Mesh voxel_mesh(const std::vector<Eigen::Vector3i>& cells, double size,
                       const Eigen::Vector3d& origin) {
  auto filled = [&](const Eigen::Vector3i& c) {
    for (const auto& d : cells)
      if (d == c) return true;
    return false;
  };
  std::map<std::tuple<int, int, int>, int> index;
  std::vector<Eigen::Vector3d> vertices;
  std::vector<Eigen::Vector3i> triangles;
  auto vertex = [&](const Eigen::Vector3i& g) {
    const auto key = std::make_tuple(g.x(), g.y(), g.z());
    auto it = index.find(key);
    if (it != index.end()) return it->second;
    vertices.push_back(origin + size * g.cast<double>());
    return index[key] = static_cast<int>(vertices.size()) - 1;
  };
  for (const auto& c : cells)
    for (int a = 0; a < 3; ++a)
      for (int s : {-1, 1}) {
        Eigen::Vector3i n = Eigen::Vector3i::Zero();
        n(a) = s;
        if (filled(c + n)) continue;
        const Eigen::Vector3i eu = Eigen::Vector3i::Unit((a + 1) % 3);
        const Eigen::Vector3i ev = Eigen::Vector3i::Unit((a + 2) % 3);
        const Eigen::Vector3i base =
            c + (s > 0 ? Eigen::Vector3i(Eigen::Vector3i::Unit(a)) : Eigen::Vector3i::Zero());
        int q[4] = {vertex(base), vertex(base + eu), vertex(base + eu + ev), vertex(base + ev)};
        if (s < 0) std::swap(q[1], q[3]);  // e_u x e_v = e_a: reverse for the -a face
        triangles.emplace_back(q[0], q[1], q[2]);
        triangles.emplace_back(q[0], q[2], q[3]);
      }
  Mesh m;
  m.vertices.resize(static_cast<Eigen::Index>(vertices.size()), 3);
  for (size_t i = 0; i < vertices.size(); ++i)
    m.vertices.row(static_cast<Eigen::Index>(i)) = vertices[i].transpose();
  m.triangles.resize(static_cast<Eigen::Index>(triangles.size()), 3);
  for (size_t i = 0; i < triangles.size(); ++i)
    m.triangles.row(static_cast<Eigen::Index>(i)) = triangles[i].transpose();
  m.triangle_part.assign(triangles.size(), 0);
  m.part_names = {"default"};
  m.interior.assign(triangles.size(), 0);
  return m;
}

/// A ground plane `y` metres below the camera's optical axis (y points down), facing up.
inline bullet::Plane ground_at(double y, double friction = 0.5) {
  bullet::Plane p;
  p.point = Eigen::Vector3d(0, y, 0);
  p.normal = Eigen::Vector3d(0, -1, 0);
  p.friction = friction;
  return p;
}

}  // namespace pbve::test
