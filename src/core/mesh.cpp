// Mesh validation, per-triangle geometry, scaling and refinement by edge splitting.

#include "pbve/core/mesh.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include <Eigen/Geometry>

#include "cell_grid.hpp"
#include "mesh_arrays.hpp"
#include "pbve/core/error.hpp"

namespace pbve {
namespace {

constexpr std::size_t kFirstFew = 8;

/// Undirected edge key: the smaller vertex id in the high 32 bits.
std::uint64_t edge_key(int a, int b) {
  const auto lo = static_cast<std::uint32_t>(std::min(a, b));
  const auto hi = static_cast<std::uint32_t>(std::max(a, b));
  return (static_cast<std::uint64_t>(lo) << 32) | hi;
}
/// The keys of every proper edge of every triangle (a triangle with a repeated vertex has
/// none), sorted: an edge appears once per triangle using it.
std::vector<std::uint64_t> sorted_edge_keys(const Triangles& triangles) {
  std::vector<std::uint64_t> keys;
  keys.reserve(static_cast<std::size_t>(triangles.rows()) * 3);
  for (Eigen::Index f = 0; f < triangles.rows(); ++f) {
    const int a = triangles(f, 0), b = triangles(f, 1), c = triangles(f, 2);
    if (a == b || b == c || a == c) continue;
    keys.push_back(edge_key(a, b));
    keys.push_back(edge_key(b, c));
    keys.push_back(edge_key(c, a));
  }
  std::sort(keys.begin(), keys.end());
  return keys;
}
int key_first(std::uint64_t k) {
  return static_cast<int>(k >> 32);
}
int key_second(std::uint64_t k) {
  return static_cast<int>(k & 0xffffffffu);
}

Eigen::Vector3d row(const Vertices& v, int i) {
  return v.row(i).transpose();
}

std::string list_ids(const std::vector<int>& ids) {
  std::string s;
  for (std::size_t i = 0; i < ids.size(); ++i) s += (i ? ", " : "") + std::to_string(ids[i]);
  return s;
}

}  // namespace

std::string MeshReport::summary() const {
  if (ok()) return {};
  std::string s;
  if (degenerate_count > 0) {
    s += std::to_string(degenerate_count) + " degenerate triangle" +
         (degenerate_count == 1 ? "" : "s") + " (first: " + list_ids(degenerate_first) + ")";
  }
  if (non_manifold_edge_count > 0) {
    if (!s.empty()) s += "; ";
    s += std::to_string(non_manifold_edge_count) + " non-manifold edge" +
         (non_manifold_edge_count == 1 ? "" : "s") + " shared by more than two triangles (first:";
    for (std::size_t i = 0; i < non_manifold_first.size(); ++i)
      s += (i ? ", " : " ") + std::to_string(non_manifold_first[i].first) + "-" +
           std::to_string(non_manifold_first[i].second);
    s += ")";
  }
  if (boundary_edge_count > 0)
    s += "; " + std::to_string(boundary_edge_count) + " boundary edge" +
         (boundary_edge_count == 1 ? "" : "s");
  return s + ".";
}

MeshReport validate_mesh(const Mesh& mesh, const std::filesystem::path& source) {
  const int nv = mesh.num_vertices();
  const int nf = mesh.num_triangles();
  if (nv == 0) throw InputError("empty mesh: no vertices", source);
  if (nf == 0) throw InputError("empty mesh: no triangles", source);
  for (int v = 0; v < nv; ++v)
    for (int k = 0; k < 3; ++k)
      if (!std::isfinite(mesh.vertices(v, k)))
        throw InputError("non-finite coordinate " + std::to_string(mesh.vertices(v, k)), source, 0,
                         "vertex " + std::to_string(v));
  for (int f = 0; f < nf; ++f)
    for (int k = 0; k < 3; ++k) {
      const int i = mesh.triangles(f, k);
      if (i < 0 || i >= nv)
        throw InputError("vertex index " + std::to_string(i) + " out of range: the mesh has " +
                             std::to_string(nv) + " vertices",
                         source, 0, "triangle " + std::to_string(f));
    }
  const auto nfs = static_cast<std::size_t>(nf);
  if (!mesh.triangle_part.empty() && mesh.triangle_part.size() != nfs)
    throw InputError("triangle_part has " + std::to_string(mesh.triangle_part.size()) +
                         " entries for " + std::to_string(nf) + " triangles",
                     source);
  if (!mesh.interior.empty() && mesh.interior.size() != nfs)
    throw InputError("interior has " + std::to_string(mesh.interior.size()) + " entries for " +
                         std::to_string(nf) + " triangles",
                     source);
  for (std::size_t f = 0; f < mesh.triangle_part.size(); ++f) {
    const int p = mesh.triangle_part[f];
    if (p < 0 || (p > 0 && p >= mesh.num_parts()))
      throw InputError("part id " + std::to_string(p) + " out of range: the mesh has " +
                           std::to_string(mesh.num_parts()) + " parts",
                       source, 0, "triangle " + std::to_string(f));
  }

  MeshReport report;
  // Degenerate: a repeated vertex, or an area tiny relative to the longest edge squared.
  for (int f = 0; f < nf; ++f) {
    const int a = mesh.triangles(f, 0), b = mesh.triangles(f, 1), c = mesh.triangles(f, 2);
    bool degenerate = a == b || b == c || a == c;
    if (!degenerate) {
      const Eigen::Vector3d pa = row(mesh.vertices, a), pb = row(mesh.vertices, b),
                            pc = row(mesh.vertices, c);
      const double l2 =
          std::max({(pb - pa).squaredNorm(), (pc - pb).squaredNorm(), (pa - pc).squaredNorm()});
      const double twice_area = (pb - pa).cross(pc - pa).norm();
      degenerate = l2 == 0.0 || twice_area <= 1e-12 * l2;
    }
    if (degenerate) {
      if (report.degenerate_first.size() < kFirstFew) report.degenerate_first.push_back(f);
      ++report.degenerate_count;
    }
  }
  // Edge use counts by sorting all edge keys.
  const std::vector<std::uint64_t> keys = sorted_edge_keys(mesh.triangles);
  std::vector<std::uint64_t> non_manifold;
  for (std::size_t i = 0; i < keys.size();) {
    std::size_t j = i + 1;
    while (j < keys.size() && keys[j] == keys[i]) ++j;
    const std::size_t uses = j - i;
    if (uses == 1) ++report.boundary_edge_count;
    if (uses > 2) {
      ++report.non_manifold_edge_count;
      if (report.non_manifold_first.size() < kFirstFew)
        report.non_manifold_first.emplace_back(key_first(keys[i]), key_second(keys[i]));
    }
    i = j;
  }
  return report;
}

void check_triangle_indices(const Triangles& triangles, Eigen::Index num_vertices,
                            const char* who) {
  if (triangles.size() == 0 || (triangles.minCoeff() >= 0 && triangles.maxCoeff() < num_vertices))
    return;
  for (Eigen::Index f = 0; f < triangles.rows(); ++f)
    for (int k = 0; k < 3; ++k)
      if (triangles(f, k) < 0 || triangles(f, k) >= num_vertices)
        throw std::invalid_argument(std::string(who) + ": triangle " + std::to_string(f) +
                                    " has vertex index " + std::to_string(triangles(f, k)) +
                                    " outside [0, " + std::to_string(num_vertices) + ")");
}

std::optional<std::pair<int, int>> first_boundary_edge(const Triangles& triangles) {
  const std::vector<std::uint64_t> keys = sorted_edge_keys(triangles);
  for (std::size_t i = 0; i < keys.size();) {
    std::size_t j = i + 1;
    while (j < keys.size() && keys[j] == keys[i]) ++j;
    if (j - i == 1) return std::make_pair(key_first(keys[i]), key_second(keys[i]));
    i = j;
  }
  return std::nullopt;
}

Vertices triangle_normals(const Vertices& vertices, const Triangles& triangles) {
  check_triangle_indices(triangles, vertices.rows(), "triangle_normals");
  Vertices n(triangles.rows(), 3);
  for (Eigen::Index f = 0; f < triangles.rows(); ++f) {
    const Eigen::Vector3d a = row(vertices, triangles(f, 0));
    const Eigen::Vector3d b = row(vertices, triangles(f, 1));
    const Eigen::Vector3d c = row(vertices, triangles(f, 2));
    n.row(f) = (b - a).cross(c - a).transpose();
  }
  return n;
}

Eigen::VectorXd triangle_areas(const Vertices& vertices, const Triangles& triangles) {
  check_triangle_indices(triangles, vertices.rows(), "triangle_areas");
  Eigen::VectorXd areas(triangles.rows());
  for (Eigen::Index f = 0; f < triangles.rows(); ++f) {
    const Eigen::Vector3d a = row(vertices, triangles(f, 0));
    const Eigen::Vector3d b = row(vertices, triangles(f, 1));
    const Eigen::Vector3d c = row(vertices, triangles(f, 2));
    areas[f] = 0.5 * (b - a).cross(c - a).norm();
  }
  return areas;
}

Vertices triangle_centroids(const Vertices& vertices, const Triangles& triangles) {
  check_triangle_indices(triangles, vertices.rows(), "triangle_centroids");
  Vertices c(triangles.rows(), 3);
  for (Eigen::Index f = 0; f < triangles.rows(); ++f)
    c.row(f) = (vertices.row(triangles(f, 0)) + vertices.row(triangles(f, 1)) +
                vertices.row(triangles(f, 2))) /
               3.0;
  return c;
}

std::vector<std::vector<int>> vertex_adjacency(const Triangles& triangles, int num_vertices) {
  std::vector<std::vector<int>> adj(static_cast<std::size_t>(std::max(0, num_vertices)));
  for (Eigen::Index f = 0; f < triangles.rows(); ++f)
    for (int k = 0; k < 3; ++k) {
      const int a = triangles(f, k), b = triangles(f, (k + 1) % 3);
      if (a == b) continue;
      if (a < 0 || b < 0 || a >= num_vertices || b >= num_vertices)
        throw std::invalid_argument("vertex_adjacency: triangle " + std::to_string(f) +
                                    " has a vertex index outside [0, " +
                                    std::to_string(num_vertices) + ")");
      adj[static_cast<std::size_t>(a)].push_back(b);
      adj[static_cast<std::size_t>(b)].push_back(a);
    }
  for (auto& list : adj) {
    std::sort(list.begin(), list.end());
    list.erase(std::unique(list.begin(), list.end()), list.end());
  }
  return adj;
}

double max_edge_length(const Mesh& mesh) {
  double l2 = 0.0;
  for (int f = 0; f < mesh.num_triangles(); ++f)
    for (int k = 0; k < 3; ++k)
      l2 = std::max(l2, (mesh.vertices.row(mesh.triangles(f, k)) -
                         mesh.vertices.row(mesh.triangles(f, (k + 1) % 3)))
                            .squaredNorm());
  return std::sqrt(l2);
}

void scale_about_centroid(Mesh& mesh, double factor) {
  if (!std::isfinite(factor) || factor <= 0.0)
    throw std::invalid_argument("scale_about_centroid: factor must be finite and positive, got " +
                                std::to_string(factor));
  if (mesh.num_vertices() == 0) return;
  Eigen::RowVector3d centroid = Eigen::RowVector3d::Zero();
  double total = 0.0;
  if (mesh.num_triangles() > 0) {
    const Eigen::VectorXd areas = triangle_areas(mesh.vertices, mesh.triangles);
    const Vertices centroids = triangle_centroids(mesh.vertices, mesh.triangles);
    total = areas.sum();
    if (total > 0.0) centroid = (areas.transpose() * centroids) / total;
  }
  if (!(total > 0.0)) centroid = mesh.vertices.colwise().mean();
  mesh.vertices = ((mesh.vertices.rowwise() - centroid) * factor).rowwise() + centroid;
}

Mesh refine_mesh(const Mesh& mesh, double max_edge_length, int max_vertices) {
  if (!std::isfinite(max_edge_length) || max_edge_length <= 0.0)
    throw std::invalid_argument("refine_mesh: max_edge_length must be finite and positive, got " +
                                std::to_string(max_edge_length));
  const double limit2 = max_edge_length * max_edge_length;
  const auto nf0 = static_cast<std::size_t>(mesh.num_triangles());

  // Working copies as flat arrays; converted back to Eigen at the end.
  std::vector<double> xyz(mesh.vertices.data(), mesh.vertices.data() + mesh.vertices.size());
  std::vector<int> tri(mesh.triangles.data(), mesh.triangles.data() + mesh.triangles.size());
  std::vector<int> part = mesh.triangle_part;
  std::vector<std::uint8_t> interior = mesh.interior;
  if (part.size() != nf0) part.assign(nf0, 0);
  if (interior.size() != nf0) interior.assign(nf0, 0);
  const auto nv_in = static_cast<std::size_t>(mesh.num_vertices());
  for (int i : tri)
    if (i < 0 || static_cast<std::size_t>(i) >= nv_in)
      throw std::invalid_argument("refine_mesh: vertex index " + std::to_string(i) +
                                  " out of range");

  auto length2 = [&](int a, int b) {
    const double dx = xyz[3 * a] - xyz[3 * b], dy = xyz[3 * a + 1] - xyz[3 * b + 1],
                 dz = xyz[3 * a + 2] - xyz[3 * b + 2];
    return dx * dx + dy * dy + dz * dz;
  };

  std::vector<std::uint64_t> marked;
  std::vector<int> new_tri;
  std::vector<int> new_part;
  std::vector<std::uint8_t> new_interior;
  for (int pass = 0;; ++pass) {
    // 1. Mark every edge longer than the limit (each once, by its sorted key).
    marked.clear();
    const std::size_t nf = tri.size() / 3;
    for (std::size_t f = 0; f < nf; ++f)
      for (int k = 0; k < 3; ++k) {
        const int a = tri[3 * f + k], b = tri[3 * f + (k + 1) % 3];
        if (length2(a, b) > limit2) marked.push_back(edge_key(a, b));
      }
    if (marked.empty()) break;
    if (pass > 200)
      throw std::runtime_error("refine_mesh: no convergence (non-finite coordinates?)");
    std::sort(marked.begin(), marked.end());
    marked.erase(std::unique(marked.begin(), marked.end()), marked.end());

    // 2. One midpoint per marked edge: vertex nv + position in `marked`.
    const int nv = static_cast<int>(xyz.size() / 3);
    if (max_vertices > 0 && static_cast<double>(nv) + static_cast<double>(marked.size()) >
                                static_cast<double>(max_vertices))
      throw std::length_error("refine_mesh: more than " + std::to_string(max_vertices) +
                              " vertices");
    xyz.resize(xyz.size() + marked.size() * 3);
    for (std::size_t e = 0; e < marked.size(); ++e) {
      const int a = key_first(marked[e]), b = key_second(marked[e]);
      for (int k = 0; k < 3; ++k) xyz[3 * (nv + e) + k] = 0.5 * (xyz[3 * a + k] + xyz[3 * b + k]);
    }
    auto midpoint = [&](int a, int b) {
      const std::uint64_t key = edge_key(a, b);
      const auto it = std::lower_bound(marked.begin(), marked.end(), key);
      return (it != marked.end() && *it == key) ? nv + static_cast<int>(it - marked.begin()) : -1;
    };

    // 3. Retriangulate each triangle by the pattern of its marked edges.
    new_tri.clear();
    new_part.clear();
    new_interior.clear();
    // At most four sub-triangles per triangle.
    new_tri.reserve(tri.size() * 4);
    new_part.reserve(nf * 4);
    new_interior.reserve(nf * 4);
    for (std::size_t f = 0; f < nf; ++f) {
      const int v[3] = {tri[3 * f], tri[3 * f + 1], tri[3 * f + 2]};
      int m[3];  // m[k]: midpoint of edge v[k] -> v[k+1], or -1
      int count = 0;
      for (int k = 0; k < 3; ++k) {
        m[k] = midpoint(v[k], v[(k + 1) % 3]);
        count += m[k] >= 0;
      }
      auto emit = [&](int a, int b, int c) {
        new_tri.insert(new_tri.end(), {a, b, c});
        new_part.push_back(part[f]);
        new_interior.push_back(interior[f]);
      };
      if (count == 0) {
        emit(v[0], v[1], v[2]);
      } else if (count == 1) {
        // Edge k split: two triangles through the opposite vertex.
        const int k = m[0] >= 0 ? 0 : m[1] >= 0 ? 1 : 2;
        const int a = v[k], b = v[(k + 1) % 3], c = v[(k + 2) % 3];
        emit(a, m[k], c);
        emit(m[k], b, c);
      } else if (count == 2) {
        // Edge k unsplit: corner triangle at the vertex between the split edges, and the
        // remaining quad cut along its shorter diagonal.
        const int k = m[0] < 0 ? 0 : m[1] < 0 ? 1 : 2;
        const int a = v[k], b = v[(k + 1) % 3], c = v[(k + 2) % 3];
        const int mbc = m[(k + 1) % 3], mca = m[(k + 2) % 3];
        emit(mbc, c, mca);
        // Quad a, b, mbc, mca (counter-clockwise).
        if (length2(a, mbc) <= length2(b, mca)) {
          emit(a, b, mbc);
          emit(a, mbc, mca);
        } else {
          emit(a, b, mca);
          emit(b, mbc, mca);
        }
      } else {
        emit(v[0], m[0], m[2]);
        emit(m[0], v[1], m[1]);
        emit(m[2], m[1], v[2]);
        emit(m[0], m[1], m[2]);
      }
    }
    tri.swap(new_tri);
    part.swap(new_part);
    interior.swap(new_interior);
  }

  Mesh out = detail::mesh_from_arrays(xyz, tri, std::move(part), std::move(interior));
  out.part_names = mesh.part_names;
  if (out.part_names.empty() && out.num_triangles() > 0) out.part_names.push_back("default");
  return out;
}

double enclosed_volume(const Vertices& vertices, const Triangles& triangles) {
  check_triangle_indices(triangles, vertices.rows(), "enclosed_volume");
  double v = 0.0;
  for (Eigen::Index f = 0; f < triangles.rows(); ++f)
    v += row(vertices, triangles(f, 0))
             .dot(row(vertices, triangles(f, 1)).cross(row(vertices, triangles(f, 2))));
  return v / 6.0;
}

namespace {

/// Unit area-weighted vertex normals (zero for a vertex in no triangle of positive area).
std::vector<Eigen::Vector3d> vertex_normals(const Vertices& x, const Triangles& t) {
  using Eigen::Vector3d;
  std::vector<Vector3d> normal(static_cast<size_t>(x.rows()), Vector3d::Zero());
  for (Eigen::Index f = 0; f < t.rows(); ++f) {
    const Vector3d n = (row(x, t(f, 1)) - row(x, t(f, 0))).cross(row(x, t(f, 2)) - row(x, t(f, 0)));
    for (int k = 0; k < 3; ++k) normal[static_cast<size_t>(t(f, k))] += n;
  }
  for (Vector3d& n : normal)
    if (n.norm() > 0.0) n.normalize();
  return normal;
}

/// opposite_layer_pairs() from the vertex normals, unsorted; with `first_only`, stops at the
/// first vertex that has a partner.
std::vector<std::pair<int, int>> facing_pairs(const Vertices& x,
                                              const std::vector<Eigen::Vector3d>& normal,
                                              double reach, bool first_only) {
  using Eigen::Vector3d;
  const int nv = static_cast<int>(x.rows());
  const detail::CellGrid cells{x.colwise().minCoeff().transpose(), reach};
  std::unordered_map<std::int64_t, std::vector<int>> grid;
  for (int i = 0; i < nv; ++i) grid[cells.key(cells.cell_of(row(x, i)))].push_back(i);

  std::vector<std::pair<int, int>> ties;
  for (int i = 0; i < nv; ++i) {
    const Vector3d p = row(x, i), n = normal[static_cast<size_t>(i)];
    if (!(n.norm() > 0.0)) continue;
    const Eigen::Vector3i c = cells.cell_of(p);
    int best = -1;
    double best_d = reach;
    for (int dz = -1; dz <= 1; ++dz)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const auto it = grid.find(cells.key(c + Eigen::Vector3i(dx, dy, dz)));
          if (it == grid.end()) continue;
          for (int j : it->second) {
            const Vector3d d = row(x, j) - p;
            const double dist = d.norm();
            // Behind i, facing the other way, mostly along -n (not a rim neighbour).
            if (j == i || dist > best_d || normal[static_cast<size_t>(j)].dot(n) > -0.7 ||
                -d.dot(n) < 0.7 * dist)
              continue;
            best = j;
            best_d = dist;
          }
        }
    if (best < 0) continue;
    ties.emplace_back(std::min(i, best), std::max(i, best));
    if (first_only) break;
  }
  return ties;
}

}  // namespace

std::vector<std::pair<int, int>> opposite_layer_pairs(const Vertices& x, const Triangles& t,
                                                      double reach) {
  if (!(reach > 0.0) || !std::isfinite(reach))
    throw std::invalid_argument("opposite_layer_pairs: reach must be positive and finite");
  check_triangle_indices(t, x.rows(), "opposite_layer_pairs");
  std::vector<std::pair<int, int>> ties = facing_pairs(x, vertex_normals(x, t), reach, false);
  std::sort(ties.begin(), ties.end());
  ties.erase(std::unique(ties.begin(), ties.end()), ties.end());
  return ties;
}

double default_layer_reach(const Vertices& x, const Triangles& t) {
  std::vector<std::uint64_t> keys;
  keys.reserve(static_cast<size_t>(3 * t.rows()));
  for (Eigen::Index f = 0; f < t.rows(); ++f)
    for (int k = 0; k < 3; ++k) keys.push_back(edge_key(t(f, k), t(f, (k + 1) % 3)));
  std::sort(keys.begin(), keys.end());
  // Closed: every undirected edge in exactly two triangles.
  bool closed = !keys.empty();
  for (size_t k = 0; closed && k < keys.size(); k += 2)
    closed = k + 1 < keys.size() && keys[k + 1] == keys[k] &&
             (k + 2 == keys.size() || keys[k + 2] != keys[k]);
  keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
  double total = 0.0;
  for (const std::uint64_t key : keys)
    total += (row(x, key_second(key)) - row(x, key_first(key))).norm();
  const double mean = keys.empty() ? 0.0 : total / static_cast<double>(keys.size());
  if (!(mean > 0.0) || !std::isfinite(mean)) return 0.0;
  const std::vector<Eigen::Vector3d> normal = vertex_normals(x, t);
  if (!closed || !facing_pairs(x, normal, mean, true).empty()) return mean;
  // Only a thin closed body can have its layers farther apart than a mean edge and within the
  // bound: its mean thickness, twice its enclosed volume over its area, is within the bound.
  const double cap = thin_layer_fraction * (x.colwise().maxCoeff() - x.colwise().minCoeff()).norm();
  double area = 0.0;
  for (Eigen::Index f = 0; f < t.rows(); ++f)
    area +=
        0.5 * (row(x, t(f, 1)) - row(x, t(f, 0))).cross(row(x, t(f, 2)) - row(x, t(f, 0))).norm();
  if (!(2.0 * std::abs(enclosed_volume(x, t)) <= cap * area)) return mean;
  for (double reach = std::min(2.0 * mean, cap); reach > mean; reach = std::min(2.0 * reach, cap)) {
    if (!facing_pairs(x, normal, reach, true).empty()) return reach;
    if (!(reach < cap)) break;
  }
  return mean;
}

}  // namespace pbve
