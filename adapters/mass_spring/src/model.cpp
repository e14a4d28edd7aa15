#include "model.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <functional>
#include <numbers>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <unordered_map>

#include <tbb/parallel_for.h>
#include <Eigen/Geometry>

namespace pbve::mass_spring::detail {

namespace {

using Eigen::Vector3d;

Vector3d row(const Vertices& v, int i) {
  return v.row(i).transpose();
}

// Generalized winding number of a closed (or nearly closed) surface at p.
double winding_number(const Vertices& x, const Triangles& t, const Vector3d& p) {
  double total = 0.0;
  for (Eigen::Index f = 0; f < t.rows(); ++f) {
    const Vector3d a = row(x, t(f, 0)) - p, b = row(x, t(f, 1)) - p, c = row(x, t(f, 2)) - p;
    const double la = a.norm(), lb = b.norm(), lc = c.norm();
    const double num = a.dot(b.cross(c));
    const double den = la * lb * lc + a.dot(b) * lc + a.dot(c) * lb + b.dot(c) * la;
    total += 2.0 * std::atan2(num, den);
  }
  return total / (4.0 * std::numbers::pi);
}

struct EdgeInfo {
  int a, b;
  std::vector<int> opposite;  // opposite vertex of each adjacent triangle
  double area = 0.0;          // a third of each adjacent triangle's area
};

std::vector<EdgeInfo> collect_edges(const Triangles& t, const Eigen::VectorXd& tri_area) {
  struct Item {
    int a, b, opp, tri;
  };
  std::vector<Item> items;
  items.reserve(static_cast<size_t>(3 * t.rows()));
  for (Eigen::Index f = 0; f < t.rows(); ++f)
    for (int e = 0; e < 3; ++e) {
      const int i = t(f, e), j = t(f, (e + 1) % 3), k = t(f, (e + 2) % 3);
      items.push_back({std::min(i, j), std::max(i, j), k, static_cast<int>(f)});
    }
  std::sort(items.begin(), items.end(), [](const Item& p, const Item& q) {
    return p.a != q.a ? p.a < q.a : (p.b != q.b ? p.b < q.b : p.tri < q.tri);
  });
  std::vector<EdgeInfo> edges;
  for (size_t s = 0; s < items.size();) {
    size_t e = s;
    EdgeInfo info{items[s].a, items[s].b, {}, 0.0};
    while (e < items.size() && items[e].a == info.a && items[e].b == info.b) {
      info.opposite.push_back(items[e].opp);
      info.area += tri_area[items[e].tri] / 3.0;
      ++e;
    }
    edges.push_back(std::move(info));
    s = e;
  }
  return edges;
}

// Ties between the two layers of a thin closed surface (see Params::layer_stiffness): a spring
// per pair found by opposite_layer_pairs().
template <class AddSpring>
void add_layer_ties(const Vertices& x, const Triangles& t, const Eigen::VectorXd& vertex_area,
                    double reach, double modulus, AddSpring&& add_spring) {
  for (const auto& [a, b] : opposite_layer_pairs(x, t, reach)) {
    const double l0 = (row(x, b) - row(x, a)).norm();
    if (!(l0 > 0.0)) continue;
    add_spring(a, b, l0, modulus * 0.5 * (vertex_area[a] + vertex_area[b]) / (l0 * l0));
  }
}

// A hinge (interior edge x0 x1 between the triangles x0 x1 x2 and x1 x0 x3) that is flat at
// rest, with the weights of its quadratic bending energy (Bergou et al. 2006, "A quadratic
// bending model for inextensible surfaces"): E = 1/2 B / (A0 + A1) |sum_i K_i x_i|^2. The sum
// is a discrete mean-curvature normal; E -> 1/2 B integral (k1 + k2)^2 dA as the mesh is
// refined (1/2 B k^2 A on a cylinder of curvature k), and it vanishes on every flat
// configuration, so rigid motions of a flat hinge cost nothing.
struct FlatHinge {
  std::array<int, 4> v;
  std::array<double, 4> K;
  double area;  // A0 + A1
};

// Rest hinges whose dihedral angle is at most this are flat (covers coordinates rounded to
// single precision or to a few decimals in a file). Their quadratic energy subtracts its rest
// value (Model::bend_rest_force), so a rest shape within it is still at equilibrium.
constexpr double flat_hinge_angle = 1e-3;  // rad

std::optional<FlatHinge> flat_hinge(const Vertices& x, int i0, int i1, int i2, int i3) {
  const Vector3d x0 = row(x, i0), x1 = row(x, i1), x2 = row(x, i2), x3 = row(x, i3);
  const Vector3d e0 = x1 - x0, e1 = x2 - x0, e2 = x3 - x0, e3 = x2 - x1, e4 = x3 - x1;
  const Vector3d n0 = e0.cross(e1), n1 = e2.cross(e0);  // both along the normal when flat
  const double a0 = n0.norm(), a1 = n1.norm();
  if (!(a0 > 0.0) || !(a1 > 0.0)) return std::nullopt;
  if (std::atan2(n0.cross(n1).norm(), n0.dot(n1)) > flat_hinge_angle) return std::nullopt;
  const double c01 = e0.dot(e1) / a0, c02 = e0.dot(e2) / a1;    // cotangents at x0
  const double c03 = -e0.dot(e3) / a0, c04 = -e0.dot(e4) / a1;  // at x1
  FlatHinge h;
  h.v = {i0, i1, i2, i3};
  h.K = {c03 + c04, c01 + c02, -c01 - c03, -c02 - c04};
  h.area = 0.5 * (a0 + a1);
  for (double k : h.K)
    if (!std::isfinite(k)) return std::nullopt;
  return h;
}

// Adds the hinges' energies as isotropic couplings (-B/(A0+A1) K_i K_j on the pair i j: the
// rows of K^T K sum to zero) on the springs of their six vertex pairs (made, with no stiffness,
// where missing), and their rest forces.
void add_flat_hinges(const Vertices& x, const std::vector<FlatHinge>& hinges, double B, Model& m) {
  m.flat_hinges = static_cast<int>(hinges.size());
  if (hinges.empty()) return;
  std::unordered_map<std::uint64_t, size_t> index;
  auto key = [](int a, int b) {
    return (static_cast<std::uint64_t>(std::min(a, b)) << 32) |
           static_cast<std::uint32_t>(std::max(a, b));
  };
  for (size_t s = 0; s < m.springs.size(); ++s)
    index.emplace(key(m.springs[s].a, m.springs[s].b), s);
  m.bend_rest_force = Eigen::VectorXd::Zero(3 * x.rows());
  for (const FlatHinge& h : hinges) {
    const double w = B / h.area;
    Vector3d kx = Vector3d::Zero();
    for (int i = 0; i < 4; ++i)
      kx += h.K[static_cast<size_t>(i)] * row(x, h.v[static_cast<size_t>(i)]);
    for (int i = 0; i < 4; ++i) {
      const auto vi = static_cast<size_t>(i);
      m.bend_rest_force.segment<3>(3 * h.v[vi]) -= (w * h.K[vi]) * kx;
      for (int j = i + 1; j < 4; ++j) {
        const auto vj = static_cast<size_t>(j);
        const auto [it, added] = index.emplace(key(h.v[vi], h.v[vj]), m.springs.size());
        if (added)
          m.springs.push_back(
              {h.v[vi], h.v[vj], (row(x, h.v[vj]) - row(x, h.v[vi])).norm(), 0.0, 0.0});
        m.springs[it->second].iso -= w * h.K[vi] * h.K[vj];
      }
    }
  }
}

}  // namespace

double surface_area(const Vertices& positions, const Triangles& triangles) {
  double area = 0.0;
  for (Eigen::Index f = 0; f < triangles.rows(); ++f) {
    const Vector3d a = row(positions, triangles(f, 0));
    area += 0.5 *
            (row(positions, triangles(f, 1)) - a).cross(row(positions, triangles(f, 2)) - a).norm();
  }
  return area;
}

std::optional<ThinSheet> thin_sheet_of(const Mesh& mesh, const Vertices& positions,
                                       const std::vector<int>& anchors, const Params& params) {
  const auto nv = positions.rows();
  const Triangles& t = mesh.triangles;
  if (nv == 0 || t.rows() == 0 || (mesh.num_vertices() != 0 && mesh.num_vertices() != nv) ||
      !positions.allFinite() || (t.size() > 0 && (t.minCoeff() < 0 || t.maxCoeff() >= nv)))
    return std::nullopt;
  std::vector<int> sorted = anchors;
  std::sort(sorted.begin(), sorted.end());
  if (std::adjacent_find(sorted.begin(), sorted.end()) != sorted.end() ||
      (!sorted.empty() && (sorted.front() < 0 || sorted.back() >= nv)))
    return std::nullopt;
  const double reach =
      params.layer_distance > 0.0 ? params.layer_distance : default_layer_reach(positions, t);
  if (!(reach > 0.0)) return std::nullopt;
  return make_thin_sheet(positions, t, reach);
}

namespace {

/// The lattice stiffness at a rest-frame point: that of the last of params.regions containing
/// it in mesh coordinates, else params.volume_stiffness. Mesh coordinates map to the rest
/// positions by the best-fitting similarity transform (the editor poses the mesh rigidly).
std::function<double(const Vector3d&)> region_stiffness(const Mesh& mesh, const Vertices& positions,
                                                        const Params& params) {
  const double E = params.volume_stiffness;
  if (params.regions.empty()) return [E](const Vector3d&) { return E; };
  Eigen::Matrix4d to_mesh = Eigen::Matrix4d::Identity();
  if (mesh.num_vertices() != 0) {
    const Eigen::Matrix3Xd src = mesh.vertices.transpose(), dst = positions.transpose();
    const Eigen::Matrix4d fit = Eigen::umeyama(src, dst, true);
    const Eigen::Matrix3Xd mapped =
        (fit.topLeftCorner<3, 3>() * src).colwise() + fit.topRightCorner<3, 1>();
    const double size = (dst.rowwise().maxCoeff() - dst.rowwise().minCoeff()).norm();
    const double misfit = (mapped - dst).colwise().norm().maxCoeff();
    if (!(misfit <= 1e-6 * size))
      throw std::invalid_argument(
          "mass_spring: parameter regions is given in mesh coordinates, but the rest positions "
          "are not a rigid or similar copy of the mesh (misfit " +
          std::to_string(misfit) + " m)");
    to_mesh = fit.inverse();
  }
  const Eigen::Matrix3d R = to_mesh.topLeftCorner<3, 3>();
  const Vector3d t = to_mesh.topRightCorner<3, 1>();
  return [R, t, E, regions = params.regions](const Vector3d& p) {
    const Vector3d q = R * p + t;
    double k = E;
    for (const StiffnessRegion& r : regions)
      if ((q.array() >= r.min.array()).all() && (q.array() <= r.max.array()).all())
        k = r.volume_stiffness;
    return k;
  };
}

}  // namespace

Model build_model(const Mesh& mesh, const Vertices& positions, std::vector<int> anchors,
                  const Params& params) {
  params.validate();
  const int nv = static_cast<int>(positions.rows());
  if (nv == 0) throw std::invalid_argument("mass_spring: positions are empty");
  if (mesh.num_vertices() != 0 && mesh.num_vertices() != nv)
    throw std::invalid_argument("mass_spring: positions have " + std::to_string(nv) +
                                " rows but the mesh has " + std::to_string(mesh.num_vertices()) +
                                " vertices");
  if (mesh.num_triangles() == 0) throw std::invalid_argument("mass_spring: mesh has no triangles");
  if (!positions.allFinite())
    throw std::invalid_argument("mass_spring: positions contain non-finite values");
  const Triangles& tris = mesh.triangles;
  for (Eigen::Index f = 0; f < tris.rows(); ++f)
    for (int c = 0; c < 3; ++c)
      if (tris(f, c) < 0 || tris(f, c) >= nv)
        throw std::invalid_argument("mass_spring: triangle " + std::to_string(f) +
                                    " has vertex index " + std::to_string(tris(f, c)) +
                                    " out of range [0, " + std::to_string(nv) + ")");
  std::sort(anchors.begin(), anchors.end());
  for (size_t i = 0; i < anchors.size(); ++i) {
    if (anchors[i] < 0 || anchors[i] >= nv)
      throw std::invalid_argument("mass_spring: anchor " + std::to_string(anchors[i]) +
                                  " out of range [0, " + std::to_string(nv) + ")");
    if (i > 0 && anchors[i] == anchors[i - 1])
      throw std::invalid_argument("mass_spring: anchor " + std::to_string(anchors[i]) +
                                  " listed twice");
  }

  Model m;
  m.params = params;
  m.num_surface = nv;
  m.anchors = anchors;

  // Per-triangle areas and per-vertex area shares.
  Eigen::VectorXd tri_area(tris.rows());
  Eigen::VectorXd vertex_area = Eigen::VectorXd::Zero(nv);
  double signed_volume = 0.0;
  for (Eigen::Index f = 0; f < tris.rows(); ++f) {
    const Vector3d a = row(positions, tris(f, 0)), b = row(positions, tris(f, 1)),
                   c = row(positions, tris(f, 2));
    tri_area[f] = 0.5 * (b - a).cross(c - a).norm();
    for (int k = 0; k < 3; ++k) vertex_area[tris(f, k)] += tri_area[f] / 3.0;
    signed_volume += a.dot(b.cross(c)) / 6.0;
  }
  const double total_area = tri_area.sum();
  if (!(total_area > 0.0)) throw std::invalid_argument("mass_spring: mesh has zero area");

  const std::vector<EdgeInfo> edges = collect_edges(tris, tri_area);
  double edge_sum = 0.0;
  for (const EdgeInfo& e : edges) edge_sum += (row(positions, e.b) - row(positions, e.a)).norm();
  m.char_length = edge_sum / static_cast<double>(edges.size());
  if (!(m.char_length > 0.0))
    throw std::invalid_argument("mass_spring: all edges have zero length");

  // Surface springs: edges (stretch), and across each interior edge (shear, plus bending where
  // the hinge is creased at rest; flat hinges bend by the quadratic energy below).
  auto add_spring = [&m](int a, int b, double rest, double k) {
    if (a == b || !(k > 0.0) || !(rest > 0.0)) return;
    m.springs.push_back({a, b, rest, k, 0.0});
  };
  std::vector<FlatHinge> flat;
  for (const EdgeInfo& e : edges) {
    const double l0 = (row(positions, e.b) - row(positions, e.a)).norm();
    add_spring(e.a, e.b, l0, params.stretch_stiffness * e.area / (l0 * l0));
    if (e.opposite.size() == 2) {
      const int c = e.opposite[0], d = e.opposite[1];
      const double l1 = (row(positions, d) - row(positions, c)).norm();
      std::optional<FlatHinge> hinge;
      if (params.bend_stiffness > 0.0) hinge = flat_hinge(positions, e.a, e.b, c, d);
      if (hinge) flat.push_back(*hinge);
      const double bend = hinge ? 0.0 : params.bend_stiffness;
      if (l1 > 0.0) add_spring(c, d, l1, (params.shear_stiffness * e.area + bend) / (l1 * l1));
    }
  }
  add_flat_hinges(positions, flat, params.bend_stiffness, m);

  if (params.material == Material::cloth && params.layer_stiffness > 0.0) {
    const size_t before = m.springs.size();
    add_layer_ties(
        positions, tris, vertex_area,
        params.layer_distance > 0.0 ? params.layer_distance : default_layer_reach(positions, tris),
        params.layer_stiffness, add_spring);
    m.layer_ties = static_cast<int>(m.springs.size() - before);
  }

  std::vector<Vector3d> lattice;  // interior node positions
  const bool solid = params.material != Material::cloth;
  Eigen::VectorXd surface_mass(nv);
  Eigen::VectorXd lattice_mass;
  if (!solid) {
    surface_mass = params.density * vertex_area;
  } else {
    // Closed first: the volume of an open surface depends on the origin (a sheet far from the
    // camera seemed to enclose one).
    if (const auto hole = first_boundary_edge(tris))
      throw std::invalid_argument(
          "mass_spring: material '" + to_string(params.material) +
          "' needs a closed surface; the edge between vertices " + std::to_string(hole->first) +
          " and " + std::to_string(hole->second) + " borders a hole (an open surface is cloth)");
    const double volume = std::abs(signed_volume);
    if (!(volume > 1e-9 * std::pow(total_area, 1.5)))
      throw std::invalid_argument(
          "mass_spring: material '" + to_string(params.material) +
          "' needs a closed surface that encloses a volume; this mesh encloses none (use cloth)");
    const Vector3d lo = positions.colwise().minCoeff().transpose();
    const Vector3d hi = positions.colwise().maxCoeff().transpose();
    const double target_nodes = params.material == Material::stiff ? 200.0 : 150.0;
    double s = params.lattice_spacing;
    if (s == 0.0) s = std::cbrt(volume / target_nodes);
    const Vector3d extent = hi - lo, center = 0.5 * (hi + lo);
    // Cell counts in double first: a tiny spacing would overflow int.
    Vector3d cells_per_axis;
    for (int k = 0; k < 3; ++k) cells_per_axis[k] = std::max(1.0, std::ceil(extent[k] / s));
    if (!(cells_per_axis.prod() <= 2e6)) {
      std::ostringstream message;
      message << "mass_spring: parameter lattice_spacing " << s << " m gives "
              << cells_per_axis.prod() << " lattice cells, more than 2e6; choose a larger one";
      throw std::invalid_argument(message.str());
    }
    const Eigen::Vector3i n = cells_per_axis.cast<int>();
    const Vector3d origin = center - 0.5 * s * (n.cast<double>() - Vector3d::Ones());
    const int cells = n[0] * n[1] * n[2];
    std::vector<char> inside(static_cast<size_t>(cells), 0);
    auto cell_pos = [&](int id) {
      const int i = id % n[0], j = (id / n[0]) % n[1], k = id / (n[0] * n[1]);
      return Vector3d(origin + s * Vector3d(i, j, k));
    };
    tbb::parallel_for(0, cells, [&](int id) {
      inside[static_cast<size_t>(id)] =
          std::abs(winding_number(positions, tris, cell_pos(id))) > 0.5 ? 1 : 0;
    });
    std::vector<int> lattice_id(static_cast<size_t>(cells), -1);
    for (int id = 0; id < cells; ++id)
      if (inside[static_cast<size_t>(id)]) {
        lattice_id[static_cast<size_t>(id)] = static_cast<int>(lattice.size());
        lattice.push_back(cell_pos(id));
      }
    const auto stiffness_at = region_stiffness(mesh, positions, params);
    // Lattice springs: 3 axis, 6 face-diagonal and 4 body-diagonal neighbours per node (each
    // pair once), each standing for a quarter of a cell volume.
    const int offsets[13][3] = {{1, 0, 0},  {0, 1, 0},  {0, 0, 1},  {1, 1, 0},  {1, -1, 0},
                                {1, 0, 1},  {1, 0, -1}, {0, 1, 1},  {0, 1, -1}, {1, 1, 1},
                                {1, 1, -1}, {1, -1, 1}, {1, -1, -1}};
    for (int id = 0; id < cells; ++id) {
      const int a = lattice_id[static_cast<size_t>(id)];
      if (a < 0) continue;
      const int i = id % n[0], j = (id / n[0]) % n[1], k = id / (n[0] * n[1]);
      for (const auto& o : offsets) {
        const int i2 = i + o[0], j2 = j + o[1], k2 = k + o[2];
        if (i2 < 0 || j2 < 0 || k2 < 0 || i2 >= n[0] || j2 >= n[1] || k2 >= n[2]) continue;
        const int b = lattice_id[static_cast<size_t>(i2 + n[0] * (j2 + n[1] * k2))];
        if (b < 0) continue;
        const double l0 =
            s * std::sqrt(static_cast<double>(o[0] * o[0] + o[1] * o[1] + o[2] * o[2]));
        const double E =
            stiffness_at(0.5 * (lattice[static_cast<size_t>(a)] + lattice[static_cast<size_t>(b)]));
        add_spring(nv + a, nv + b, l0, E * 0.25 * s * s * s / (l0 * l0));
      }
    }
    // Ties: each surface vertex to up to 8 lattice nodes within 1.5 s (else its nearest node
    // within 3 s), sharing a shell volume of area * s; rest lengths below s/2 count as s/2 in
    // the stiffness to avoid extreme springs.
    if (!lattice.empty()) {
      for (int v = 0; v < nv; ++v) {
        const Vector3d p = row(positions, v);
        const Vector3d g = (p - origin) / s;
        std::vector<std::pair<double, int>> near;
        for (int dk = -2; dk <= 3; ++dk)
          for (int dj = -2; dj <= 3; ++dj)
            for (int di = -2; di <= 3; ++di) {
              const int i = static_cast<int>(std::floor(g[0])) + di,
                        j = static_cast<int>(std::floor(g[1])) + dj,
                        k = static_cast<int>(std::floor(g[2])) + dk;
              if (i < 0 || j < 0 || k < 0 || i >= n[0] || j >= n[1] || k >= n[2]) continue;
              const int b = lattice_id[static_cast<size_t>(i + n[0] * (j + n[1] * k))];
              if (b < 0) continue;
              const double d = (lattice[static_cast<size_t>(b)] - p).norm();
              if (d <= 3.0 * s) near.push_back({d, b});
            }
        std::sort(near.begin(), near.end());
        size_t count = 0;
        while (count < near.size() && count < 8 && near[count].first <= 1.5 * s) ++count;
        if (count == 0 && !near.empty()) count = 1;
        for (size_t q = 0; q < count; ++q) {
          const double l0 = near[q].first, le = std::max(l0, 0.5 * s);
          const double E = stiffness_at(0.5 * (p + lattice[static_cast<size_t>(near[q].second)]));
          add_spring(v, nv + near[q].second, l0,
                     E * vertex_area[v] * s / static_cast<double>(count) / (le * le));
        }
      }
    }
    // Masses: each lattice node carries a cell, the surface carries the rest of the volume in
    // proportion to vertex area (at least 20% of it); scaled to density * volume in total.
    const double cell_volume = s * s * s;
    const double nl = static_cast<double>(lattice.size());
    const double shell = std::max(volume - nl * cell_volume, 0.2 * volume);
    const double scale = volume / (shell + nl * cell_volume);
    surface_mass = params.density * scale * shell * vertex_area / total_area;
    lattice_mass = Eigen::VectorXd::Constant(static_cast<Eigen::Index>(lattice.size()),
                                             params.density * scale * cell_volume);
  }
  // Vertices in no triangle of nonzero area get the mean vertex mass (they move freely).
  const double mean_mass = surface_mass.sum() / nv;
  for (int v = 0; v < nv; ++v)
    if (!(surface_mass[v] > 0.0)) surface_mass[v] = mean_mass;

  // Drop lattice nodes without springs.
  {
    std::vector<int> degree(lattice.size(), 0);
    for (const Spring& sp : m.springs) {
      if (sp.a >= nv) ++degree[static_cast<size_t>(sp.a - nv)];
      if (sp.b >= nv) ++degree[static_cast<size_t>(sp.b - nv)];
    }
    std::vector<int> remap(lattice.size(), -1);
    std::vector<Vector3d> kept;
    std::vector<double> kept_mass;
    for (size_t i = 0; i < lattice.size(); ++i)
      if (degree[i] > 0) {
        remap[i] = static_cast<int>(kept.size());
        kept.push_back(lattice[i]);
        kept_mass.push_back(lattice_mass[static_cast<Eigen::Index>(i)]);
      }
    for (Spring& sp : m.springs) {
      if (sp.a >= nv) sp.a = nv + remap[static_cast<size_t>(sp.a - nv)];
      if (sp.b >= nv) sp.b = nv + remap[static_cast<size_t>(sp.b - nv)];
    }
    lattice = std::move(kept);
    lattice_mass =
        Eigen::Map<Eigen::VectorXd>(kept_mass.data(), static_cast<Eigen::Index>(kept_mass.size()));
  }

  m.num_nodes = nv + static_cast<int>(lattice.size());
  m.mass.resize(m.num_nodes);
  m.mass.head(nv) = surface_mass;
  if (!lattice.empty()) m.mass.tail(static_cast<Eigen::Index>(lattice.size())) = lattice_mass;
  m.rest.resize(3 * m.num_nodes);
  for (int v = 0; v < nv; ++v) m.rest.segment<3>(3 * v) = row(positions, v);
  for (size_t i = 0; i < lattice.size(); ++i)
    m.rest.segment<3>(3 * (nv + static_cast<Eigen::Index>(i))) = lattice[i];
  if (m.bend_rest_force.size() > 0)
    m.bend_rest_force.conservativeResizeLike(Eigen::VectorXd::Zero(3 * m.num_nodes));
  for (Eigen::Index i = 0; i < m.mass.size(); ++i)
    if (!(m.mass[i] > 0.0) || !std::isfinite(m.mass[i]))
      throw std::invalid_argument("mass_spring: node " + std::to_string(i) +
                                  " has a non-positive mass; check parameter density");

  // Free blocks.
  m.free_index.assign(static_cast<size_t>(m.num_nodes), 0);
  for (int a : m.anchors) m.free_index[static_cast<size_t>(a)] = -1;
  for (int i = 0; i < m.num_nodes; ++i)
    if (m.free_index[static_cast<size_t>(i)] >= 0) {
      m.free_index[static_cast<size_t>(i)] = static_cast<int>(m.free_nodes.size());
      m.free_nodes.push_back(i);
    }

  // Sparsity pattern of the free-free matrix and block offsets.
  const int nf = static_cast<int>(m.free_nodes.size());
  std::vector<Eigen::Triplet<double>> trip;
  auto add_block = [&trip](int r, int c) {
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) trip.emplace_back(3 * r + i, 3 * c + j, 0.0);
  };
  for (int f = 0; f < nf; ++f) add_block(f, f);
  for (const Spring& sp : m.springs) {
    const int fa = m.free_index[static_cast<size_t>(sp.a)];
    const int fb = m.free_index[static_cast<size_t>(sp.b)];
    if (fa >= 0 && fb >= 0) {
      add_block(fa, fb);
      add_block(fb, fa);
    }
  }
  m.pattern.resize(3 * nf, 3 * nf);
  m.pattern.setFromTriplets(trip.begin(), trip.end());
  m.pattern.makeCompressed();
  const auto& P = m.pattern;
  auto offset = [&P](int r, int c, int j) {
    const int col = 3 * c + j;
    const int* begin = P.innerIndexPtr() + P.outerIndexPtr()[col];
    const int* end = P.innerIndexPtr() + P.outerIndexPtr()[col + 1];
    const int* it = std::lower_bound(begin, end, 3 * r);
    return static_cast<int>(it - P.innerIndexPtr());
  };
  m.diag_offset.resize(static_cast<size_t>(nf));
  for (int f = 0; f < nf; ++f)
    for (int j = 0; j < 3; ++j)
      m.diag_offset[static_cast<size_t>(f)][static_cast<size_t>(j)] = offset(f, f, j);
  m.spring_offset.resize(m.springs.size());
  for (size_t s = 0; s < m.springs.size(); ++s) {
    const int fa = m.free_index[static_cast<size_t>(m.springs[s].a)];
    const int fb = m.free_index[static_cast<size_t>(m.springs[s].b)];
    for (int j = 0; j < 3; ++j) {
      m.spring_offset[s][static_cast<size_t>(j)] = (fa >= 0 && fb >= 0) ? offset(fa, fb, j) : -1;
      m.spring_offset[s][static_cast<size_t>(3 + j)] =
          (fa >= 0 && fb >= 0) ? offset(fb, fa, j) : -1;
    }
  }
  m.incident_start.assign(static_cast<size_t>(nf) + 1, 0);
  for (const Spring& sp : m.springs)
    for (int end : {sp.a, sp.b}) {
      const int f = m.free_index[static_cast<size_t>(end)];
      if (f >= 0) ++m.incident_start[static_cast<size_t>(f) + 1];
    }
  for (int f = 0; f < nf; ++f)
    m.incident_start[static_cast<size_t>(f) + 1] += m.incident_start[static_cast<size_t>(f)];
  m.incident_spring.resize(static_cast<size_t>(m.incident_start.back()));
  m.incident_column.resize(m.incident_spring.size());
  std::vector<int> fill(m.incident_start.begin(), m.incident_start.end() - 1);
  for (size_t s = 0; s < m.springs.size(); ++s) {
    const int fa = m.free_index[static_cast<size_t>(m.springs[s].a)];
    const int fb = m.free_index[static_cast<size_t>(m.springs[s].b)];
    // Block (fb, fa) lies in fa's columns (spring_offset[3..5]), block (fa, fb) in fb's.
    if (fa >= 0) {
      const auto k = static_cast<size_t>(fill[static_cast<size_t>(fa)]++);
      m.incident_spring[k] = static_cast<int>(s);
      m.incident_column[k] = fb >= 0 ? 3 : -1;
    }
    if (fb >= 0) {
      const auto k = static_cast<size_t>(fill[static_cast<size_t>(fb)]++);
      m.incident_spring[k] = static_cast<int>(s);
      m.incident_column[k] = fa >= 0 ? 0 : -1;
    }
  }
  return m;
}

}  // namespace pbve::mass_spring::detail
