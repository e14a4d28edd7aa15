// Voronoi fracture of a convex mesh: each seed's cell is the mesh clipped by the bisector
// half-spaces of the other seeds. A cell is kept as a list of convex polygons (the input's
// triangles clipped, plus one cap polygon per cut), then triangulated as fans with shared
// vertices inside the piece.

#include "pbve/core/fracture.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <string>
#include <tuple>
#include <vector>

#include <Eigen/Geometry>

#include "mesh_arrays.hpp"
#include "pbve/core/error.hpp"

namespace pbve {

namespace {

using Eigen::Vector3d;

struct Polygon {
  std::vector<Vector3d> points;  // convex, counter-clockwise seen from outside
  bool interior = false;
};

// splitmix64: a small, portable generator (the same pieces on every platform).
struct Random {
  std::uint64_t state;
  std::uint64_t next() {
    std::uint64_t z = (state += 0x9e3779b97f4a7c15ULL);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
  }
  double uniform() { return static_cast<double>(next() >> 11) * 0x1.0p-53; }
};

// Keeps the part of `poly` where (x - point) . normal <= 0; the points on the plane are
// appended to `cut`.
Polygon clip(const Polygon& poly, const Vector3d& point, const Vector3d& normal, double eps,
             std::vector<Vector3d>& cut) {
  Polygon out;
  out.interior = poly.interior;
  const size_t n = poly.points.size();
  for (size_t i = 0; i < n; ++i) {
    const Vector3d& a = poly.points[i];
    const Vector3d& b = poly.points[(i + 1) % n];
    const double da = (a - point).dot(normal), db = (b - point).dot(normal);
    if (da <= eps) {
      out.points.push_back(a);
      if (da >= -eps) cut.push_back(a);
    }
    if ((da < -eps && db > eps) || (da > eps && db < -eps)) {
      const Vector3d x = a + (b - a) * (da / (da - db));
      out.points.push_back(x);
      cut.push_back(x);
    }
  }
  return out;
}

// The convex polygon through `points` (all on the plane of `normal`), counter-clockwise seen
// from the side `normal` points to; duplicates within eps are merged.
std::vector<Vector3d> cap(const std::vector<Vector3d>& points, const Vector3d& normal, double eps) {
  if (points.size() < 3) return {};
  Vector3d c = Vector3d::Zero();
  for (const auto& p : points) c += p;
  c /= static_cast<double>(points.size());
  const Vector3d u = normal.unitOrthogonal(), v = normal.cross(u);
  std::vector<std::pair<double, Vector3d>> by_angle;
  for (const auto& p : points) by_angle.emplace_back(std::atan2((p - c).dot(v), (p - c).dot(u)), p);
  std::sort(by_angle.begin(), by_angle.end(),
            [](const auto& a, const auto& b) { return a.first < b.first; });
  std::vector<Vector3d> out;
  for (const auto& [angle, p] : by_angle)
    if (out.empty() || (p - out.back()).norm() > eps) out.push_back(p);
  while (out.size() > 1 && (out.front() - out.back()).norm() <= eps) out.pop_back();
  return out.size() >= 3 ? out : std::vector<Vector3d>{};
}

double polygon_area(const std::vector<Vector3d>& p) {
  Vector3d s = Vector3d::Zero();
  for (size_t i = 1; i + 1 < p.size(); ++i) s += (p[i] - p[0]).cross(p[i + 1] - p[0]);
  return 0.5 * s.norm();
}

}  // namespace

Mesh voronoi_fracture(const Mesh& convex, const FractureOptions& options) {
  if (options.pieces < 2 || options.pieces > 1000)
    throw InputError("fracture needs between 2 and 1000 pieces (got " +
                     std::to_string(options.pieces) + ")");
  const int nv = convex.num_vertices(), nf = convex.num_triangles();
  if (nv < 4 || nf < 4) throw InputError("fracture needs a closed convex mesh (too few faces)");
  const Vector3d lo = convex.vertices.colwise().minCoeff().transpose();
  const Vector3d hi = convex.vertices.colwise().maxCoeff().transpose();
  const double size = (hi - lo).norm();
  if (!(size > 0.0) || !std::isfinite(size))
    throw InputError("fracture needs a mesh with a positive, finite extent");
  const double eps = 1e-9 * size;

  // Face planes; convexity: every vertex on the inner side of every face plane.
  std::vector<Polygon> surface;
  std::vector<std::pair<Vector3d, Vector3d>> planes;  // point, outward unit normal
  for (int f = 0; f < nf; ++f) {
    Polygon p;
    for (int k = 0; k < 3; ++k) p.points.push_back(convex.vertices.row(convex.triangles(f, k)));
    p.interior = !convex.interior.empty() && convex.interior[static_cast<size_t>(f)];
    const Vector3d n = (p.points[1] - p.points[0]).cross(p.points[2] - p.points[0]);
    if (!(n.norm() > eps * size)) continue;  // degenerate triangle: covers no area
    planes.emplace_back(p.points[0], n.normalized());
    surface.push_back(std::move(p));
  }
  double volume = 0.0;
  for (const auto& p : surface) volume += p.points[0].dot(p.points[1].cross(p.points[2])) / 6.0;
  if (!(volume > 0.0))
    throw InputError(
        "fracture needs a closed mesh with counter-clockwise faces seen from "
        "outside (enclosed volume " +
        std::to_string(volume) + ")");
  for (size_t f = 0; f < planes.size(); ++f)
    for (int i = 0; i < nv; ++i) {
      const double d = (Vector3d(convex.vertices.row(i)) - planes[f].first).dot(planes[f].second);
      if (d > 1e-6 * size)
        throw InputError("fracture needs a convex mesh: vertex " + std::to_string(i) + " is " +
                         std::to_string(d) + " in front of the plane of a face");
    }

  // Seeds, uniform inside the mesh (rejection sampling in the bounding box).
  Random rng{options.seed};
  std::vector<Vector3d> seeds;
  for (int tries = 0; static_cast<int>(seeds.size()) < options.pieces; ++tries) {
    if (tries > 1000 * options.pieces)
      throw InputError("fracture could not place seeds inside the mesh (is it flat?)");
    const Vector3d p(lo.x() + (hi.x() - lo.x()) * rng.uniform(),
                     lo.y() + (hi.y() - lo.y()) * rng.uniform(),
                     lo.z() + (hi.z() - lo.z()) * rng.uniform());
    bool inside = true;
    for (const auto& [q, n] : planes) inside = inside && (p - q).dot(n) < 0.0;
    if (inside) seeds.push_back(p);
  }

  Mesh out;
  std::vector<double> xyz;
  std::vector<int> tri;
  std::vector<int> part;
  std::vector<std::uint8_t> interior;
  for (size_t s = 0; s < seeds.size(); ++s) {
    std::vector<Polygon> cell = surface;
    for (size_t t = 0; t < seeds.size(); ++t) {
      if (t == s) continue;
      const Vector3d normal = (seeds[t] - seeds[s]).normalized();
      const Vector3d mid = 0.5 * (seeds[s] + seeds[t]);
      std::vector<Vector3d> cut;
      std::vector<Polygon> next;
      for (const auto& p : cell) {
        Polygon q = clip(p, mid, normal, eps, cut);
        if (q.points.size() >= 3 && polygon_area(q.points) > eps * eps) next.push_back(q);
      }
      if (next.size() == cell.size() && cut.size() < 3) {
        cell.swap(next);
        continue;  // the plane misses the cell
      }
      Polygon c{cap(cut, normal, 1e-7 * size), true};
      if (c.points.size() >= 3 && polygon_area(c.points) > eps * eps) next.push_back(c);
      cell.swap(next);
    }
    if (cell.empty()) continue;
    // Fan triangulation with vertices shared inside the piece (merged on a 1e-7 grid).
    std::map<std::tuple<long long, long long, long long>, int> index;
    const double grid = 1e-7 * size;
    auto vertex = [&](const Vector3d& p) {
      const auto key = std::make_tuple(std::llround(p.x() / grid), std::llround(p.y() / grid),
                                       std::llround(p.z() / grid));
      const auto it = index.find(key);
      if (it != index.end()) return it->second;
      const int id = static_cast<int>(xyz.size() / 3);
      xyz.insert(xyz.end(), {p.x(), p.y(), p.z()});
      index.emplace(key, id);
      return id;
    };
    const int piece = static_cast<int>(out.part_names.size());
    out.part_names.push_back("piece_" + std::to_string(piece));
    for (const auto& p : cell) {
      std::vector<int> ids;
      for (const auto& x : p.points) {
        const int id = vertex(x);
        if (ids.empty() || (id != ids.back() && id != ids.front())) ids.push_back(id);
      }
      for (size_t i = 1; i + 1 < ids.size(); ++i) {
        tri.insert(tri.end(), {ids[0], ids[i], ids[i + 1]});
        part.push_back(piece);
        interior.push_back(p.interior ? 1 : 0);
      }
    }
  }
  Mesh geometry = detail::mesh_from_arrays(xyz, tri, std::move(part), std::move(interior));
  geometry.part_names = std::move(out.part_names);
  return geometry;
}

}  // namespace pbve
