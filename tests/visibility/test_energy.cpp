// Energy terms: values, and every analytic gradient against central differences.

#include <cmath>
#include <random>

#include <gtest/gtest.h>

#include "pbve/core/error.hpp"
#include "pbve/testing/shapes.hpp"
#include "pbve/visibility/energy.hpp"
#include "pbve/visibility/visibility.hpp"

namespace pbve {
namespace {

using testing::make_icosphere;
using testing::make_plate;
using testing::Shape;

// Central differences have truncation error O(h^2 f''') and round-off O(eps_machine f / h).
// With h = 1e-6 (coordinates and forces of order 1) both are ~1e-10 relative, so a relative
// error of 1e-5 (the requirement) leaves a wide margin while still catching any wrong term.
constexpr double kStep = 1e-6;
constexpr double kRelTol = 1e-5;

// max |a - b| / max |b|.
double relative_error(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b) {
  return (a - b).cwiseAbs().maxCoeff() / std::max(b.cwiseAbs().maxCoeff(), 1e-300);
}

// A randomly perturbed icosphere in front of the camera: its facing values spread over
// [-1, 1] so every branch of the penalties is exercised.
Shape random_blob(std::mt19937& rng) {
  Shape s = make_icosphere(1, 1.0, {0.0, 0.0, 0.0});
  std::uniform_real_distribution<double> jitter(-0.15, 0.15);
  for (Eigen::Index i = 0; i < s.vertices.rows(); ++i)
    for (int d = 0; d < 3; ++d) s.vertices(i, d) += jitter(rng);
  s.vertices.col(0).array() += 0.3;
  s.vertices.col(2).array() += 3.0;
  return s;
}

// Keeps every constrained triangle's facing value at least `gap` away from the penalty's
// kinks (s = mu for both penalties; s_floor is a C2 junction, no kink).
bool away_from_kinks(const Shape& s, const std::vector<std::uint8_t>& mask, double mu, double gap) {
  const Eigen::VectorXd f = facing_values(s.vertices, s.triangles);
  for (Eigen::Index j = 0; j < f.size(); ++j)
    if (mask[static_cast<size_t>(j)] && std::abs(f[j] - mu) < gap) return false;
  return true;
}

TEST(Energy, FacingGradientMatchesCentralDifferences) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (int trial = 0; trial < 50; ++trial) {
    Eigen::Vector3d x[3];
    for (auto& p : x) p = Eigen::Vector3d(u(rng), u(rng), 3.0 + u(rng));
    const FacingGradient g = facing_gradient(x[0], x[1], x[2]);
    Eigen::MatrixXd analytic(3, 3), numeric(3, 3);
    analytic << g.da.transpose(), g.db.transpose(), g.dc.transpose();
    for (int v = 0; v < 3; ++v) {
      for (int d = 0; d < 3; ++d) {
        Eigen::Vector3d p[3] = {x[0], x[1], x[2]}, m[3] = {x[0], x[1], x[2]};
        p[v][d] += kStep;
        m[v][d] -= kStep;
        numeric(v, d) =
            (facing_gradient(p[0], p[1], p[2]).s - facing_gradient(m[0], m[1], m[2]).s) /
            (2 * kStep);
      }
    }
    EXPECT_LT(relative_error(analytic, numeric), kRelTol) << trial;
    // s agrees with facing_values().
    Vertices v(3, 3);
    v << x[0].transpose(), x[1].transpose(), x[2].transpose();
    Triangles t(1, 3);
    t << 0, 1, 2;
    EXPECT_NEAR(facing_values(v, t)[0], g.s, 1e-15);
  }
}

TEST(Energy, PenaltiesAreContinuousAndDifferentiable) {
  for (SmoothPenalty kind : {SmoothPenalty::quadratic, SmoothPenalty::log_barrier}) {
    SmoothVisibilityOptions o;
    o.penalty = kind;
    o.margin = 0.1;
    // s_floor = 0.001 joins the barrier to its Taylor continuation: C2 there, with a jump of
    // the third derivative (~1/s^2) that a central difference of d1 would see; sample points
    // either side of it instead.
    for (double s : {-0.9, -0.3, 0.0005, 0.0009, 0.0011, 0.0015, 0.02, 0.05, 0.09, 0.3}) {
      const PenaltyValue p = smooth_penalty(s, o);
      const double d1 =
          (smooth_penalty(s + kStep, o).value - smooth_penalty(s - kStep, o).value) / (2 * kStep);
      const double d2 =
          (smooth_penalty(s + kStep, o).d1 - smooth_penalty(s - kStep, o).d1) / (2 * kStep);
      EXPECT_NEAR(p.d1, d1, kRelTol * std::max(1.0, std::abs(d1))) << s;
      EXPECT_NEAR(p.d2, d2, kRelTol * std::max(1.0, std::abs(d2))) << s;
      EXPECT_GE(p.value, 0.0);
      if (s >= o.margin) {
        EXPECT_EQ(p.value, 0.0);
      }
    }
    // Monotone: the closer to facing the camera, the larger the penalty.
    EXPECT_GT(smooth_penalty(-0.5, o).value, smooth_penalty(0.0, o).value);
    EXPECT_GT(smooth_penalty(0.0, o).value, smooth_penalty(0.05, o).value);
  }
  // The quadratic penalty is w (mu - s)^2.
  SmoothVisibilityOptions o;
  o.margin = 0.1;
  EXPECT_DOUBLE_EQ(smooth_penalty(-0.2, o).value, 0.09);
}

TEST(Energy, SmoothVisibilityGradientMatchesCentralDifferences) {
  std::mt19937 rng(11);
  int checked = 0;
  for (int trial = 0; trial < 40; ++trial) {
    const Shape s = random_blob(rng);
    std::vector<std::uint8_t> mask(s.triangles.rows());
    std::bernoulli_distribution coin(0.5);
    for (auto& m : mask) m = coin(rng);
    std::uniform_real_distribution<double> w(0.1, 1.0);
    Eigen::VectorXd weights(s.triangles.rows());
    for (Eigen::Index j = 0; j < weights.size(); ++j) weights[j] = w(rng);
    SmoothVisibilityOptions options;
    options.penalty = trial % 2 ? SmoothPenalty::log_barrier : SmoothPenalty::quadratic;
    options.margin = 0.2;
    // Perturbations of 1e-6 change s by ~1e-6; stay 1e-4 clear of the kink at mu.
    if (!away_from_kinks(s, mask, options.margin, 1e-4)) continue;
    const auto e = visibility_energy_smooth(s.vertices, s.triangles, mask, weights, options);
    ASSERT_GT(e.active_count, 0);
    Vertices numeric = Vertices::Zero(s.vertices.rows(), 3);
    for (Eigen::Index i = 0; i < s.vertices.rows(); ++i) {
      for (int d = 0; d < 3; ++d) {
        Vertices p = s.vertices, m = s.vertices;
        p(i, d) += kStep;
        m(i, d) -= kStep;
        numeric(i, d) = (visibility_energy_smooth(p, s.triangles, mask, weights, options).value -
                         visibility_energy_smooth(m, s.triangles, mask, weights, options).value) /
                        (2 * kStep);
      }
    }
    EXPECT_LT(relative_error(e.gradient, numeric), kRelTol) << trial;
    ++checked;
  }
  EXPECT_GE(checked, 20);
}

TEST(Energy, SmoothVisibilityIgnoresUnconstrainedAndFarTurnedTriangles) {
  // A plate facing away from the camera by more than the margin costs nothing; turned
  // towards it, it costs w (mu - s)^2 per triangle.
  const Shape away = make_plate({-0.2, -0.2, 2.0}, {0.4, 0.0, 0.0}, {0.0, 0.4, 0.0}, 1, 1);
  const Shape toward = make_plate({-0.2, 0.2, 2.0}, {0.4, 0.0, 0.0}, {0.0, -0.4, 0.0}, 1, 1);
  const std::vector<std::uint8_t> all(2, 1), none(2, 0);
  const Eigen::VectorXd w = Eigen::VectorXd::Constant(2, 0.5);
  EXPECT_EQ(visibility_energy_smooth(away.vertices, away.triangles, all, w).value, 0.0);
  const auto e = visibility_energy_smooth(toward.vertices, toward.triangles, all, w);
  const Eigen::VectorXd s = facing_values(toward.vertices, toward.triangles);
  EXPECT_NEAR(e.value, 0.5 * std::pow(0.05 - s[0], 2) + 0.5 * std::pow(0.05 - s[1], 2), 1e-15);
  EXPECT_EQ(e.active_count, 2);
  EXPECT_EQ(visibility_energy_smooth(toward.vertices, toward.triangles, none, w).value, 0.0);
  EXPECT_THROW(visibility_energy_smooth(toward.vertices, toward.triangles, {1}, w), InputError);
}

TEST(Energy, ForceTermsAndTheirGradients) {
  std::mt19937 rng(3);
  std::normal_distribution<double> n(0.0, 1.0);
  const double eps = 1e-3;
  for (int trial = 0; trial < 20; ++trial) {
    const int cols = trial % 2 ? 3 : 6;  // per-vertex forces or force + torque
    ForceMatrix f(9, cols), prev(9, cols);
    for (Eigen::Index i = 0; i < f.size(); ++i) {
      f.data()[i] = n(rng);
      prev.data()[i] = n(rng);
    }
    const ForceEnergy ef = force_energy(f, eps);
    const ForceEnergy et = temporal_energy(f, prev, eps);
    // Smoothing error is below eps per row.
    double norms = 0.0, diff_norms = 0.0;
    for (Eigen::Index i = 0; i < f.rows(); ++i) {
      norms += f.row(i).norm();
      diff_norms += (f.row(i) - prev.row(i)).norm();
    }
    EXPECT_NEAR(ef.value, norms, eps * f.rows());
    EXPECT_LE(ef.value, norms);
    EXPECT_NEAR(et.value, diff_norms, eps * f.rows());
    ForceMatrix nf(f.rows(), f.cols()), nt(f.rows(), f.cols());
    for (Eigen::Index i = 0; i < f.size(); ++i) {
      ForceMatrix p = f, m = f;
      p.data()[i] += kStep;
      m.data()[i] -= kStep;
      nf.data()[i] = (force_energy(p, eps).value - force_energy(m, eps).value) / (2 * kStep);
      nt.data()[i] =
          (temporal_energy(p, prev, eps).value - temporal_energy(m, prev, eps).value) / (2 * kStep);
    }
    EXPECT_LT(relative_error(ef.gradient, nf), kRelTol) << trial;
    EXPECT_LT(relative_error(et.gradient, nt), kRelTol) << trial;
  }
  // At f = 0 the smoothed norm is 0 with zero gradient (no kink).
  const ForceEnergy zero = force_energy(ForceMatrix::Zero(4, 3), eps);
  EXPECT_EQ(zero.value, 0.0);
  EXPECT_EQ(zero.gradient.cwiseAbs().maxCoeff(), 0.0);
  EXPECT_THROW(temporal_energy(ForceMatrix::Zero(4, 3), ForceMatrix::Zero(3, 3), eps), InputError);
}

TEST(Energy, FrameEnergyGradientMatchesCentralDifferences) {
  std::mt19937 rng(5);
  std::normal_distribution<double> n(0.0, 0.5);
  EnergyWeights weights;
  weights.visibility = 2.0;
  weights.force = 0.3;
  weights.temporal = 0.7;
  weights.force_eps = 1e-2;
  weights.smooth.margin = 0.2;
  int checked = 0;
  for (int trial = 0; trial < 10; ++trial) {
    const Shape s = random_blob(rng);
    std::vector<std::uint8_t> mask(s.triangles.rows());
    for (size_t j = 0; j < mask.size(); ++j) mask[j] = (j % 3) != 0;
    if (!away_from_kinks(s, mask, weights.smooth.margin, 1e-4)) continue;
    const Eigen::VectorXd w = area_weights(s.vertices, s.triangles);
    EXPECT_NEAR(w.sum(), 1.0, 1e-12);
    ForceMatrix f(s.vertices.rows(), 3), prev(s.vertices.rows(), 3);
    for (Eigen::Index i = 0; i < f.size(); ++i) {
      f.data()[i] = n(rng);
      prev.data()[i] = n(rng);
    }
    const FrameEnergy e = frame_energy(s.vertices, s.triangles, mask, w, f, prev, weights);
    EXPECT_NEAR(e.value, 2.0 * e.visibility + 0.3 * e.force + 0.7 * e.temporal, 1e-12 * e.value);
    auto value = [&](const Vertices& x, const ForceMatrix& g) {
      return frame_energy(x, s.triangles, mask, w, g, prev, weights).value;
    };
    Vertices nx(s.vertices.rows(), 3);
    for (Eigen::Index i = 0; i < s.vertices.size(); ++i) {
      Vertices p = s.vertices, m = s.vertices;
      p.data()[i] += kStep;
      m.data()[i] -= kStep;
      nx.data()[i] = (value(p, f) - value(m, f)) / (2 * kStep);
    }
    ForceMatrix nf(f.rows(), 3);
    for (Eigen::Index i = 0; i < f.size(); ++i) {
      ForceMatrix p = f, m = f;
      p.data()[i] += kStep;
      m.data()[i] -= kStep;
      nf.data()[i] = (value(s.vertices, p) - value(s.vertices, m)) / (2 * kStep);
    }
    EXPECT_LT(relative_error(e.gradient_positions, nx), kRelTol) << trial;
    EXPECT_LT(relative_error(e.gradient_forces, nf), kRelTol) << trial;
    ++checked;
  }
  EXPECT_GE(checked, 5);
}

TEST(Energy, ExactEnergyIsTheViolatingShareOfTheVisibleArea) {
  // Plate of 2 x 2 cells facing the camera: 8 triangles, all visible, equal projected areas
  // (fronto-parallel). Three unobserved triangles, one of them interior: EC = 2 / 8.
  const Camera camera;
  const Shape plate = make_plate({-0.2, 0.2, 2.0}, {0.4, 0.0, 0.0}, {0.0, -0.4, 0.0}, 2, 2);
  RayScene scene(plate.vertices, plate.triangles);
  const auto sim = compute_visibility(scene, camera);
  ASSERT_EQ(sim.visible_count(), 8);
  std::vector<std::uint8_t> observed(8, 1), interior(8, 0);
  observed[1] = observed[4] = observed[6] = 0;
  interior[6] = 1;
  const auto ec = visibility_energy_exact(observed, sim, interior);
  EXPECT_EQ(ec.violating_count, 2);
  EXPECT_NEAR(ec.value, 0.25, 1e-12);
  EXPECT_NEAR(ec.total_area_px, 120.0 * 120.0, 1e-8);  // 0.4 * 600 / 2 = 120 px square
  EXPECT_NEAR(ec.violating_area_px, 120.0 * 120.0 / 4.0, 1e-8);
  const auto mask = constrained_triangles(observed, interior);
  EXPECT_EQ(mask, (std::vector<std::uint8_t>{0, 1, 0, 0, 1, 0, 0, 0}));
  EXPECT_THROW(visibility_energy_exact({1, 0}, sim, interior), InputError);
}

}  // namespace
}  // namespace pbve
