#pragma once
// A thin closed cloth (a board made into cloth: two layers joined at a rim) as one sheet. The
// triangles of one layer are the simulated sheet; every other vertex (the other layer, the
// rim) is attached to the closest point of the sheet at rest and follows it at its rest offset,
// expressed in a frame that turns with the sheet. Used by the engines that simulate thin boards
// as cloth (pbve::bullet, pbve::mass_spring).

#include <optional>
#include <vector>

#include <Eigen/Core>

#include "pbve/core/mesh.hpp"

namespace pbve {

/// Where a vertex that is not a sheet node sits relative to the sheet.
struct SheetAttachment {
  int triangle = -1;                                ///< row of ThinSheet::triangles
  Eigen::Vector3d bary = Eigen::Vector3d::Zero();   ///< closest sheet point at rest
  Eigen::Vector3d local = Eigen::Vector3d::Zero();  ///< rest offset in (t1, t2, normal), m
};

struct ThinSheet {
  std::vector<int> node_vertex;  ///< per sheet node: its vertex, ascending
  std::vector<int> vertex_node;  ///< per vertex: its sheet node, -1 when it is attached
  Triangles triangles;           ///< sheet triangles, sheet node indices (mesh orientation)
  /// Per vertex; meaningful where vertex_node is -1.
  std::vector<SheetAttachment> attachment;
  double max_offset = 0.0;  ///< largest distance of an attached vertex from the sheet at rest, m
  /// Per sheet node: the sheet triangles around it.
  std::vector<std::vector<int>> node_triangles;
};

/// The sheet of a thin closed surface, or nothing when the surface does not split into one
/// layer and the rest: the layer is the smooth region (neighbouring triangles within 60
/// degrees) grown from the first vertex of opposite_layer_pairs(rest, triangles, reach) that
/// lies inside a flat region; it must hold exactly one vertex of every such pair, and every
/// other vertex must lie within 2 * reach of it.
std::optional<ThinSheet> make_thin_sheet(const Vertices& rest, const Triangles& triangles,
                                         double reach);

/// Unit area-weighted normals of the sheet at its nodes (#nodes by 3) from node positions.
Vertices sheet_normals(const ThinSheet& sheet, const Vertices& nodes);

/// Position of an attached vertex, from the node positions and sheet_normals() of them.
Eigen::Vector3d attached_position(const ThinSheet& sheet, const SheetAttachment& a,
                                  const Vertices& nodes, const Vertices& normals);

/// The sheet nodes attached_position() of `a` depends on, sorted (into `involved`): those of
/// the triangles around its triangle's nodes.
void attached_position_support(const ThinSheet& sheet, const SheetAttachment& a,
                               std::vector<int>& involved);

/// attached_position() and its Jacobian with respect to the sheet nodes it depends on
/// (attached_position_support()): `involved` receives their indices (sorted),
/// `jacobian` the 3 x (3 * involved.size()) matrix d position / d node positions (node-major,
/// x y z per node).
Eigen::Vector3d attached_position_jacobian(const ThinSheet& sheet, const SheetAttachment& a,
                                           const Vertices& nodes, std::vector<int>& involved,
                                           Eigen::Matrix<double, 3, Eigen::Dynamic>& jacobian);

}  // namespace pbve
