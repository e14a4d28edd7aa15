#pragma once
/// @file
/// Procedural meshes with known geometry for tests and benchmarks (header-only).
///
/// All meshes are oriented: triangles are counter-clockwise seen from the side their normal
/// (b - a) x (c - a) points to (outside for closed surfaces).

#include <array>
#include <cmath>
#include <map>
#include <numbers>
#include <utility>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "pbve/core/mesh.hpp"
#include "pbve/edit/synth.hpp"

namespace pbve::testing {

/// A vertex grid and its triangles.
struct Shape {
  Vertices vertices;
  Triangles triangles;
};

/// A flat parallelogram corner + s U + t V, (s, t) in [0, 1]^2, split into nu x nv cells of two
/// triangles each (2 nu nv triangles, normals along U x V).
inline Shape make_plate(const Eigen::Vector3d& corner, const Eigen::Vector3d& U,
                        const Eigen::Vector3d& V, int nu, int nv) {
  Shape shape;
  shape.vertices.resize((nu + 1) * (nv + 1), 3);
  for (int j = 0; j <= nv; ++j)
    for (int i = 0; i <= nu; ++i)
      shape.vertices.row(j * (nu + 1) + i) =
          (corner + (double(i) / nu) * U + (double(j) / nv) * V).transpose();
  shape.triangles.resize(2 * nu * nv, 3);
  int f = 0;
  for (int j = 0; j < nv; ++j) {
    for (int i = 0; i < nu; ++i) {
      const int v00 = j * (nu + 1) + i, v10 = v00 + 1, v01 = v00 + nu + 1, v11 = v01 + 1;
      shape.triangles.row(f++) << v00, v10, v11;
      shape.triangles.row(f++) << v00, v11, v01;
    }
  }
  return shape;
}

/// A torus around the z axis of its own frame (major radius R, minor radius r), nu segments
/// around the ring and nv around the tube (2 nu nv triangles), then rotated by `rotation` and
/// moved to `centre`.
inline Shape make_torus(double R, double r, int nu, int nv, const Eigen::Matrix3d& rotation,
                        const Eigen::Vector3d& centre) {
  Shape shape;
  shape.vertices.resize(nu * nv, 3);
  const double two_pi = 2.0 * std::numbers::pi;
  for (int i = 0; i < nu; ++i) {
    const double u = two_pi * i / nu;
    for (int j = 0; j < nv; ++j) {
      const double v = two_pi * j / nv;
      const Eigen::Vector3d p((R + r * std::cos(v)) * std::cos(u),
                              (R + r * std::cos(v)) * std::sin(u), r * std::sin(v));
      shape.vertices.row(i * nv + j) = (rotation * p + centre).transpose();
    }
  }
  shape.triangles.resize(2 * nu * nv, 3);
  int f = 0;
  for (int i = 0; i < nu; ++i) {
    for (int j = 0; j < nv; ++j) {
      const int a = i * nv + j, b = ((i + 1) % nu) * nv + j;
      const int c = ((i + 1) % nu) * nv + (j + 1) % nv, d = i * nv + (j + 1) % nv;
      shape.triangles.row(f++) << a, b, c;
      shape.triangles.row(f++) << a, c, d;
    }
  }
  return shape;
}

/// An icosphere: the icosahedron subdivided `levels` times (20 * 4^levels triangles), vertices
/// on the sphere of `radius` around `centre`.
inline Shape make_icosphere(int levels, double radius, const Eigen::Vector3d& centre) {
  const Mesh m = pbve::make_icosphere(radius, levels);
  Shape shape{m.vertices, m.triangles};
  shape.vertices.rowwise() += centre.transpose();
  return shape;
}

/// Concatenates two shapes (the second's triangle ids follow the first's).
inline Shape concatenate(const Shape& first, const Shape& second) {
  Shape shape;
  shape.vertices.resize(first.vertices.rows() + second.vertices.rows(), 3);
  shape.vertices << first.vertices, second.vertices;
  shape.triangles.resize(first.triangles.rows() + second.triangles.rows(), 3);
  shape.triangles << first.triangles,
      (second.triangles.array() + static_cast<int>(first.vertices.rows())).matrix();
  return shape;
}

}  // namespace pbve::testing
