// The linear solvers of pbve::mass_spring: the sparse Cholesky factorizations (CHOLMOD, a
// symbolic analysis shared between factorizations and threads), the LDL^T / LU fallback for
// indefinite matrices, and, through the simulator, that clones stepping in parallel threads
// and separately built simulators reproduce serial runs bit for bit.

#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <random>
#include <thread>
#include <vector>

#include <Eigen/Geometry>

#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include "../../adapters/mass_spring/src/cholesky.hpp"
#include "../../adapters/mass_spring/src/factor.hpp"
#include "../../adapters/mass_spring/src/multigrid.hpp"
#include "meshes.hpp"
#include "pbve/edit/synth.hpp"
#include "pbve/mass_spring/mass_spring.hpp"
#include "support/pcg.hpp"

namespace {

using Eigen::Matrix3d;
using Eigen::SparseMatrix;
using Eigen::Vector3d;
using Eigen::VectorXd;
using pbve::SimState;
using pbve::StepInput;
using pbve::Vertices;
using pbve::mass_spring::LinearSolver;
using pbve::mass_spring::MassSpringSimulator;
using pbve::mass_spring::Material;
using pbve::mass_spring::Params;

// Calls f(a, b) once per spring of an n x n sheet: each node to its 8 neighbours.
template <class F>
void for_each_sheet_spring(int n, F f) {
  const int offsets[4][2] = {{1, 0}, {0, 1}, {1, 1}, {1, -1}};
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i)
      for (const auto& o : offsets) {
        const int i2 = i + o[0], j2 = j + o[1];
        if (i2 < n && j2 >= 0 && j2 < n) f(j * n + i, j2 * n + i2);
      }
}

// The system matrix of a backward Euler substep of an n x n sheet of side 1 m (x-y plane,
// slightly wrinkled in z) with springs to the 8 neighbours: m (1 + h alpha) I per node plus
// h^2 k [(1 - t) u u^T + t I] per spring (t: stretch of the spring), with the cloth preset's
// scaling: node mass 0.3 kg/m^2 x area, k = 2000 N/m, h = 1/300 s. Both triangles stored;
// `positions` gets the node positions.
SparseMatrix<double> sheet_matrix(int n, double stretch, VectorXd& positions) {
  const double L = 1.0 / (n - 1), h = 1.0 / 300.0, m = 0.3 * L * L, k = 2000.0;
  positions.resize(3 * n * n);
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i)
      positions.segment<3>(3 * (j * n + i)) =
          Vector3d(i * L, j * L, 0.01 * std::sin(7.0 * i * L) * std::cos(5.0 * j * L));
  std::vector<Eigen::Triplet<double>> t;
  auto add = [&t](int a, int b, const Matrix3d& B) {
    for (int c = 0; c < 3; ++c)
      for (int r = 0; r < 3; ++r) t.emplace_back(3 * a + r, 3 * b + c, B(r, c));
  };
  for (int a = 0; a < n * n; ++a) add(a, a, m * 1.005 * Matrix3d::Identity());
  for_each_sheet_spring(n, [&](int a, int b) {
    const Vector3d u = (positions.segment<3>(3 * b) - positions.segment<3>(3 * a)).normalized();
    const Matrix3d B =
        h * h * k * ((1.0 - stretch) * u * u.transpose() + stretch * Matrix3d::Identity());
    add(a, a, B);
    add(b, b, B);
    add(a, b, -B);
    add(b, a, -B);
  });
  SparseMatrix<double> A(3 * n * n, 3 * n * n);
  A.setFromTriplets(t.begin(), t.end());
  A.makeCompressed();
  return A;
}

bool bit_equal_vectors(const VectorXd& a, const VectorXd& b) {
  return a.size() == b.size() &&
         std::memcmp(a.data(), b.data(), sizeof(double) * static_cast<size_t>(a.size())) == 0;
}

VectorXd random_vector(Eigen::Index n, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> d(0.0, 1.0);
  return VectorXd::NullaryExpr(n, [&] { return d(rng); });
}

TEST(MassSpringSolvers, CholeskySolvesAndIsReproducible) {
  VectorXd x0;
  const SparseMatrix<double> A = sheet_matrix(30, 0.02, x0);
  auto analysis = std::make_shared<const pbve::mass_spring::detail::CholeskyAnalysis>(A);
  EXPECT_GT(analysis->factor_nonzeros(), static_cast<double>(A.nonZeros()) / 2);
  EXPECT_FALSE(analysis->splits_solves());  // small: CHOLMOD's own solve
  pbve::mass_spring::detail::SparseCholesky a(analysis), b(analysis);
  ASSERT_TRUE(a.factorize(A));
  ASSERT_TRUE(b.factorize(A));
  const VectorXd rhs = random_vector(A.rows(), 1);
  VectorXd xa, xb;
  a.solve(rhs, xa);
  b.solve(rhs, xb);
  EXPECT_LT((A * xa - rhs).norm(), 1e-12 * rhs.norm() * 1e3);
  // Same analysis, same matrix: the same bits.
  ASSERT_EQ(xa.size(), xb.size());
  EXPECT_EQ(std::memcmp(xa.data(), xb.data(), sizeof(double) * static_cast<size_t>(xa.size())), 0);
  // A copy shares the analysis but not the factor.
  const pbve::mass_spring::detail::SparseCholesky c(a);
  EXPECT_FALSE(c.valid());
  // An indefinite matrix is refused by LL^T.
  SparseMatrix<double> I(A.rows(), A.cols());
  I.setIdentity();
  const SparseMatrix<double> shifted = A - 2.0 * A.diagonal().mean() * I;
  EXPECT_FALSE(a.factorize(shifted));
  EXPECT_FALSE(a.valid());
  EXPECT_TRUE(a.factorize(A));  // and the factor is usable again
}

// A factor of more than a million entries: its triangular solves run in two parallel parts of
// the elimination tree, then the separators above them. Two cases: a 64 x 64 sheet (12 288
// unknowns, one tree: the parts are subtrees below its top separators) and two separate 48 x 48
// sheets (two trees, one per part, no separator above them). The solve is backward stable like
// any Cholesky solve: the residual is within a small multiple of the unit round-off times
// |A| |x|. The parts' order is fixed, so one thread gives the same bits as two.
TEST(MassSpringSolvers, LargeCholeskySolvesInTwoParallelParts) {
  VectorXd x0;
  const SparseMatrix<double> one_sheet = sheet_matrix(64, 0.02, x0);
  const SparseMatrix<double> half = sheet_matrix(48, 0.02, x0);
  SparseMatrix<double> two_sheets(2 * half.rows(), 2 * half.cols());
  {
    std::vector<Eigen::Triplet<double>> t;
    for (int k = 0; k < half.outerSize(); ++k)
      for (SparseMatrix<double>::InnerIterator it(half, k); it; ++it) {
        t.emplace_back(it.row(), it.col(), it.value());
        t.emplace_back(it.row() + half.rows(), it.col() + half.cols(), it.value());
      }
    two_sheets.setFromTriplets(t.begin(), t.end());
    two_sheets.makeCompressed();
  }
  const SparseMatrix<double>* cases[] = {&one_sheet, &two_sheets};
  for (const SparseMatrix<double>* A : cases) {
    auto analysis = std::make_shared<const pbve::mass_spring::detail::CholeskyAnalysis>(*A);
    ASSERT_TRUE(analysis->splits_solves()) << analysis->factor_nonzeros() << " factor entries";
    pbve::mass_spring::detail::SparseCholesky a(analysis), b(analysis);
    ASSERT_TRUE(a.factorize(*A));
    ASSERT_TRUE(b.factorize(*A));
    for (unsigned seed : {3u, 4u}) {
      const VectorXd rhs = random_vector(A->rows(), seed);
      VectorXd xa, xb;
      a.solve(rhs, xa);
      const double backward_error = (*A * xa - rhs).norm() / (A->norm() * xa.norm() + rhs.norm());
      EXPECT_LT(backward_error, 100 * std::numeric_limits<double>::epsilon());
      tbb::task_arena one_thread(1);
      one_thread.execute([&] { b.solve(rhs, xb); });
      EXPECT_TRUE(bit_equal_vectors(xa, xb));
    }
  }
}

// The stiffness graph of sheet_matrix(): k = 2000 N/m between 8-neighbours.
SparseMatrix<double> sheet_strength(int n) {
  std::vector<Eigen::Triplet<double>> t;
  for_each_sheet_spring(n, [&](int a, int b) {
    t.emplace_back(a, b, 2000.0);
    t.emplace_back(b, a, 2000.0);
  });
  SparseMatrix<double> S(n * n, n * n);
  S.setFromTriplets(t.begin(), t.end());
  return S;
}

// The multigrid hierarchy of an n x n sheet_matrix(): by smoothed aggregation only, or (with
// `positions`, the sheet's 3 n^2 coordinates) with its finest level coarsened by C/F splitting.
std::shared_ptr<const pbve::mass_spring::detail::MultigridHierarchy> sheet_hierarchy(
    const SparseMatrix<double>& A, int n, const VectorXd* positions) {
  using pbve::mass_spring::detail::MultigridHierarchy;
  Eigen::MatrixX3d rest;
  if (positions)
    rest = Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>>(
        positions->data(), n * n, 3);
  return std::make_shared<const MultigridHierarchy>(A, sheet_strength(n), rest);
}

using pbve::test::pcg_iterations;

// pcg_iterations() to 1e-8 with one V-cycle of m as the preconditioner, from the fixed
// pseudo-random right side b.
int vcycle_cg_iterations(const SparseMatrix<double>& A,
                         const pbve::mass_spring::detail::Multigrid& m, VectorXd& b, VectorXd& x) {
  b = random_vector(A.rows(), 2);
  return pcg_iterations(
      A, b, 1e-8, [&](const VectorXd& r, VectorXd& z) { m.apply(r, z); }, x);
}

TEST(MassSpringSolvers, MultigridIterationsDoNotGrowWithTheResolution) {
  // Sheets of 16^2, 32^2 and 64^2 nodes: h^2 k / m grows 16x from the first to the last, and
  // so does the condition number; block-Jacobi CG needs about sqrt(16) = 4x the iterations.
  // A multigrid V-cycle's contraction is bounded independently of the mesh size, so its CG
  // iteration count stays about the same: at most 1.5x that of the coarsest sheet is asked.
  // Both ways of building the finest transfer (smoothed aggregation; C/F splitting from the
  // rest positions) are held to this.
  using pbve::mass_spring::detail::Multigrid;
  using pbve::mass_spring::detail::MultigridHierarchy;
  for (const bool cf : {false, true}) {
    SCOPED_TRACE(cf ? "C/F splitting" : "smoothed aggregation");
    int mg[3], jac[3];
    const int sizes[3] = {16, 32, 64};
    for (int k = 0; k < 3; ++k) {
      const int n = sizes[k];
      VectorXd x0, x;
      const SparseMatrix<double> A = sheet_matrix(n, 0.02, x0);
      auto hierarchy = sheet_hierarchy(A, n, cf ? &x0 : nullptr);
      EXPECT_GE(hierarchy->levels().size(), k == 0 ? 2u : 3u) << n;
      Multigrid m(hierarchy);
      ASSERT_TRUE(m.setup(A));
      VectorXd b;
      mg[k] = vcycle_cg_iterations(A, m, b, x);
      ASSERT_GT(mg[k], 0) << n;
      EXPECT_LT((A * x - b).norm(), 1e-8 * b.norm() * (1 + 1e-9));
      // The V-cycle is a symmetric positive definite operator.
      const VectorXd u = random_vector(A.rows(), 3), v = random_vector(A.rows(), 4);
      VectorXd Mu, Mv;
      m.apply(u, Mu);
      m.apply(v, Mv);
      EXPECT_NEAR(u.dot(Mv), v.dot(Mu), 1e-10 * Mu.norm() * v.norm());
      EXPECT_GT(u.dot(Mu), 0.0);
      const VectorXd d = A.diagonal();
      jac[k] = pcg_iterations(
          A, b, 1e-8, [&](const VectorXd& r, VectorXd& z) { z = r.cwiseQuotient(d); }, x);
    }
    EXPECT_LE(mg[2], 1.5 * mg[0]) << mg[0] << " " << mg[1] << " " << mg[2];
    EXPECT_LE(mg[1], 1.5 * mg[0]);
    // The problem does get harder (else the check above would show nothing).
    EXPECT_TRUE(jac[2] < 0 || jac[2] > 2 * jac[0]) << jac[0] << " " << jac[2];
  }
  // An indefinite matrix is refused.
  VectorXd x0;
  const SparseMatrix<double> A = sheet_matrix(32, 0.02, x0);
  SparseMatrix<double> I(A.rows(), A.cols());
  I.setIdentity();
  Multigrid m(std::make_shared<const MultigridHierarchy>(A, sheet_strength(32)));
  EXPECT_FALSE(m.setup(A - 2.0 * A.diagonal().mean() * I));
  EXPECT_TRUE(m.setup(A));
}

TEST(MassSpringSolvers, MultigridProductAndFinestLevelUpdate) {
  // The V-cycle and the product read the upper triangle only: J x must match the full
  // matrix's product to rounding. A setup that takes a new finest matrix and keeps the coarse
  // levels of an earlier one (the next Newton iterations of a substep) must give J's product,
  // a symmetric positive definite V-cycle, and CG iterations close to a full setup's. The
  // 64 x 64 sheet is large enough for the finest level to be split into two parts and a
  // separator, smoothed by two threads: results must not depend on how many threads run.
  using pbve::mass_spring::detail::Multigrid;
  using pbve::mass_spring::detail::MultigridHierarchy;
  VectorXd x0;
  const SparseMatrix<double> A1 = sheet_matrix(64, 0.02, x0);
  const SparseMatrix<double> A2 = sheet_matrix(64, 0.05, x0);
  ASSERT_GT((A1 - A2).norm(), 1e-3 * A1.norm());
  for (const bool cf : {false, true}) {
    SCOPED_TRACE(cf ? "C/F splitting" : "smoothed aggregation");
    auto hierarchy = sheet_hierarchy(A1, 64, cf ? &x0 : nullptr);
    ASSERT_GE(hierarchy->levels().size(), 3u);
    const auto& fine = hierarchy->levels()[0];
    ASSERT_GT(fine.part[0], 0);                       // two parts
    ASSERT_LT(fine.part[1], fine.A.rows());           // and a separator
    EXPECT_LE(fine.A.rows() - fine.part[1], 3 * 64);  // a few grid lines (bending springs)
    Multigrid full(hierarchy), kept(hierarchy);
    ASSERT_TRUE(full.setup(A2));
    ASSERT_TRUE(kept.setup(A2, false));  // no earlier full setup: a full one
    ASSERT_TRUE(kept.setup(A1));
    ASSERT_TRUE(kept.setup(A2, false));
    const VectorXd u = random_vector(A2.rows(), 7), v = random_vector(A2.rows(), 8);
    VectorXd Ju;
    kept.multiply(u, Ju);
    const VectorXd ref = A2 * u;
    // Each entry sums 39 products in another order: a few units of rounding of |A| |u|.
    const VectorXd scale = A2.cwiseAbs() * u.cwiseAbs();
    EXPECT_LT(((Ju - ref).cwiseQuotient(scale)).cwiseAbs().maxCoeff(), 1e-14);
    VectorXd Mu, Mv;
    kept.apply(u, Mu);
    kept.apply(v, Mv);
    EXPECT_NEAR(u.dot(Mv), v.dot(Mu), 1e-10 * Mu.norm() * v.norm());
    EXPECT_GT(u.dot(Mu), 0.0);
    VectorXd x;
    const VectorXd b = random_vector(A2.rows(), 9);
    const int with_full = pcg_iterations(
        A2, b, 1e-8, [&](const VectorXd& r, VectorXd& z) { full.apply(r, z); }, x);
    const int with_kept = pcg_iterations(
        A2, b, 1e-8, [&](const VectorXd& r, VectorXd& z) { kept.apply(r, z); }, x);
    ASSERT_GT(with_full, 0);
    ASSERT_GT(with_kept, 0);
    EXPECT_LT((A2 * x - b).norm(), 1e-8 * b.norm() * (1 + 1e-9));
    EXPECT_LE(with_kept, 1.5 * with_full) << with_full << " " << with_kept;
    // One thread gives the same bits as two.
    VectorXd Mu1, Ju1;
    tbb::task_arena one(1);
    one.execute([&] {
      kept.apply(u, Mu1);
      kept.multiply(u, Ju1);
    });
    EXPECT_TRUE(bit_equal_vectors(Mu, Mu1));
    EXPECT_TRUE(bit_equal_vectors(Ju, Ju1));
    // The finest level still refuses an indefinite matrix.
    SparseMatrix<double> I(A2.rows(), A2.cols());
    I.setIdentity();
    EXPECT_FALSE(kept.setup(A2 - 2.0 * A2.diagonal().mean() * I, false));
  }
}

TEST(MassSpringSolvers, MultigridSplitsLargeCoarseLevels) {
  // On a 128 x 128 sheet the first coarse level (about 1.8k nodes) is also smoothed as two
  // parts and a separator, so the transfers between the levels must follow both levels'
  // orders. Checked: a symmetric positive definite V-cycle, CG iterations at most 1.5x those
  // of the 64 x 64 sheet (the mesh-independent bound asked above; with the transfers in the
  // wrong order they were about 5x), and the same bits on one thread as on two.
  using pbve::mass_spring::detail::Multigrid;
  using pbve::mass_spring::detail::MultigridHierarchy;
  for (const bool cf : {false, true}) {
    SCOPED_TRACE(cf ? "C/F splitting" : "smoothed aggregation");
    int iterations[2];
    const int sizes[2] = {64, 128};
    for (int k = 0; k < 2; ++k) {
      const int n = sizes[k];
      VectorXd x0, x, b;
      const SparseMatrix<double> A = sheet_matrix(n, 0.02, x0);
      auto hierarchy = sheet_hierarchy(A, n, cf ? &x0 : nullptr);
      Multigrid m(hierarchy);
      ASSERT_TRUE(m.setup(A));
      iterations[k] = vcycle_cg_iterations(A, m, b, x);
      ASSERT_GT(iterations[k], 0) << n;
      if (n < 128) continue;
      ASSERT_GE(hierarchy->levels().size(), 3u);
      const auto& first = hierarchy->levels()[1];
      ASSERT_GT(first.part[0], 0);               // two parts
      ASSERT_LT(first.part[1], first.A.rows());  // and a separator
      const VectorXd u = random_vector(A.rows(), 3), v = random_vector(A.rows(), 4);
      VectorXd Mu, Mv, Mu1;
      m.apply(u, Mu);
      m.apply(v, Mv);
      EXPECT_NEAR(u.dot(Mv), v.dot(Mu), 1e-10 * Mu.norm() * v.norm());
      EXPECT_GT(u.dot(Mu), 0.0);
      tbb::task_arena one(1);
      one.execute([&] { m.apply(u, Mu1); });
      EXPECT_TRUE(bit_equal_vectors(Mu, Mu1));
    }
    EXPECT_LE(iterations[1], 1.5 * iterations[0]) << iterations[0] << " " << iterations[1];
  }
}

TEST(MassSpringSolvers, MultigridCFTransferInterpolatesAffineFunctions) {
  // With rest positions, the finest level's coarse nodes are a maximal independent set of the
  // stiffness graph (on the 8-neighbour sheet, every other node of every other row: a
  // quarter), kept with weight 1, and every other node interpolates its coarse neighbours with
  // weights that reproduce constants and the rest coordinates - also on the sheet's last row
  // and column (32 nodes a side: no coarse node on them), where this takes extrapolation from
  // two links away. Without it those nodes would copy their one coarse neighbour, and a
  // free edge's bending could not be represented up to the edge.
  const int n = 32;
  VectorXd x0;
  const SparseMatrix<double> A = sheet_matrix(n, 0.02, x0);
  for (int i = 0; i < n * n; ++i) x0[3 * i + 2] = 0.0;  // flat at rest
  const auto hierarchy = sheet_hierarchy(A, n, &x0);
  const auto& fine = hierarchy->levels()[0];
  ASSERT_EQ(fine.coarse, (n / 2) * (n / 2));
  // The coarse nodes' positions: the rows of P with a single weight 1.
  std::vector<int> of_coarse(static_cast<size_t>(fine.coarse), -1);
  for (int i = 0; i < n * n; ++i) {
    const int begin = fine.p_row_start[static_cast<size_t>(i)];
    const int end = fine.p_row_start[static_cast<size_t>(i) + 1];
    if (end - begin == 1 && fine.p_row_w[static_cast<size_t>(begin)] == 1.0) {
      const int c = fine.p_row_col[static_cast<size_t>(begin)];
      EXPECT_EQ(of_coarse[static_cast<size_t>(c)], -1);
      of_coarse[static_cast<size_t>(c)] = i;
    }
  }
  for (int c = 0; c < fine.coarse; ++c) ASSERT_GE(of_coarse[static_cast<size_t>(c)], 0) << c;
  int extrapolated = 0;
  for (int i = 0; i < n * n; ++i) {
    double sum = 0.0, largest = 0.0;
    Vector3d x = Vector3d::Zero();
    bool negative = false;
    for (int q = fine.p_row_start[static_cast<size_t>(i)];
         q < fine.p_row_start[static_cast<size_t>(i) + 1]; ++q) {
      const double w = fine.p_row_w[static_cast<size_t>(q)];
      const int node = of_coarse[static_cast<size_t>(fine.p_row_col[static_cast<size_t>(q)])];
      sum += w;
      largest = std::max(largest, std::abs(w));
      negative = negative || w < 0.0;
      x += w * x0.segment<3>(3 * node);
    }
    extrapolated += negative;
    // The weights sum to 1 up to rounding; the position is reproduced by a least-squares
    // penalty of 1e8, which leaves about |w|^2 / 1e8 of the distances to the coarse nodes
    // (at most 0.2 m here): under 1e-8 m.
    EXPECT_NEAR(sum, 1.0, 1e-12) << i;
    EXPECT_LT((x - x0.segment<3>(3 * i)).norm(), 1e-8) << i;
    EXPECT_LE(largest, 2.0) << i;
  }
  // The last row's and column's nodes (2 n - 1 of them) extrapolate.
  EXPECT_GE(extrapolated, n);
}

TEST(MassSpringSolvers, IndefiniteMatricesFallBackToLdlt) {
  VectorXd x0;
  const SparseMatrix<double> A = sheet_matrix(20, 0.02, x0);
  // Shift the spectrum so that it straddles zero (nonsingular: the shift is no eigenvalue).
  SparseMatrix<double> I(A.rows(), A.cols());
  I.setIdentity();
  const SparseMatrix<double> S = A - 0.7377 * A.diagonal().mean() * I;
  pbve::mass_spring::detail::SymmetricFactor f(
      std::make_shared<const pbve::mass_spring::detail::CholeskyAnalysis>(A));
  ASSERT_TRUE(f.factorize(S));
  EXPECT_FALSE(f.positive_definite());
  const VectorXd rhs = random_vector(A.rows(), 2);
  const VectorXd x = f.solve(rhs);
  EXPECT_LT((S * x - rhs).norm(), 1e-8 * rhs.norm());
  ASSERT_TRUE(f.factorize(A));
  EXPECT_TRUE(f.positive_definite());
}

// ----- through the simulator ---------------------------------------------------------------

// The board of example 1 (40 x 30 x 1 cm, two layers tied), refined to `edge` metres, held by
// the middle of its top edge.
struct Board {
  pbve::Mesh mesh;
  std::vector<int> anchors;
  StepInput input(int f) const {
    StepInput in;
    in.anchor_targets.resize(static_cast<Eigen::Index>(anchors.size()), 3);
    const double yaw = 1.4 * std::sin(2 * 3.14159265358979 * 0.9 * f / 30.0);
    const Matrix3d R = Eigen::AngleAxisd(yaw, Vector3d::UnitY()).toRotationMatrix();
    for (size_t k = 0; k < anchors.size(); ++k)
      in.anchor_targets.row(static_cast<Eigen::Index>(k)) =
          (R * mesh.vertices.row(anchors[k]).transpose()).transpose();
    return in;
  }
};

Board make_board(double edge) {
  Board b;
  b.mesh = pbve::refine_mesh(pbve::make_box_mesh(0.4, 0.3, 0.01), edge);
  for (int i = 0; i < b.mesh.num_vertices(); ++i)
    if (std::abs(b.mesh.vertices(i, 1)) < 1e-9 && std::abs(b.mesh.vertices(i, 0)) <= 0.05)
      b.anchors.push_back(i);
  return b;
}

Params board_params(LinearSolver solver, double tolerance) {
  Params p = Params::preset(Material::cloth);
  p.substeps = 3;
  p.linear_solver = solver;
  p.newton_tolerance = tolerance;
  p.single_sheet = 0;  // the two tied layers: the larger system, one block per vertex
  return p;
}

bool bit_equal(const Vertices& a, const Vertices& b) {
  return a.rows() == b.rows() && a.cols() == b.cols() &&
         std::memcmp(a.data(), b.data(), sizeof(double) * static_cast<size_t>(a.size())) == 0;
}

TEST(MassSpringSolvers, ParallelClonesReproduceSerialRuns) {
  // Clones step different controls in parallel threads (as parallel central differences do);
  // each must match the same control stepped serially, bit for bit: the factorizations share
  // one symbolic analysis and BLAS runs in the calling thread.
  // (The iterative solver keeps no factorization between calls; its determinism is the
  // conformance suite's.)
  for (LinearSolver solver : {LinearSolver::direct, LinearSolver::multigrid}) {
    const Board board = make_board(0.035);
    MassSpringSimulator sim(board.mesh, board.anchors, board_params(solver, 1e-6));
    for (int f = 1; f <= 2; ++f) sim.step(board.input(f));
    const SimState s0 = sim.save();
    const int probes = 4;
    std::vector<StepInput> inputs;
    for (int k = 0; k < probes; ++k) {
      StepInput in = board.input(3);
      in.control = 1e-4 * random_vector(3 * sim.num_vertices(), 10 + k);
      inputs.push_back(in);
    }
    std::vector<Vertices> serial, parallel(probes);
    std::vector<VectorXd> serial_jvp, parallel_jvp(probes);
    const VectorXd du = random_vector(3 * sim.num_vertices(), 99);
    for (int k = 0; k < probes; ++k) {
      sim.restore(s0);
      sim.step(inputs[static_cast<size_t>(k)]);
      serial.push_back(sim.positions());
      serial_jvp.push_back(sim.linearize_step(s0, inputs[static_cast<size_t>(k)])->jvp({}, du));
    }
    std::vector<std::unique_ptr<pbve::Simulator>> clones;
    for (int k = 0; k < probes; ++k) clones.push_back(sim.clone());
    std::vector<std::thread> threads;
    for (int k = 0; k < probes; ++k)
      threads.emplace_back([&, k] {
        pbve::Simulator& c = *clones[static_cast<size_t>(k)];
        c.restore(s0);
        c.step(inputs[static_cast<size_t>(k)]);
        parallel[static_cast<size_t>(k)] = c.positions();
        parallel_jvp[static_cast<size_t>(k)] =
            c.linearize_step(s0, inputs[static_cast<size_t>(k)])->jvp({}, du);
      });
    for (std::thread& t : threads) t.join();
    for (int k = 0; k < probes; ++k) {
      EXPECT_TRUE(bit_equal(serial[static_cast<size_t>(k)], parallel[static_cast<size_t>(k)]))
          << "probe " << k << (solver == LinearSolver::direct ? " direct" : " multigrid");
      const VectorXd& a = serial_jvp[static_cast<size_t>(k)];
      const VectorXd& b = parallel_jvp[static_cast<size_t>(k)];
      ASSERT_EQ(a.size(), b.size());
      EXPECT_EQ(std::memcmp(a.data(), b.data(), sizeof(double) * static_cast<size_t>(a.size())), 0)
          << "jvp of probe " << k;
    }
  }
}

TEST(MassSpringSolvers, AStepDoesNotDependOnTheThreadCount) {
  // A 64 x 64 cloth (about 24k springs, 4096 nodes) takes the threaded paths: the spring blocks
  // and block columns of the Newton matrix, the springs' forces and the nodes' residuals, and
  // chunks of the incremental potential are computed in parallel, the multigrid's finest
  // level is smoothed as two parts, and its restriction and Galerkin product to the next level
  // run by ranges of coarse rows. One thread must give the same bits.
  const int n = 64;
  const pbve::Mesh mesh = pbve::test::grid_mesh(n, 1.0);
  Params p = Params::preset(Material::cloth);
  p.linear_solver = LinearSolver::multigrid;
  MassSpringSimulator sim(mesh, {0, n - 1}, p);
  ASSERT_GE(sim.num_springs(), 20000);
  StepInput in;
  in.control = 1e-3 * random_vector(3 * sim.num_vertices(), 5);
  sim.step(in);
  const SimState s0 = sim.save();
  sim.step(in);
  const Vertices two = sim.positions();
  ASSERT_TRUE(sim.last_stats().converged);
  sim.restore(s0);
  tbb::task_arena one(1);
  one.execute([&] { sim.step(in); });
  EXPECT_TRUE(bit_equal(two, sim.positions()));
  // And the step moved the cloth: the comparison is not between two unchanged states.
  EXPECT_GT((two - pbve::Vertices(mesh.vertices)).cwiseAbs().maxCoeff(), 1e-3);
}

TEST(MassSpringSolvers, ALinearizationDoesNotDependOnTheThreadCount) {
  // The same 64 x 64 cloth: linearize_step() factorizes its substeps' matrices in parallel, and
  // their factors (12 288 unknowns, over a million entries) are solved in two parallel parts of
  // the elimination tree. One thread must give the same bits in jvp() and vjp().
  const int n = 64;
  const pbve::Mesh mesh = pbve::test::grid_mesh(n, 1.0);
  Params p = Params::preset(Material::cloth);
  p.substeps = 3;
  MassSpringSimulator sim(mesh, {0, n - 1}, p);
  StepInput in;
  in.control = 1e-3 * random_vector(3 * sim.num_vertices(), 6);
  sim.step(in);
  const SimState s0 = sim.save();
  sim.step(in);
  const VectorXd du = random_vector(in.control.size(), 7);
  const VectorXd g = random_vector(sim.state_dim(), 8);
  const auto two = sim.linearize_step(s0, in);
  const VectorXd jvp_two = two->jvp(VectorXd(), du);
  const pbve::StepVjp vjp_two = two->vjp(g);
  VectorXd jvp_one;
  pbve::StepVjp vjp_one;
  tbb::task_arena one(1);
  one.execute([&] {
    const auto lin = sim.linearize_step(s0, in);
    jvp_one = lin->jvp(VectorXd(), du);
    vjp_one = lin->vjp(g);
  });
  EXPECT_TRUE(bit_equal_vectors(jvp_two, jvp_one));
  EXPECT_TRUE(bit_equal_vectors(vjp_two.state, vjp_one.state));
  EXPECT_TRUE(bit_equal_vectors(vjp_two.control, vjp_one.control));
  EXPECT_GT(jvp_two.norm(), 0.0);  // the products are not trivially equal
  EXPECT_GT(vjp_two.control.norm(), 0.0);
}

TEST(MassSpringSolvers, TheAutomaticChoiceFactorizesOnlyUpToItsLimit) {
  // LinearSolver::automatic factorizes up to direct_solver_max_dofs free unknowns (300 by
  // default) and runs multigrid-preconditioned CG above, which never factorizes a Newton matrix
  // of a cloth step (its coarsest level is dense and not counted).
  auto factorizations = [](int n, int max_dofs) {
    Params p = Params::preset(Material::cloth);
    if (max_dofs >= 0) p.direct_solver_max_dofs = max_dofs;
    MassSpringSimulator sim(pbve::test::grid_mesh(n, 0.5), {0, n - 1}, p);
    sim.step(StepInput{});
    EXPECT_TRUE(sim.last_stats().converged) << n << " x " << n;
    EXPECT_GT(sim.last_stats().newton_iterations, 0) << n << " x " << n;
    return sim.last_stats().factorizations;
  };
  // 8 x 8 nodes, two anchored: 186 free unknowns; 12 x 12: 426.
  EXPECT_GT(factorizations(8, -1), 0);
  EXPECT_EQ(factorizations(12, -1), 0);
  EXPECT_GT(factorizations(12, 426), 0);
  EXPECT_EQ(factorizations(12, 425), 0);
  EXPECT_EQ(factorizations(8, 0), 0);
}

TEST(MassSpringSolvers, FreshInstancesStepIdentically) {
  // Two simulators built separately (each its own symbolic analysis, AMD or METIS ordering)
  // give the same bits.
  const Board board = make_board(0.035);
  MassSpringSimulator a(board.mesh, board.anchors, board_params(LinearSolver::direct, 1e-6));
  MassSpringSimulator b(board.mesh, board.anchors, board_params(LinearSolver::direct, 1e-6));
  for (int f = 1; f <= 3; ++f) {
    a.step(board.input(f));
    b.step(board.input(f));
  }
  EXPECT_TRUE(bit_equal(a.positions(), b.positions()));
}

TEST(MassSpringSolvers, ACompressedClothStepsTheSameWhetherItsFactorizationIsKeptOrNot) {
  // Newton starts on the exact Hessian, which a cloth squeezed to 60% of its rest size in its
  // plane makes indefinite (every spring compressed: negative stiffness across it, out of the
  // plane nothing else). A step that factorizes it finds that out and factorizes the projected
  // Hessian instead, and keeps that for the next step from the same start; such a step must
  // take the same path without factorizing anything, and give the same bits as a fresh one.
  const pbve::Mesh grid = pbve::test::grid_mesh(16, 0.5);
  Params p = Params::preset(Material::cloth);
  p.substeps = 3;
  p.linear_solver = LinearSolver::direct;
  MassSpringSimulator sim(grid, {0, 15}, p);
  SimState s0 = sim.save();
  const size_t n = static_cast<size_t>(grid.num_vertices());
  for (size_t i = 0; i < n; ++i) {
    double* x = &s0.values[3 * i];
    x[0] *= 0.6;
    x[1] *= 0.6;
    x[2] += 1e-3 * std::sin(9.0 * x[0]) * std::cos(7.0 * x[1]);  // off the plane, a little
  }
  StepInput a, b;
  a.control = 1e-4 * random_vector(3 * sim.num_vertices(), 5);
  b.control = 1e-4 * random_vector(3 * sim.num_vertices(), 6);
  const std::unique_ptr<pbve::Simulator> fresh_base = sim.clone();
  sim.restore(s0);
  sim.step(a);  // makes the factorization of this start
  sim.restore(s0);
  sim.step(b);  // keeps it
  const int kept = sim.last_stats().factorizations;
  const Vertices kept_positions = sim.positions();
  MassSpringSimulator fresh(grid, {0, 15}, p);
  fresh.restore(s0);
  fresh.step(b);
  // The fresh step's first solve factorizes twice (exact: refused; projected), the kept one
  // not at all; everything after is the same.
  EXPECT_EQ(fresh.last_stats().factorizations, kept + 2);
  EXPECT_TRUE(bit_equal(fresh.positions(), kept_positions));
  // A clone starts without the factorization, like a fresh simulator.
  fresh_base->restore(s0);
  fresh_base->step(b);
  EXPECT_TRUE(bit_equal(fresh_base->positions(), kept_positions));
}

TEST(MassSpringSolvers, NewtonStopsOnTheResidualWithinTheTolerance) {
  // A 32 x 32 cloth of 1 m, horizontal, held at two corners, swinging under gravity
  // (multigrid). Within a step each substep after the first starts from the previous one's
  // acceleration, and Newton stops as soon as the mass-scaled residual bounds the next update
  // by the tolerance, which spares the solve that would only confirm an update's size in most
  // substeps: fewer than the 3 Newton iterations per substep that the update test needs here.
  // Each substep is then within about the tolerance of its solution, so the step stays within
  // substeps x tolerance of the same step converged to 1e-12.
  pbve::Mesh sheet = pbve::test::grid_mesh(32, 1.0);
  for (Eigen::Index i = 0; i < sheet.vertices.rows(); ++i)
    sheet.vertices.row(i) =
        Eigen::RowVector3d(sheet.vertices(i, 0), 0.0, 1.5 + sheet.vertices(i, 1));
  Params p = Params::preset(Material::cloth);
  p.linear_solver = LinearSolver::multigrid;
  Params tight = p;
  tight.newton_tolerance = 1e-12;
  MassSpringSimulator sim(sheet, {0, 31}, p);
  MassSpringSimulator reference(sheet, {0, 31}, tight);
  for (int f = 1; f <= 3; ++f) sim.step(StepInput{});
  reference.restore(sim.save());
  const double bound = p.substeps * p.newton_tolerance / 31.0;  // edges of 1/31 m and longer
  for (int f = 4; f <= 6; ++f) {
    sim.step(StepInput{});
    reference.step(StepInput{});
    EXPECT_TRUE(sim.last_stats().converged) << f;
    EXPECT_LT(sim.last_stats().newton_iterations, 3 * p.substeps) << f;
    const double error = (sim.positions() - reference.positions()).cwiseAbs().maxCoeff();
    EXPECT_LT(error, bound) << f;
    reference.restore(sim.save());
  }
}

TEST(MassSpringSolvers, NewtonLeavesSaddlesAlongNegativeCurvature) {
  // A 16 x 16 cloth of 1 m, horizontal, held at two neighbouring corners and falling, without
  // bending stiffness (the flat sheet's bending energy would keep it off the saddles): from the
  // fifth step on (one substep each) the exact Hessian is indefinite near the solution. Newton
  // on the projected Hessian alone converged there linearly, at a ratio close to 1 (199
  // iterations with the direct solver, 187 with block-Jacobi CG), and the solvers then ended
  // up to 0.4 mm apart. Stepping along the negative curvature that conjugate gradients meet,
  // every solver reaches the same backward Euler step in a few iterations.
  pbve::Mesh sheet = pbve::test::grid_mesh(16, 1.0, 0.0);
  for (Eigen::Index i = 0; i < sheet.vertices.rows(); ++i)
    sheet.vertices.row(i) =
        Eigen::RowVector3d(sheet.vertices(i, 0), 0.0, 2.0 + sheet.vertices(i, 1));
  const double edge = 1.0 / 15.0;
  auto make = [&](LinearSolver solver) {
    Params p = Params::preset(Material::cloth);
    p.substeps = 1;
    p.newton_iterations = 300;
    p.linear_solver = solver;
    p.bend_stiffness = 0.0;
    return MassSpringSimulator(sheet, {0, 15}, p);
  };
  MassSpringSimulator direct = make(LinearSolver::direct);
  MassSpringSimulator iterative = make(LinearSolver::iterative);
  MassSpringSimulator multigrid = make(LinearSolver::multigrid);
  std::vector<MassSpringSimulator*> sims = {&direct, &iterative, &multigrid};
  const double tol = direct.params().newton_tolerance * edge;
  std::vector<int> curvature_steps(sims.size(), 0);
  for (int f = 1; f <= 6; ++f) {
    for (size_t s = 0; s < sims.size(); ++s) {
      sims[s]->step(StepInput{});
      const auto& st = sims[s]->last_stats();
      EXPECT_TRUE(st.converged) << "solver " << s << " step " << f;
      EXPECT_LE(st.max_newton_iterations, 12) << "solver " << s << " step " << f;
      curvature_steps[s] += st.curvature_steps;
    }
    // Newton stops once an update is below the tolerance; quadratic convergence leaves the
    // iterate much closer than that to the solution.
    EXPECT_LT((iterative.positions() - direct.positions()).cwiseAbs().maxCoeff(), tol) << f;
    EXPECT_LT((multigrid.positions() - direct.positions()).cwiseAbs().maxCoeff(), tol) << f;
  }
  for (size_t s = 0; s < sims.size(); ++s) EXPECT_GE(curvature_steps[s], 1) << "solver " << s;
}

}  // namespace
