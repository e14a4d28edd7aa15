#pragma once
/// @file
/// Voronoi fracture of a convex mesh into separate closed pieces (the paper's shattering
/// statue, section 4.3).

#include <cstdint>

#include "pbve/core/mesh.hpp"

namespace pbve {

/// Options of voronoi_fracture().
struct FractureOptions {
  int pieces = 8;          ///< number of Voronoi seeds (>= 2); a seed's cell is one piece
  std::uint64_t seed = 1;  ///< random seed of the seed points (same seed, same pieces)
};

/// Cuts a closed convex mesh into the Voronoi cells of `options.pieces` random points drawn
/// uniformly inside it. Each cell is a separate closed piece with its own vertices, so engines
/// that make one body per connected piece get one body per cell. The result's parts are
/// "piece_0", "piece_1", ... (triangle_part); faces on the original surface keep the input's
/// interior flag and faces created by the cuts are flagged interior (not textured from the
/// footage, drawn in a uniform colour). Triangles stay counter-clockwise seen from outside.
/// The pieces' volumes add up to the input's and the surface faces cover the input's surface.
/// Throws InputError when the mesh is not closed and convex or options are out of range.
Mesh voronoi_fracture(const Mesh& convex, const FractureOptions& options);

}  // namespace pbve
