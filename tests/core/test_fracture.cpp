// Voronoi fracture: the pieces partition the convex input exactly (volumes add up, the original
// surface is covered once), each piece is closed and outward-facing, cut faces are interior.

#include "pbve/core/fracture.hpp"

#include <cmath>
#include <map>
#include <utility>

#include <gtest/gtest.h>

#include "pbve/core/error.hpp"
#include "pbve/edit/synth.hpp"

namespace pbve {
namespace {

// Volume enclosed by the triangles of one piece.
double signed_volume(const Mesh& m, int piece) {
  std::vector<int> rows;
  for (int f = 0; f < m.num_triangles(); ++f)
    if (m.triangle_part[static_cast<size_t>(f)] == piece) rows.push_back(f);
  return enclosed_volume(m.vertices, m.triangles(rows, Eigen::all));
}

TEST(Fracture, BoxPiecesPartitionTheVolumeAndTheSurface) {
  const Mesh box = make_box_mesh(0.2, 0.4, 0.1);  // volume 0.008 m^3, area 0.28 m^2
  FractureOptions o;
  o.pieces = 8;
  o.seed = 7;
  const Mesh m = voronoi_fracture(box, o);
  ASSERT_EQ(static_cast<int>(m.part_names.size()), 8);
  ASSERT_EQ(static_cast<int>(m.triangle_part.size()), m.num_triangles());
  ASSERT_EQ(static_cast<int>(m.interior.size()), m.num_triangles());

  double volume = 0.0;
  for (int p = 0; p < 8; ++p) {
    const double v = signed_volume(m, p);
    EXPECT_GT(v, 0.0) << "piece " << p;  // outward-facing and not empty
    volume += v;
  }
  // Exact partition up to rounding (cut points are computed in double precision).
  EXPECT_NEAR(volume, 0.2 * 0.4 * 0.1, 1e-12);

  const Eigen::VectorXd area = triangle_areas(m.vertices, m.triangles);
  double outside = 0.0, cut = 0.0;
  std::vector<int> cut_faces(8, 0);
  for (int f = 0; f < m.num_triangles(); ++f) {
    if (m.interior[static_cast<size_t>(f)]) {
      cut += area(f);
      ++cut_faces[static_cast<size_t>(m.triangle_part[static_cast<size_t>(f)])];
    } else {
      outside += area(f);
    }
  }
  EXPECT_NEAR(outside, 2 * (0.2 * 0.4 + 0.2 * 0.1 + 0.4 * 0.1), 1e-12);
  EXPECT_GT(cut, 0.0);
  for (int p = 0; p < 8; ++p) EXPECT_GT(cut_faces[static_cast<size_t>(p)], 0) << "piece " << p;

  // Every piece is closed: each of its edges is used once in each direction.
  std::map<std::pair<int, int>, int> directed;
  for (int f = 0; f < m.num_triangles(); ++f)
    for (int k = 0; k < 3; ++k) ++directed[{m.triangles(f, k), m.triangles(f, (k + 1) % 3)}];
  for (const auto& [edge, count] : directed) {
    EXPECT_EQ(count, 1) << edge.first << "-" << edge.second;
    EXPECT_EQ(directed.count({edge.second, edge.first}), 1u) << edge.first << "-" << edge.second;
  }
  // Pieces share no vertex (each is a separate body for the engines).
  std::vector<int> owner(static_cast<size_t>(m.num_vertices()), -1);
  for (int f = 0; f < m.num_triangles(); ++f)
    for (int k = 0; k < 3; ++k) {
      int& o = owner[static_cast<size_t>(m.triangles(f, k))];
      const int p = m.triangle_part[static_cast<size_t>(f)];
      EXPECT_TRUE(o < 0 || o == p);
      o = p;
    }
}

TEST(Fracture, SameSeedSamePiecesOtherSeedOtherPieces) {
  const Mesh ball = make_icosphere(0.1, 2);
  FractureOptions o;
  o.pieces = 5;
  const Mesh a = voronoi_fracture(ball, o), b = voronoi_fracture(ball, o);
  EXPECT_EQ(a.vertices, b.vertices);
  EXPECT_EQ(a.triangles, b.triangles);
  o.seed = 2;
  const Mesh c = voronoi_fracture(ball, o);
  EXPECT_FALSE(a.vertices.rows() == c.vertices.rows() && a.vertices == c.vertices);
  double volume = 0.0;
  for (int p = 0; p < 5; ++p) volume += signed_volume(c, p);
  // The pieces fill the icosphere (a polyhedron), not the ball.
  EXPECT_NEAR(volume, enclosed_volume(ball.vertices, ball.triangles), 1e-12);
}

TEST(Fracture, RejectsConcaveOpenAndBadCounts) {
  FractureOptions o;
  o.pieces = 1;
  EXPECT_THROW(voronoi_fracture(make_box_mesh(1, 1, 1), o), InputError);
  o.pieces = 4;
  // Concave: a box with one vertex pushed inside.
  Mesh dented = make_box_mesh(1, 1, 1);
  dented.vertices.row(7) *= 0.2;
  EXPECT_THROW(voronoi_fracture(dented, o), InputError);
  // Inside-out (clockwise faces).
  Mesh flipped = make_box_mesh(1, 1, 1);
  flipped.triangles.col(1).swap(flipped.triangles.col(2));
  EXPECT_THROW(voronoi_fracture(flipped, o), InputError);
}

}  // namespace
}  // namespace pbve
