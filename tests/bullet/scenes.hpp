#pragma once
// Small Bullet scenes shared by the Bullet adapter tests.

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

/// A ground plane `y` metres below the camera's optical axis (y points down), facing up.
inline bullet::Plane ground_at(double y, double friction = 0.5) {
  bullet::Plane p;
  p.point = Eigen::Vector3d(0, y, 0);
  p.normal = Eigen::Vector3d(0, -1, 0);
  p.friction = friction;
  return p;
}

}  // namespace pbve::test
