// The sheet of a thin closed surface (pbve/core/thin_sheet.hpp): the split of a board into a
// simulated layer and attached vertices, and the exact Jacobian of an attached vertex's position.

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

#include <gtest/gtest.h>

#include "pbve/core/thin_sheet.hpp"
#include "pbve/edit/synth.hpp"
#include "support/test_util.hpp"

namespace pbve {
namespace {

Vertices node_positions(const ThinSheet& s, const Vertices& x) {
  Vertices n(static_cast<Eigen::Index>(s.node_vertex.size()), 3);
  for (size_t i = 0; i < s.node_vertex.size(); ++i)
    n.row(static_cast<Eigen::Index>(i)) = x.row(s.node_vertex[i]);
  return n;
}

TEST(ThinSheet, ABoardSplitsIntoOneLayerAndAttachedVertices) {
  const Mesh board = refine_mesh(make_box_mesh(0.40, 0.30, 0.01), 0.05);
  const auto sheet = make_thin_sheet(board.vertices, board.triangles, 0.05);
  ASSERT_TRUE(sheet.has_value());
  int attached = 0;
  for (size_t v = 0; v < sheet->vertex_node.size(); ++v) attached += sheet->vertex_node[v] < 0;
  EXPECT_GT(attached, static_cast<int>(sheet->node_vertex.size()) / 2);  // the other layer, rim
  EXPECT_NEAR(sheet->max_offset, 0.01, 1e-9);                            // the thickness
  // At rest every attached vertex sits where it is.
  const Vertices nodes = node_positions(*sheet, board.vertices);
  const Vertices normals = sheet_normals(*sheet, nodes);
  for (size_t v = 0; v < sheet->vertex_node.size(); ++v) {
    if (sheet->vertex_node[v] >= 0) continue;
    EXPECT_LT((attached_position(*sheet, sheet->attachment[v], nodes, normals) -
               board.vertices.row(static_cast<Eigen::Index>(v)).transpose())
                  .norm(),
              1e-12);
  }
}

// Distance from p to triangle (a, b, c): to its plane where p projects inside it, else to the
// nearest of its edges.
double triangle_distance(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                         const Eigen::Vector3d& b, const Eigen::Vector3d& c) {
  const Eigen::Vector3d n = (b - a).cross(c - a).normalized();
  const Eigen::Vector3d q = p - (p - a).dot(n) * n;
  const bool inside = (b - a).cross(q - a).dot(n) >= 0.0 && (c - b).cross(q - b).dot(n) >= 0.0 &&
                      (a - c).cross(q - c).dot(n) >= 0.0;
  if (inside) return std::abs((p - a).dot(n));
  auto segment = [&](const Eigen::Vector3d& u, const Eigen::Vector3d& w) {
    const double s = std::clamp((p - u).dot(w - u) / (w - u).squaredNorm(), 0.0, 1.0);
    return (p - (u + s * (w - u))).norm();
  };
  return std::min({segment(a, b), segment(b, c), segment(c, a)});
}

// Every attached vertex hangs from the closest point of the whole sheet (the attachment search
// looks only near the vertex), on a board meshed finer than its thickness and bent into a half
// cylinder.
TEST(ThinSheet, AttachmentsAreTheClosestSheetPoints) {
  Mesh board = refine_mesh(make_box_mesh(0.40, 0.30, 0.01), 0.012);
  board.vertices = test::bent_about_y(board.vertices, 0.4 / 3.14159265358979);
  const auto sheet = make_thin_sheet(board.vertices, board.triangles, 0.015);
  ASSERT_TRUE(sheet.has_value());
  const Vertices nodes = node_positions(*sheet, board.vertices);
  auto node = [&](Eigen::Index t, int k) -> Eigen::Vector3d {
    return nodes.row(sheet->triangles(t, k)).transpose();
  };
  int checked = 0;
  for (size_t v = 0; v < sheet->vertex_node.size(); ++v) {
    if (sheet->vertex_node[v] >= 0) continue;
    const SheetAttachment& a = sheet->attachment[v];
    const Eigen::Vector3d x = board.vertices.row(static_cast<Eigen::Index>(v)).transpose();
    const Eigen::Vector3d at = a.bary[0] * node(a.triangle, 0) + a.bary[1] * node(a.triangle, 1) +
                               a.bary[2] * node(a.triangle, 2);
    double closest = std::numeric_limits<double>::infinity();
    for (Eigen::Index t = 0; t < sheet->triangles.rows(); ++t)
      closest = std::min(closest, triangle_distance(x, node(t, 0), node(t, 1), node(t, 2)));
    EXPECT_NEAR((x - at).norm(), closest, 1e-12) << "vertex " << v;
    ++checked;
  }
  EXPECT_GT(checked, static_cast<int>(sheet->node_vertex.size()));
}

TEST(ThinSheet, AttachedPositionJacobianMatchesCentralDifferences) {
  const Mesh board = refine_mesh(make_box_mesh(0.40, 0.30, 0.01), 0.05);
  const auto sheet = make_thin_sheet(board.vertices, board.triangles, 0.05);
  ASSERT_TRUE(sheet.has_value());
  // A bent and stretched sheet.
  std::mt19937 rng(3);
  std::normal_distribution<double> g(0.0, 0.01);
  Vertices nodes = node_positions(*sheet, board.vertices);
  for (Eigen::Index i = 0; i < nodes.rows(); ++i)
    nodes.row(i) += Eigen::RowVector3d(g(rng), g(rng), g(rng) + 0.5 * nodes(i, 0) * nodes(i, 0));
  int checked = 0;
  for (size_t v = 0; v < sheet->vertex_node.size(); v += 7) {
    if (sheet->vertex_node[v] >= 0) continue;
    const SheetAttachment& a = sheet->attachment[v];
    std::vector<int> involved;
    Eigen::Matrix<double, 3, Eigen::Dynamic> jac;
    const Eigen::Vector3d p = attached_position_jacobian(*sheet, a, nodes, involved, jac);
    EXPECT_LT((p - attached_position(*sheet, a, nodes, sheet_normals(*sheet, nodes))).norm(),
              1e-14);
    ASSERT_EQ(jac.cols(), 3 * static_cast<Eigen::Index>(involved.size()));
    const double h = 1e-6;
    for (size_t i = 0; i < involved.size(); ++i)
      for (int d = 0; d < 3; ++d) {
        Vertices hi = nodes, lo = nodes;
        hi(involved[i], d) += h;
        lo(involved[i], d) -= h;
        const Eigen::Vector3d fd = (attached_position(*sheet, a, hi, sheet_normals(*sheet, hi)) -
                                    attached_position(*sheet, a, lo, sheet_normals(*sheet, lo))) /
                                   (2 * h);
        // Truncation O(h^2 / L^2) relative for L ~ 5 cm edges, round-off ~1e-16 / h.
        EXPECT_LT((fd - jac.col(3 * static_cast<Eigen::Index>(i) + d)).norm(), 1e-7)
            << "vertex " << v << " node " << involved[i] << " axis " << d;
      }
    ++checked;
  }
  EXPECT_GT(checked, 5);
}

}  // namespace
}  // namespace pbve
