#pragma once
// Internal: the cells of a uniform grid and their hash keys, for sparse spatial hashing
// (std::unordered_map from key to the items in a cell) in the mesh routines of src/core.

#include <cstdint>

#include <Eigen/Core>

namespace pbve::detail {

struct CellGrid {
  Eigen::Vector3d origin;  ///< corner of cell (0, 0, 0)
  double size = 1.0;       ///< cell side, > 0

  Eigen::Vector3i cell_of(const Eigen::Vector3d& p) const {
    return Eigen::Vector3i(((p - origin) / size).array().floor().cast<int>());
  }
  static std::int64_t key(const Eigen::Vector3i& c) {
    return (static_cast<std::int64_t>(c[0]) * 73856093) ^
           (static_cast<std::int64_t>(c[1]) * 19349663) ^
           (static_cast<std::int64_t>(c[2]) * 83492791);
  }
};

}  // namespace pbve::detail
