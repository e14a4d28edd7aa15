#pragma once
// Internal: a Mesh from flat coordinate and index arrays (mesh builders of src/core).

#include <cstdint>
#include <vector>

#include "pbve/core/mesh.hpp"

namespace pbve::detail {

/// xyz: 3 numbers per vertex; tri: 3 indices per triangle; per-triangle parts and interior
/// flags. part_names is left empty.
inline Mesh mesh_from_arrays(const std::vector<double>& xyz, const std::vector<int>& tri,
                             std::vector<int> part, std::vector<std::uint8_t> interior) {
  Mesh out;
  out.vertices =
      Eigen::Map<const Vertices>(xyz.data(), static_cast<Eigen::Index>(xyz.size() / 3), 3);
  out.triangles =
      Eigen::Map<const Triangles>(tri.data(), static_cast<Eigen::Index>(tri.size() / 3), 3);
  out.triangle_part = std::move(part);
  out.interior = std::move(interior);
  return out;
}

}  // namespace pbve::detail
