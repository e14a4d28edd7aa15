// Energy terms of the control optimizer: analytic gradients against central differences,
// barrier smoothness and sign conventions.

#include <cmath>
#include <random>

#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include "pbve/control/energy.hpp"
#include "pbve/testing/shapes.hpp"

namespace pbve {
namespace {

Vertices random_vertices(int n, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-0.2, 0.2);
  Vertices x(n, 3);
  for (int i = 0; i < n; ++i) x.row(i) << u(rng), u(rng), 1.0 + u(rng);
  return x;
}

TEST(ControlEnergy, FacingValueSignAndRange) {
  // Counter-clockwise seen from the camera (origin, looking along +z, y down) faces it.
  const Eigen::Vector3d a(0, 0, 1), b(0, 0.1, 1), c(0.1, 0, 1);
  // n = (b - a) x (c - a) = (0, 0.1, 0) x (0.1, 0, 0) = (0, 0, -0.01): towards the camera.
  const double s = facing_value(a, b, c, nullptr);
  EXPECT_LT(s, -0.99);
  EXPECT_GT(facing_value(a, c, b, nullptr), 0.99);
  EXPECT_EQ(facing_value(a, a, c, nullptr), 0.0);  // degenerate
}

TEST(ControlEnergy, FacingValueGradientMatchesCentralDifferences) {
  const Vertices x = random_vertices(3, 7);
  Eigen::Matrix3d g;
  const Eigen::Vector3d a = x.row(0).transpose(), b = x.row(1).transpose(),
                        c = x.row(2).transpose();
  facing_value(a, b, c, &g);
  const double h = 1e-6;
  for (int v = 0; v < 3; ++v)
    for (int d = 0; d < 3; ++d) {
      Eigen::Vector3d p[3] = {a, b, c}, m[3] = {a, b, c};
      p[v][d] += h;
      m[v][d] -= h;
      const double fd =
          (facing_value(p[0], p[1], p[2], nullptr) - facing_value(m[0], m[1], m[2], nullptr)) /
          (2 * h);
      // Truncation O(h^2 s''') with |s'''| ~ 1/L^3 ~ 1e3 (L ~ 0.1 m) plus round-off 1e-16/h.
      EXPECT_NEAR(g(v, d), fd, 1e-6 * (1.0 + std::abs(fd))) << "vertex " << v << " axis " << d;
    }
}

TEST(ControlEnergy, BarrierIsC1AndZeroBeyondTheMargin) {
  VisibilityBarrier b;
  double d = 1.0;
  EXPECT_EQ(visibility_barrier(1.0, b, &d), 0.0);
  EXPECT_EQ(d, 0.0);
  EXPECT_EQ(visibility_barrier(3.0, b, &d), 0.0);
  // Continuous value and slope at the clamp point and at 1.
  for (double at : {b.clamp, 1.0}) {
    double dl, dr;
    const double fl = visibility_barrier(at - 1e-9, b, &dl);
    const double fr = visibility_barrier(at + 1e-9, b, &dr);
    EXPECT_NEAR(fl, fr, 1e-7);
    EXPECT_NEAR(dl, dr, 1e-6 * (1.0 + std::abs(dl)));
  }
  // Decreasing in sigma: a triangle turning towards the camera costs more.
  double prev = 0.0;
  for (double s = 0.99; s > -5.0; s -= 0.01) {
    const double f = visibility_barrier(s, b, &d);
    EXPECT_GT(f, prev);
    EXPECT_LT(d, 0.0);
    prev = f;
  }
}

TEST(ControlEnergy, IndicesOutsideTheMeshAreErrorsNotReads) {
  const Vertices x = random_vertices(4, 7);
  Triangles t(2, 3);
  t << 0, 1, 2, 1, 3, 50;
  const std::vector<std::uint8_t> pen(2, 1), obs(2, 0);
  const Eigen::VectorXd w = Eigen::VectorXd::Constant(2, 0.5);
  EXPECT_THROW(visibility_energy(x, t, pen, w, VisibilityBarrier{}, nullptr),
               std::invalid_argument);
  EXPECT_THROW(occlusion_pairs(x, x, t, pen, obs, 0.01), std::invalid_argument);
  t(1, 2) = 2;
  OcclusionPair pair;
  pair.vertex = 100000000;
  pair.triangle = 0;
  pair.rest_depth = 0.01;
  EXPECT_THROW(occlusion_depth(x, t, pair, nullptr), std::invalid_argument);
  pair.vertex = 3;
  pair.triangle = 2;
  EXPECT_THROW(occlusion_energy(x, t, {pair}, VisibilityBarrier{}, nullptr), std::invalid_argument);
  pair.triangle = 0;
  EXPECT_NO_THROW(occlusion_depth(x, t, pair, nullptr));
}

TEST(ControlEnergy, VisibilityEnergyGradientMatchesCentralDifferences) {
  // A random crumpled sheet: facing values spread over [-1, 1], so triangles sit on the
  // log branch, on the quadratic extension and beyond the margin.
  const int n = 5;
  Vertices x = random_vertices(n * n, 3);
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) x.row(i * n + j).head<2>() << 0.05 * i, 0.05 * j;
  Triangles t(2 * (n - 1) * (n - 1), 3);
  int f = 0;
  for (int i = 0; i + 1 < n; ++i)
    for (int j = 0; j + 1 < n; ++j) {
      t.row(f++) << i * n + j, (i + 1) * n + j, i * n + j + 1;
      t.row(f++) << (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1;
    }
  std::vector<std::uint8_t> pen(static_cast<size_t>(t.rows()), 1);
  const Eigen::VectorXd w = visibility_weights(x, t);
  EXPECT_NEAR(w.sum(), 1.0, 1e-12);
  VisibilityBarrier barrier;
  barrier.margin = 0.3;
  Vertices g;
  const double e = visibility_energy(x, t, pen, w, barrier, &g);
  EXPECT_GT(e, 0.0);
  const double h = 1e-7;
  double max_err = 0.0, max_g = 0.0;
  for (int v = 0; v < x.rows(); ++v)
    for (int d = 0; d < 3; ++d) {
      Vertices p = x, m = x;
      p(v, d) += h;
      m(v, d) -= h;
      const double fd = (visibility_energy(p, t, pen, w, barrier, nullptr) -
                         visibility_energy(m, t, pen, w, barrier, nullptr)) /
                        (2 * h);
      max_err = std::max(max_err, std::abs(fd - g(v, d)));
      max_g = std::max(max_g, std::abs(g(v, d)));
    }
  EXPECT_GT(max_g, 0.0);
  EXPECT_LT(max_err, 1e-5 * max_g);
}

// Two parallel plates facing the camera 2 cm apart (a thin board's front and back layers):
// the front layer is observed, the back layer (its triangles reversed, facing away) must stay
// hidden.
struct TwoLayers {
  Vertices x;
  Triangles t;
  std::vector<std::uint8_t> observed, penalized;
  int front_vertices = 0;
  TwoLayers() {
    const int n = 6;
    // make_plate's normal U x V: U = +x, V = -y gives -z (towards the camera).
    const auto front =
        testing::make_plate(Eigen::Vector3d(-0.1, 0.1, 1.0), Eigen::Vector3d(0.2, 0, 0),
                            Eigen::Vector3d(0, -0.2, 0), n, n);
    auto back = testing::make_plate(Eigen::Vector3d(-0.1, 0.1, 1.02), Eigen::Vector3d(0.2, 0, 0),
                                    Eigen::Vector3d(0, -0.2, 0), n, n);
    back.triangles.col(1).swap(back.triangles.col(2));  // facing away
    const auto both = testing::concatenate(front, back);
    x = both.vertices;
    t = both.triangles;
    front_vertices = static_cast<int>(front.vertices.rows());
    const auto nf = static_cast<size_t>(front.triangles.rows());
    observed.assign(static_cast<size_t>(t.rows()), 0);
    penalized.assign(static_cast<size_t>(t.rows()), 0);
    for (size_t j = 0; j < observed.size(); ++j) {
      if (j < nf)
        observed[j] = 1;
      else
        penalized[j] = 1;
    }
  }
};

TEST(ControlEnergy, OcclusionPairsTieTheBackLayerToTheFrontOne) {
  const TwoLayers s;
  const auto pairs = occlusion_pairs(s.x, s.x, s.t, s.penalized, s.observed, 0.0);
  // Every back vertex hides behind the front plate (rays from the origin to the back plate's
  // vertices cross the front plate 2 cm in front, except some through its very rim, which may
  // slip past it).
  const int back_vertices = static_cast<int>(s.x.rows()) - s.front_vertices;
  EXPECT_GE(static_cast<int>(pairs.size()), back_vertices - 2 * 7);
  double weights = 0.0;
  for (const OcclusionPair& p : pairs) {
    EXPECT_GE(p.vertex, s.front_vertices);                     // a back vertex
    EXPECT_TRUE(s.observed[static_cast<size_t>(p.triangle)]);  // behind a front triangle
    EXPECT_NEAR(p.rest_depth, 0.02, 1e-12);
    EXPECT_NEAR(occlusion_depth(s.x, s.t, p, nullptr), 1.0, 1e-12);
    weights += p.weight;
  }
  EXPECT_GT(weights, 0.3);  // most of the back layer's half of the area
  EXPECT_LT(weights, 0.5 + 1e-12);
  // At rest, and after a rigid motion, nothing is penalized.
  const VisibilityBarrier barrier{0.5, 0.1};
  EXPECT_EQ(occlusion_energy(s.x, s.t, pairs, barrier, nullptr), 0.0);
  const Eigen::Matrix3d r =
      Eigen::AngleAxisd(0.4, Eigen::Vector3d(0.3, 1, 0.2).normalized()).toRotationMatrix();
  const Vertices moved = (s.x * r.transpose()).rowwise() + Eigen::RowVector3d(0.05, 0, 0.3);
  for (const OcclusionPair& p : pairs)
    EXPECT_NEAR(occlusion_depth(moved, s.t, p, nullptr), 1.0, 1e-12);
  // A back vertex pushed through the front layer is penalized.
  Vertices poked = s.x;
  poked(pairs.front().vertex, 2) = 0.99;
  EXPECT_LT(occlusion_depth(poked, s.t, pairs.front(), nullptr), 0.0);
  EXPECT_GT(occlusion_energy(poked, s.t, pairs, barrier, nullptr), 0.0);
}

TEST(ControlEnergy, OcclusionEnergyGradientMatchesCentralDifferences) {
  TwoLayers s;
  const auto pairs = occlusion_pairs(s.x, s.x, s.t, s.penalized, s.observed, 0.0);
  ASSERT_FALSE(pairs.empty());
  // Crumple both layers so that back vertices sit at every depth: beyond the margin, on the log
  // branch, on the quadratic extension and through the front layer.
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-0.015, 0.015);
  Vertices x = s.x;
  for (Eigen::Index i = 0; i < x.rows(); ++i)
    x.row(i) += Eigen::RowVector3d(u(rng), u(rng), u(rng));
  const VisibilityBarrier barrier{0.5, 0.1};
  Vertices g;
  const double e = occlusion_energy(x, s.t, pairs, barrier, &g);
  EXPECT_GT(e, 0.0);
  const double h = 1e-7;
  double max_err = 0.0, max_g = 0.0;
  for (Eigen::Index v = 0; v < x.rows(); ++v)
    for (int d = 0; d < 3; ++d) {
      Vertices p = x, m = x;
      p(v, d) += h;
      m(v, d) -= h;
      const double fd = (occlusion_energy(p, s.t, pairs, barrier, nullptr) -
                         occlusion_energy(m, s.t, pairs, barrier, nullptr)) /
                        (2 * h);
      max_err = std::max(max_err, std::abs(fd - g(v, d)));
      max_g = std::max(max_g, std::abs(g(v, d)));
    }
  EXPECT_GT(max_g, 0.0);
  // Second derivatives reach ~ w / (margin D)^2 and third ones ~ w / (margin D)^3 (D = 2 cm):
  // truncation O(h^2) ~ 1e-8 relative, round-off ~ 1e-16 / h.
  EXPECT_LT(max_err, 1e-5 * max_g);
}

TEST(ControlEnergy, SmoothedNormSumGradientAndValue) {
  Eigen::VectorXd x(6), eps(2), g;
  x << 3, 4, 0, 0, 0, 0;
  eps << 1e-3, 1e-3;
  const double e = smoothed_norm_sum(x, 3, eps, &g);
  EXPECT_NEAR(e, 5.0 - 1e-3, 1e-6);  // sqrt(25 + 1e-6) - 1e-3 = 5 - 1e-3 + 1e-7
  EXPECT_NEAR(g[0], 0.6, 1e-6);
  EXPECT_NEAR(g[1], 0.8, 1e-6);
  EXPECT_EQ(g[3], 0.0);  // differentiable at 0
  EXPECT_THROW(smoothed_norm_sum(x, 4, eps, nullptr), std::invalid_argument);
}

}  // namespace
}  // namespace pbve
