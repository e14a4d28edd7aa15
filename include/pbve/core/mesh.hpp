#pragma once
/// @file
/// Triangle meshes: loading (OBJ, PLY), validation, refinement and per-triangle geometry.

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <Eigen/Core>

namespace pbve {

/// #V by 3 vertex positions (one vertex per row), double precision.
using Vertices = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;
/// #F by 3 vertex indices (one triangle per row, counter-clockwise seen from outside).
using Triangles = Eigen::Matrix<int, Eigen::Dynamic, 3, Eigen::RowMajor>;

/// A triangle mesh with parts (OBJ groups/objects, e.g. fracture pieces) and per-triangle flags.
struct Mesh {
  Vertices vertices;               ///< #V by 3, mesh units
  Triangles triangles;             ///< #F by 3
  std::vector<int> triangle_part;  ///< #F, index into part_names (0 when the file has no parts)
  std::vector<std::string> part_names;  ///< at least one entry ("default") when non-empty
  std::vector<std::uint8_t> interior;   ///< #F, 1 = interior face (not textured from the footage)

  int num_vertices() const { return static_cast<int>(vertices.rows()); }
  int num_triangles() const { return static_cast<int>(triangles.rows()); }
  int num_parts() const { return static_cast<int>(part_names.size()); }
};

/// Loads an OBJ or PLY mesh (chosen by extension, case-insensitive). Polygons are
/// triangulated as fans. Throws InputError naming the file and line (OBJ, ASCII PLY) or
/// element (binary PLY) at fault; throws InputError for an empty mesh, indices out of
/// range and non-finite coordinates.
///
/// OBJ: `v`, `f` (with `v/vt/vn` forms and negative indices), `g`/`o` start a part; a
/// part whose name starts with "interior" (or a `usemtl interior*` material) has its
/// faces flagged interior. PLY: ascii and binary_little_endian 1.0, `vertex` with
/// x y z, `face` with a list of indices; an optional face property `interior` (uchar)
/// and `part` (int).
Mesh load_mesh(const std::filesystem::path& path);
Mesh load_obj(const std::filesystem::path& path);
Mesh load_ply(const std::filesystem::path& path);

/// The readers of load_obj() and load_ply() on a file's content held in memory (load_obj and
/// load_ply map the file and call these). `name` is the file named in error messages; the
/// data is not copied and need not be null-terminated.
Mesh parse_obj(std::string_view text, const std::filesystem::path& name = {});
Mesh parse_ply(std::string_view data, const std::filesystem::path& name = {});

/// Writes OBJ (one `g` per part, interior parts keep their names) — via a temporary file renamed on
/// success.
void save_obj(const Mesh& mesh, const std::filesystem::path& path);
/// Writes binary little-endian PLY with `part` and `interior` face properties.
void save_ply(const Mesh& mesh, const std::filesystem::path& path);

/// Findings of validate_mesh() that are reported, not fatal.
struct MeshReport {
  int degenerate_count = 0;           ///< triangles with (near) zero area or repeated vertices
  std::vector<int> degenerate_first;  ///< first few degenerate triangle ids (at most 8)
  int non_manifold_edge_count = 0;    ///< edges shared by more than two triangles
  std::vector<std::pair<int, int>> non_manifold_first;  ///< first few such edges (vertex ids)
  int boundary_edge_count = 0;                          ///< edges used by exactly one triangle
  bool ok() const { return degenerate_count == 0 && non_manifold_edge_count == 0; }
  /// Human-readable one-paragraph summary, empty when ok().
  std::string summary() const;
};

/// Checks a mesh. Throws InputError (with `source` as the file, and the element, e.g.
/// "triangle 12", as the key) for fatal problems: empty mesh, index out of range,
/// non-finite coordinate, inconsistent per-triangle arrays. Returns the non-fatal findings.
MeshReport validate_mesh(const Mesh& mesh, const std::filesystem::path& source = {});

/// Scales vertices uniformly about the area-weighted centroid of the surface (factor 1.01 =
/// the paper's 1% enlargement).
void scale_about_centroid(Mesh& mesh, double factor);

/// Splits edges until no edge is longer than `max_edge_length` (mesh units). Original
/// vertices keep their indices (new vertices are appended), parts and interior flags are
/// inherited by the sub-triangles, and shared edges are split consistently (no T-junctions).
/// With `max_vertices` > 0, throws std::length_error as soon as the result would have more
/// vertices than that (before allocating them).
Mesh refine_mesh(const Mesh& mesh, double max_edge_length, int max_vertices = 0);

/// Throws std::invalid_argument, naming `who` and the first such triangle, when a triangle has
/// a vertex index outside [0, num_vertices). The functions below that take vertices and
/// triangles check it (a min/max pass over the indices) before reading any vertex.
void check_triangle_indices(const Triangles& triangles, Eigen::Index num_vertices, const char* who);

/// An edge used by one triangle only (it borders a hole), as its two vertex ids (smaller
/// first, the smallest such edge), or nullopt when every edge is shared: the surface is closed
/// (up to non-manifold edges, which validate_mesh() reports).
std::optional<std::pair<int, int>> first_boundary_edge(const Triangles& triangles);

/// Per-triangle unnormalized normals (b - a) x (c - a), #F by 3.
Vertices triangle_normals(const Vertices& vertices, const Triangles& triangles);
/// Per-triangle areas, #F.
Eigen::VectorXd triangle_areas(const Vertices& vertices, const Triangles& triangles);
/// Per-triangle centroids, #F by 3.
Vertices triangle_centroids(const Vertices& vertices, const Triangles& triangles);
/// For each vertex, the sorted list of vertices sharing an edge with it.
std::vector<std::vector<int>> vertex_adjacency(const Triangles& triangles, int num_vertices);
/// Signed volume enclosed by a closed surface: positive when its triangles are counter-clockwise
/// seen from outside (the divergence theorem; meaningless for an open surface).
double enclosed_volume(const Vertices& vertices, const Triangles& triangles);
/// Longest edge length of the mesh.
double max_edge_length(const Mesh& mesh);

/// Pairs of vertices facing each other across a thin closed surface (a board, a thick sheet):
/// each vertex is paired with the nearest vertex at most `reach` away that lies behind it
/// (mostly along minus its normal) and whose area-weighted normal points the other way.
/// Vertices on the rim, where the two layers meet, find no partner. Each pair appears once
/// with first < second, sorted. Engines tie such pairs so that the two layers of a board made
/// into cloth do not pass through each other.
std::vector<std::pair<int, int>> opposite_layer_pairs(const Vertices& vertices,
                                                      const Triangles& triangles, double reach);

/// The engines' default reach of opposite_layer_pairs() (layer_distance 0): the mean edge
/// length; for a thin closed body (every edge in two triangles, and its mean thickness, twice
/// its enclosed volume over its area, at most `thin_layer_fraction` of its bounding box's
/// diagonal) with no facing pair within a mean edge, the mean edge doubled until some pair lies
/// within it, up to that bound. So a board's two layers are found however finely it is meshed
/// (a board 1 cm thick has no facing pair within a mean edge of 7 mm), flat or bent. Elsewhere
/// (an open surface, a thick body) it is the mean edge length; 0 for a mesh without edges of
/// positive length. Costs about one opposite_layer_pairs() per reach it tries: none for an open
/// surface, one for a closed body whose layers lie within a mean edge or which is not thin.
double default_layer_reach(const Vertices& vertices, const Triangles& triangles);
/// The largest mean thickness of a thin closed body, as a fraction of its bounding box's
/// diagonal, that default_layer_reach() reaches (a board 0.4 x 0.3 m by 1 cm is 2%).
inline constexpr double thin_layer_fraction = 0.05;

}  // namespace pbve
