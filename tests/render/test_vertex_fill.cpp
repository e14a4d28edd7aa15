// Fail-safe colour propagation over the vertex graph.

#include "pbve/render/vertex_fill.hpp"

#include <gtest/gtest.h>

#include "pbve/core/error.hpp"

namespace pbve {
namespace {

/// A strip of n - 1 quads (two triangles each) with vertices 2i (top) and 2i + 1 (bottom).
Triangles strip(int n) {
  Triangles t(2 * (n - 1), 3);
  for (int i = 0; i + 1 < n; ++i) {
    t.row(2 * i) << 2 * i, 2 * i + 1, 2 * i + 3;
    t.row(2 * i + 1) << 2 * i, 2 * i + 3, 2 * i + 2;
  }
  return t;
}

TEST(VertexGraph, NeighboursAreTheEdgeNeighbours) {
  Triangles t(2, 3);
  t << 0, 1, 2, 0, 2, 3;
  const VertexGraph g = VertexGraph::from_triangles(t, 5);
  ASSERT_EQ(g.num_vertices(), 5);
  const std::vector<int> n0(g.neighbours.begin() + g.offsets[0],
                            g.neighbours.begin() + g.offsets[1]);
  EXPECT_EQ(n0, (std::vector<int>{1, 2, 3}));
  EXPECT_EQ(g.offsets[5] - g.offsets[4], 0);  // isolated vertex
  Triangles bad(1, 3);
  bad << 0, 1, 7;
  EXPECT_THROW(VertexGraph::from_triangles(bad, 3), InputError);
}

/// A path graph 0 - 1 - ... - (n - 1), made of degenerate triangles (i, i + 1, i + 1).
Triangles path(int n) {
  Triangles t(n - 1, 3);
  for (int i = 0; i + 1 < n; ++i) t.row(i) << i, i + 1, i + 1;
  return t;
}

// Known colours at both ends of a path: the fill converges to the harmonic interpolant, which
// on a path is linear; known colours never change.
TEST(VertexFill, InterpolatesLinearlyAlongAPath) {
  const int n = 11;
  const VertexGraph g = VertexGraph::from_triangles(path(n), n);
  std::vector<cv::Vec3f> colors(n, cv::Vec3f(0, 0, 0));
  std::vector<std::uint8_t> known(n, 0);
  colors[0] = cv::Vec3f(0, 100, 200);
  colors[n - 1] = cv::Vec3f(100, 100, 0);
  known[0] = known[n - 1] = 1;
  EXPECT_EQ(fill_vertex_colors(g, colors, known, 2000, cv::Vec3f(1, 2, 3)), n - 2);
  for (int i = 0; i < n; ++i) {
    const float s = static_cast<float>(i) / (n - 1);
    // Gauss-Seidel on 9 unknowns contracts the error by about cos(pi / 10)^2 ~ 0.9 per sweep;
    // after 2000 sweeps only float round-off (~1e-5 of 200) remains.
    EXPECT_NEAR(colors[i][0], 100 * s, 0.01) << i;
    EXPECT_NEAR(colors[i][1], 100, 0.01) << i;
    EXPECT_NEAR(colors[i][2], 200 * (1 - s), 0.01) << i;
  }
}

// On a triangulated strip the fill is a weighted mean of the boundary colours at every vertex
// (maximum principle): every filled value lies within the range of the known ones.
TEST(VertexFill, StaysWithinTheKnownRange) {
  const int n = 11;
  const VertexGraph g = VertexGraph::from_triangles(strip(n), 2 * n);
  std::vector<cv::Vec3f> colors(2 * n, cv::Vec3f(0, 0, 0));
  std::vector<std::uint8_t> known(2 * n, 0);
  for (int v : {0, 1}) colors[v] = cv::Vec3f(0, 100, 200), known[v] = 1;
  for (int v : {2 * n - 2, 2 * n - 1}) colors[v] = cv::Vec3f(100, 100, 0), known[v] = 1;
  for (int sweeps : {0, 3, 50}) {
    std::vector<cv::Vec3f> c = colors;
    EXPECT_EQ(fill_vertex_colors(g, c, known, sweeps, cv::Vec3f(1, 2, 3)), 2 * n - 4);
    for (int v = 0; v < 2 * n; ++v) {
      EXPECT_GE(c[v][0], 0.0f);
      EXPECT_LE(c[v][0], 100.0f);
      EXPECT_FLOAT_EQ(c[v][1], 100.0f);
      EXPECT_GE(c[v][2], 0.0f);
      EXPECT_LE(c[v][2], 200.0f);
    }
    EXPECT_EQ(c[0], colors[0]);
    EXPECT_EQ(c[2 * n - 1], colors[2 * n - 1]);
  }
}

TEST(VertexFill, FrontPropagationWithoutSmoothingAndUnreachableVertices) {
  const int n = 4;
  Triangles t = strip(n);
  const VertexGraph g = VertexGraph::from_triangles(t, 2 * n + 1);  // vertex 8 is isolated
  std::vector<cv::Vec3f> colors(2 * n + 1, cv::Vec3f(-1, -1, -1));
  std::vector<std::uint8_t> known(2 * n + 1, 0);
  colors[0] = cv::Vec3f(10, 20, 30);
  known[0] = 1;
  const int filled = fill_vertex_colors(g, colors, known, 0, cv::Vec3f(7, 7, 7));
  EXPECT_EQ(filled, 2 * n);
  // One known colour: the front carries it everywhere reachable.
  for (int v = 0; v < 2 * n; ++v) EXPECT_EQ(colors[v], cv::Vec3f(10, 20, 30)) << v;
  EXPECT_EQ(colors[2 * n], cv::Vec3f(7, 7, 7));
  std::vector<std::uint8_t> wrong(3, 0);
  EXPECT_THROW(fill_vertex_colors(g, colors, wrong, 0, {}), InputError);
}

}  // namespace
}  // namespace pbve
