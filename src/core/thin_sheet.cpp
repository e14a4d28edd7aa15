#include "pbve/core/thin_sheet.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <map>
#include <unordered_map>
#include <utility>
#include <vector>

#include <Eigen/Geometry>

#include "cell_grid.hpp"

namespace pbve {

namespace {

using Eigen::Matrix3d;
using Eigen::Vector3d;

Vector3d row3(const Vertices& x, int i) {
  return x.row(i).transpose();
}

/// Barycentric coordinates of the point of triangle (a, b, c) closest to p (the Voronoi-region
/// walk of Ericson, Real-Time Collision Detection, 5.1.5).
Vector3d closest_barycentric(const Vector3d& p, const Vector3d& a, const Vector3d& b,
                             const Vector3d& c) {
  const Vector3d ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0.0 && d2 <= 0.0) return {1.0, 0.0, 0.0};
  const Vector3d bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0.0 && d4 <= d3) return {0.0, 1.0, 0.0};
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) {
    const double v = d1 / (d1 - d3);
    return {1.0 - v, v, 0.0};
  }
  const Vector3d cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0.0 && d5 <= d6) return {0.0, 0.0, 1.0};
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) {
    const double w = d2 / (d2 - d6);
    return {1.0 - w, 0.0, w};
  }
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0) {
    const double w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
    return {0.0, 1.0 - w, w};
  }
  const double denom = 1.0 / (va + vb + vc);
  const double v = vb * denom, w = vc * denom;
  return {1.0 - v - w, v, w};
}

/// The frame (t1, t2, n) as columns at the sheet point of `a`, and that point.
Matrix3d frame(const ThinSheet& s, const SheetAttachment& a, const Vertices& nodes,
               const Vertices& normals, Vector3d* point) {
  const Eigen::Index t = a.triangle;
  Vector3d p = Vector3d::Zero(), n = Vector3d::Zero();
  for (int k = 0; k < 3; ++k) {
    p += a.bary[k] * row3(nodes, s.triangles(t, k));
    n += a.bary[k] * row3(normals, s.triangles(t, k));
  }
  if (n.norm() > 0.0) n.normalize();
  const Vector3d e = row3(nodes, s.triangles(t, 1)) - row3(nodes, s.triangles(t, 0));
  Vector3d t1 = e - e.dot(n) * n;
  if (t1.norm() > 0.0) t1.normalize();
  Matrix3d f;
  f.col(0) = t1;
  f.col(1) = n.cross(t1);
  f.col(2) = n;
  *point = p;
  return f;
}

}  // namespace

Vertices sheet_normals(const ThinSheet& s, const Vertices& nodes) {
  Vertices n = Vertices::Zero(nodes.rows(), 3);
  for (Eigen::Index f = 0; f < s.triangles.rows(); ++f) {
    const Vector3d a = row3(nodes, s.triangles(f, 0)), b = row3(nodes, s.triangles(f, 1)),
                   c = row3(nodes, s.triangles(f, 2));
    const Eigen::RowVector3d area_normal = (b - a).cross(c - a).transpose();
    for (int k = 0; k < 3; ++k) n.row(s.triangles(f, k)) += area_normal;
  }
  for (Eigen::Index i = 0; i < n.rows(); ++i) {
    const double len = n.row(i).norm();
    if (len > 0.0) n.row(i) /= len;
  }
  return n;
}

Vector3d attached_position(const ThinSheet& s, const SheetAttachment& a, const Vertices& nodes,
                           const Vertices& normals) {
  Vector3d p;
  const Matrix3d f = frame(s, a, nodes, normals, &p);
  return p + f * a.local;
}

namespace {

Matrix3d skew(const Vector3d& v) {
  Matrix3d s;
  s << 0.0, -v.z(), v.y(), v.z(), 0.0, -v.x(), -v.y(), v.x(), 0.0;
  return s;
}

/// d (v / |v|) / dv; the identity where |v| = 0 (attached_position() leaves a zero vector
/// as it is).
Matrix3d normalize_jacobian(const Vector3d& v) {
  const double len = v.norm();
  if (!(len > 0.0)) return Matrix3d::Identity();
  const Vector3d u = v / len;
  return (Matrix3d::Identity() - u * u.transpose()) / len;
}

}  // namespace

void attached_position_support(const ThinSheet& s, const SheetAttachment& a,
                               std::vector<int>& involved) {
  // The nodes of the triangles around the attachment triangle's nodes.
  involved.clear();
  for (int k = 0; k < 3; ++k)
    for (int f : s.node_triangles[static_cast<size_t>(s.triangles(a.triangle, k))])
      for (int c = 0; c < 3; ++c) involved.push_back(s.triangles(f, c));
  std::sort(involved.begin(), involved.end());
  involved.erase(std::unique(involved.begin(), involved.end()), involved.end());
}

Eigen::Vector3d attached_position_jacobian(const ThinSheet& s, const SheetAttachment& a,
                                           const Vertices& nodes, std::vector<int>& involved,
                                           Eigen::Matrix<double, 3, Eigen::Dynamic>& jacobian) {
  attached_position_support(s, a, involved);
  const auto t = static_cast<Eigen::Index>(a.triangle);
  const auto m = static_cast<Eigen::Index>(involved.size());
  auto local = [&](int node) {
    return static_cast<Eigen::Index>(std::lower_bound(involved.begin(), involved.end(), node) -
                                     involved.begin());
  };
  jacobian.setZero(3, 3 * m);
  auto block = [&](int node) { return jacobian.middleCols<3>(3 * local(node)); };

  // The chain of attached_position(), forward: area normals c_k of the triangle's nodes,
  // their unit normals, the interpolated normal n, the first tangent t1, then
  // q = p + l0 t1 + l1 (n x t1) + l2 n.
  const int tri[3] = {s.triangles(t, 0), s.triangles(t, 1), s.triangles(t, 2)};
  Vector3d area[3], n_raw = Vector3d::Zero(), p = Vector3d::Zero();
  for (int k = 0; k < 3; ++k) {
    area[k].setZero();
    for (int f : s.node_triangles[static_cast<size_t>(tri[k])]) {
      const Vector3d p0 = row3(nodes, s.triangles(f, 0));
      area[k] += (row3(nodes, s.triangles(f, 1)) - p0).cross(row3(nodes, s.triangles(f, 2)) - p0);
    }
    const double len = area[k].norm();
    n_raw += a.bary[k] * (len > 0.0 ? Vector3d(area[k] / len) : area[k]);
    p += a.bary[k] * row3(nodes, tri[k]);
  }
  const double n_len = n_raw.norm();
  const Vector3d n = n_len > 0.0 ? Vector3d(n_raw / n_len) : n_raw;
  const Vector3d e = row3(nodes, tri[1]) - row3(nodes, tri[0]);
  const Vector3d t1_raw = e - e.dot(n) * n;
  const double t1_len = t1_raw.norm();
  const Vector3d t1 = t1_len > 0.0 ? Vector3d(t1_raw / t1_len) : t1_raw;
  const Vector3d q = p + a.local[0] * t1 + a.local[1] * n.cross(t1) + a.local[2] * n;

  // Backward: dq/dt1, then dq/de and dq/dn (t1 depends on both), then through the normals.
  const Matrix3d dq_dt1 = a.local[0] * Matrix3d::Identity() + a.local[1] * skew(n);
  const Matrix3d dt1 = normalize_jacobian(t1_raw);
  const Matrix3d dq_de = dq_dt1 * dt1 * (Matrix3d::Identity() - n * n.transpose());
  const Matrix3d dq_dn = a.local[2] * Matrix3d::Identity() - a.local[1] * skew(t1) +
                         dq_dt1 * dt1 * (-(n * e.transpose()) - e.dot(n) * Matrix3d::Identity());
  const Matrix3d dq_dnraw = dq_dn * normalize_jacobian(n_raw);
  block(tri[0]) -= dq_de;
  block(tri[1]) += dq_de;
  for (int k = 0; k < 3; ++k) {
    block(tri[k]) += a.bary[k] * Matrix3d::Identity();
    // c = (p1 - p0) x (p2 - p0): dc/dp0 = [p2 - p1]x, dc/dp1 = -[p2 - p0]x, dc/dp2 = [p1 - p0]x.
    const Matrix3d dq_darea = a.bary[k] * dq_dnraw * normalize_jacobian(area[k]);
    for (int f : s.node_triangles[static_cast<size_t>(tri[k])]) {
      const int i0 = s.triangles(f, 0), i1 = s.triangles(f, 1), i2 = s.triangles(f, 2);
      const Vector3d p0 = row3(nodes, i0), p1 = row3(nodes, i1), p2 = row3(nodes, i2);
      block(i0) += dq_darea * skew(p2 - p1);
      block(i1) -= dq_darea * skew(p2 - p0);
      block(i2) += dq_darea * skew(p1 - p0);
    }
  }
  return q;
}

std::optional<ThinSheet> make_thin_sheet(const Vertices& rest, const Triangles& triangles,
                                         double reach) {
  const auto pairs = opposite_layer_pairs(rest, triangles, reach);
  if (pairs.empty()) return std::nullopt;
  const int nv = static_cast<int>(rest.rows());
  const Eigen::Index nf = triangles.rows();

  // Unit triangle normals and the triangles of each undirected edge.
  std::vector<Vector3d> normal(static_cast<size_t>(nf));
  std::map<std::pair<int, int>, std::vector<int>> edge_triangles;
  for (Eigen::Index f = 0; f < nf; ++f) {
    const Vector3d a = row3(rest, triangles(f, 0)), b = row3(rest, triangles(f, 1)),
                   c = row3(rest, triangles(f, 2));
    Vector3d n = (b - a).cross(c - a);
    if (n.norm() > 0.0) n.normalize();
    normal[static_cast<size_t>(f)] = n;
    for (int k = 0; k < 3; ++k) {
      const int u = triangles(f, k), w = triangles(f, (k + 1) % 3);
      edge_triangles[{std::min(u, w), std::max(u, w)}].push_back(static_cast<int>(f));
    }
  }

  // Seed: a triangle at the first paired vertex inside a flat region (all its triangles within
  // about 25 degrees of their area-weighted mean), so the region does not start on a rim.
  std::vector<std::vector<int>> vertex_triangles(static_cast<size_t>(nv));
  for (Eigen::Index f = 0; f < nf; ++f)
    for (int k = 0; k < 3; ++k)
      vertex_triangles[static_cast<size_t>(triangles(f, k))].push_back(static_cast<int>(f));
  auto flat = [&](int v) {
    const auto& around = vertex_triangles[static_cast<size_t>(v)];
    if (around.empty()) return false;
    Vector3d mean = Vector3d::Zero();
    for (int f : around) {
      const Vector3d a = row3(rest, triangles(f, 0));
      mean += (row3(rest, triangles(f, 1)) - a).cross(row3(rest, triangles(f, 2)) - a);
    }
    if (!(mean.norm() > 0.0)) return false;
    mean.normalize();
    for (int f : around)
      if (normal[static_cast<size_t>(f)].dot(mean) < 0.9) return false;
    return true;
  };
  int seed = -1;
  for (const auto& [a, b] : pairs) {
    for (int v : {a, b})
      if (flat(v)) {
        seed = vertex_triangles[static_cast<size_t>(v)].front();
        break;
      }
    if (seed >= 0) break;
  }
  if (seed < 0) return std::nullopt;

  // The smooth region around the seed: across manifold edges between triangles within 60
  // degrees of each other (a board's rim meets its faces at 90 degrees).
  std::vector<char> in(static_cast<size_t>(nf), 0);
  std::vector<int> queue{seed};
  in[static_cast<size_t>(seed)] = 1;
  for (size_t q = 0; q < queue.size(); ++q) {
    const int f = queue[q];
    for (int k = 0; k < 3; ++k) {
      const int u = triangles(f, k), w = triangles(f, (k + 1) % 3);
      const auto& across = edge_triangles.at({std::min(u, w), std::max(u, w)});
      if (across.size() != 2) continue;
      const int g = across[0] == f ? across[1] : across[0];
      if (in[static_cast<size_t>(g)] ||
          normal[static_cast<size_t>(f)].dot(normal[static_cast<size_t>(g)]) < 0.5)
        continue;
      in[static_cast<size_t>(g)] = 1;
      queue.push_back(g);
    }
  }

  ThinSheet s;
  std::vector<char> on_sheet(static_cast<size_t>(nv), 0);
  for (Eigen::Index f = 0; f < nf; ++f)
    if (in[static_cast<size_t>(f)])
      for (int k = 0; k < 3; ++k) on_sheet[static_cast<size_t>(triangles(f, k))] = 1;
  // One layer: exactly one vertex of every facing pair.
  for (const auto& [a, b] : pairs)
    if (on_sheet[static_cast<size_t>(a)] == on_sheet[static_cast<size_t>(b)]) return std::nullopt;
  s.vertex_node.assign(static_cast<size_t>(nv), -1);
  for (int v = 0; v < nv; ++v)
    if (on_sheet[static_cast<size_t>(v)]) {
      s.vertex_node[static_cast<size_t>(v)] = static_cast<int>(s.node_vertex.size());
      s.node_vertex.push_back(v);
    }
  s.triangles.resize(static_cast<Eigen::Index>(queue.size()), 3);
  Eigen::Index row = 0;
  for (Eigen::Index f = 0; f < nf; ++f)
    if (in[static_cast<size_t>(f)]) {
      for (int k = 0; k < 3; ++k)
        s.triangles(row, k) = s.vertex_node[static_cast<size_t>(triangles(f, k))];
      ++row;
    }

  s.node_triangles.assign(s.node_vertex.size(), {});
  for (Eigen::Index f = 0; f < s.triangles.rows(); ++f)
    for (int k = 0; k < 3; ++k)
      s.node_triangles[static_cast<size_t>(s.triangles(f, k))].push_back(static_cast<int>(f));

  // Attach every other vertex to its closest sheet point (first closest triangle in order).
  Vertices nodes(static_cast<Eigen::Index>(s.node_vertex.size()), 3);
  for (size_t i = 0; i < s.node_vertex.size(); ++i)
    nodes.row(static_cast<Eigen::Index>(i)) = rest.row(s.node_vertex[i]);
  const Vertices normals = sheet_normals(s, nodes);
  s.attachment.assign(static_cast<size_t>(nv), SheetAttachment{});
  // The closest triangle by rings of cells around the vertex: after ring r every triangle not
  // yet seen lies at least r cells away, so the search stops once that is beyond the closest
  // distance found, or beyond 2 * reach (a vertex farther from the sheet fails). Ties go to the
  // lower triangle index, as over the whole sheet in order. Cells are as wide as the widest
  // triangle (a triangle meets at most 8), at least reach / 4.
  double widest = 0.0;
  for (Eigen::Index t = 0; t < s.triangles.rows(); ++t)
    for (int k = 0; k < 3; ++k)
      widest = std::max(widest,
                        (row3(nodes, s.triangles(t, k)) - row3(nodes, s.triangles(t, (k + 1) % 3)))
                            .cwiseAbs()
                            .maxCoeff());
  const detail::CellGrid cells{rest.colwise().minCoeff().transpose(),
                               std::max(widest, 0.25 * reach) * (1.0 + 1e-9)};
  std::unordered_map<std::int64_t, std::vector<int>> grid;
  for (Eigen::Index t = 0; t < s.triangles.rows(); ++t) {
    Vector3d bmin = row3(nodes, s.triangles(t, 0)), bmax = bmin;
    for (int k = 1; k < 3; ++k) {
      bmin = bmin.cwiseMin(row3(nodes, s.triangles(t, k)));
      bmax = bmax.cwiseMax(row3(nodes, s.triangles(t, k)));
    }
    const Eigen::Vector3i c0 = cells.cell_of(bmin), c1 = cells.cell_of(bmax);
    for (int z = c0[2]; z <= c1[2]; ++z)
      for (int y = c0[1]; y <= c1[1]; ++y)
        for (int x = c0[0]; x <= c1[0]; ++x)
          grid[cells.key({x, y, z})].push_back(static_cast<int>(t));
  }
  std::vector<int> seen(static_cast<size_t>(s.triangles.rows()), -1);
  for (int v = 0; v < nv; ++v) {
    if (on_sheet[static_cast<size_t>(v)]) continue;
    const Vector3d x = row3(rest, v);
    const Eigen::Vector3i c = cells.cell_of(x);
    double best_d2 = std::numeric_limits<double>::infinity();
    SheetAttachment a;
    auto try_cell = [&](const Eigen::Vector3i& at) {
      const auto it = grid.find(cells.key(at));
      if (it == grid.end()) return;
      for (const int t : it->second) {
        if (seen[static_cast<size_t>(t)] == v) continue;
        seen[static_cast<size_t>(t)] = v;
        const Vector3d p0 = row3(nodes, s.triangles(t, 0)), p1 = row3(nodes, s.triangles(t, 1)),
                       p2 = row3(nodes, s.triangles(t, 2));
        const Vector3d bary = closest_barycentric(x, p0, p1, p2);
        const double d2 = (bary[0] * p0 + bary[1] * p1 + bary[2] * p2 - x).squaredNorm();
        if (d2 < best_d2 || (d2 == best_d2 && t < a.triangle)) {
          best_d2 = d2;
          a.triangle = t;
          a.bary = bary;
        }
      }
    };
    for (int r = 0;; ++r) {
      for (int dz = -r; dz <= r; ++dz)
        for (int dy = -r; dy <= r; ++dy)
          for (int dx = -r; dx <= r; ++dx)
            if (std::max({std::abs(dx), std::abs(dy), std::abs(dz)}) == r)
              try_cell(c + Eigen::Vector3i(dx, dy, dz));
      const double beyond = r * cells.size;
      if (beyond * beyond > best_d2 || beyond > 2.0 * reach) break;
    }
    if (a.triangle < 0 || !(std::sqrt(best_d2) <= 2.0 * reach)) return std::nullopt;
    s.max_offset = std::max(s.max_offset, std::sqrt(best_d2));
    Vector3d p;
    const Matrix3d f = frame(s, a, nodes, normals, &p);
    a.local = f.transpose() * (x - p);
    s.attachment[static_cast<size_t>(v)] = a;
  }
  return s;
}

}  // namespace pbve
