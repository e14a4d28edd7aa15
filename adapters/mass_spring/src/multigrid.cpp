#include "multigrid.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include <Eigen/LU>

namespace pbve::mass_spring::detail {

namespace {

using Eigen::Matrix3d;
using Eigen::SparseMatrix;
using Eigen::Vector3d;
using Eigen::VectorXd;
using Blocks = MultigridHierarchy::Blocks;
using Level = MultigridHierarchy::Level;
using Real = Multigrid::Real;
using Block = Multigrid::Block;
using Vector = Multigrid::Vector;
using Vec3 = Eigen::Matrix<Real, 3, 1>;

// Coarsening stops at this many nodes (the coarsest matrix is factorized dense) or when a level
// would keep more than `max_coarse_ratio` of its nodes.
constexpr int coarsest_nodes = 96;
constexpr double max_coarse_ratio = 0.6;
// Two nodes are strongly connected when their connection is at least this fraction of the
// geometric mean of their total connections (smoothed aggregation's usual criterion).
constexpr double strength_threshold = 0.08;
// Prolongator smoothing P = (I - omega D^-1 S_F) P_0 with the filtered stiffness graph S_F,
// whose D^-1 S_F has spectral radius at most 2 (a graph Laplacian): omega = 4 / (3 * 2).
constexpr double smoothing_omega = 2.0 / 3.0;

// Per node: the aggregate it belongs to. Greedy aggregation of the strong-connection graph:
// a node whose strong neighbours are all free starts an aggregate with them; the nodes left
// join the aggregate of their strongest aggregated neighbour; the rest (no aggregated strong
// neighbour) start aggregates with their free strong neighbours.
std::vector<int> aggregate(const std::vector<std::vector<std::pair<int, double>>>& strong,
                           int& count) {
  const int n = static_cast<int>(strong.size());
  std::vector<int> agg(static_cast<size_t>(n), -1);
  count = 0;
  for (int i = 0; i < n; ++i) {
    const auto& nb = strong[static_cast<size_t>(i)];
    if (agg[static_cast<size_t>(i)] >= 0 || nb.empty()) continue;
    if (std::any_of(nb.begin(), nb.end(),
                    [&](const auto& e) { return agg[static_cast<size_t>(e.first)] >= 0; }))
      continue;
    agg[static_cast<size_t>(i)] = count;
    for (const auto& e : nb) agg[static_cast<size_t>(e.first)] = count;
    ++count;
  }
  const std::vector<int> first = agg;
  for (int i = 0; i < n; ++i) {
    if (agg[static_cast<size_t>(i)] >= 0) continue;
    double best = -1.0;
    for (const auto& e : strong[static_cast<size_t>(i)])
      if (first[static_cast<size_t>(e.first)] >= 0 && e.second > best) {
        best = e.second;
        agg[static_cast<size_t>(i)] = first[static_cast<size_t>(e.first)];
      }
  }
  for (int i = 0; i < n; ++i) {
    if (agg[static_cast<size_t>(i)] >= 0) continue;
    agg[static_cast<size_t>(i)] = count;
    for (const auto& e : strong[static_cast<size_t>(i)])
      if (agg[static_cast<size_t>(e.first)] < 0) agg[static_cast<size_t>(e.first)] = count;
    ++count;
  }
  return agg;
}

// Builds the transfer of `level` from its strength graph S (n x n, symmetric, off-diagonal
// entries the connection weights >= 0; the diagonal is ignored). Returns the next level's S
// (P^T L P with L the graph Laplacian of S), or an empty matrix when coarsening stops.
SparseMatrix<double> build_transfer(const SparseMatrix<double>& S, Level& level) {
  const int n = static_cast<int>(S.rows());
  std::vector<double> total(static_cast<size_t>(n), 0.0);
  for (int j = 0; j < n; ++j)
    for (SparseMatrix<double>::InnerIterator it(S, j); it; ++it)
      if (it.row() != j) total[static_cast<size_t>(j)] += std::abs(it.value());
  std::vector<std::vector<std::pair<int, double>>> strong(static_cast<size_t>(n));
  for (int j = 0; j < n; ++j)
    for (SparseMatrix<double>::InnerIterator it(S, j); it; ++it) {
      const int i = static_cast<int>(it.row());
      const double w = std::abs(it.value());
      if (i != j && w > 0.0 &&
          w >= strength_threshold *
                   std::sqrt(total[static_cast<size_t>(i)] * total[static_cast<size_t>(j)]))
        strong[static_cast<size_t>(j)].emplace_back(i, w);
    }
  int count = 0;
  const std::vector<int> agg = aggregate(strong, count);
  if (n <= coarsest_nodes || count > max_coarse_ratio * n || count == 0) return {};

  // P = (I - omega D^-1 S_F) P_0, row by row: P_0 puts node i in its aggregate with weight 1.
  SparseMatrix<double> P(n, count);
  std::vector<Eigen::Triplet<double>> entries;
  for (int i = 0; i < n; ++i) {
    const auto& nb = strong[static_cast<size_t>(i)];
    double d = 0.0;
    for (const auto& e : nb) d += e.second;
    const int a = agg[static_cast<size_t>(i)];
    if (d <= 0.0) {
      entries.emplace_back(i, a, 1.0);
      continue;
    }
    entries.emplace_back(i, a, 1.0 - smoothing_omega);
    for (const auto& e : nb)
      entries.emplace_back(i, agg[static_cast<size_t>(e.first)], smoothing_omega * e.second / d);
  }
  P.setFromTriplets(entries.begin(), entries.end());  // sums duplicates
  P.prune(0.0);
  level.coarse = count;
  const SparseMatrix<double, Eigen::RowMajor> Pr = P;
  level.p_row_start.assign(Pr.outerIndexPtr(), Pr.outerIndexPtr() + n + 1);
  level.p_row_col.assign(Pr.innerIndexPtr(), Pr.innerIndexPtr() + Pr.nonZeros());
  level.p_row_w.assign(Pr.valuePtr(), Pr.valuePtr() + Pr.nonZeros());
  level.p_col_start.assign(P.outerIndexPtr(), P.outerIndexPtr() + count + 1);
  level.p_col_row.assign(P.innerIndexPtr(), P.innerIndexPtr() + P.nonZeros());
  level.p_col_w.assign(P.valuePtr(), P.valuePtr() + P.nonZeros());

  // The next level's strength graph: the Galerkin product of the Laplacian.
  std::vector<Eigen::Triplet<double>> lap;
  for (int j = 0; j < n; ++j) {
    lap.emplace_back(j, j, total[static_cast<size_t>(j)]);
    for (SparseMatrix<double>::InnerIterator it(S, j); it; ++it)
      if (it.row() != j) lap.emplace_back(static_cast<int>(it.row()), j, -std::abs(it.value()));
  }
  SparseMatrix<double> L(n, n);
  L.setFromTriplets(lap.begin(), lap.end());
  SparseMatrix<double> next = SparseMatrix<double>(P.transpose()) * L * P;
  next.prune(0.0);
  return next;
}

// The Galerkin plans of `level` (whose A pattern and transfer are set) and the next level's
// pattern.
Blocks build_plans(Level& level) {
  const Blocks& A = level.A;
  const int n = A.rows(), nc = level.coarse;
  // T = P^T A: row b sums w * (row i of A) over the nodes i of P's column b.
  Blocks& T = level.T;
  T.start.assign(1, 0);
  std::vector<int> mark(static_cast<size_t>(n), -1);
  for (int b = 0; b < nc; ++b) {
    const int row_begin = static_cast<int>(T.col.size());
    for (int k = level.p_col_start[static_cast<size_t>(b)];
         k < level.p_col_start[static_cast<size_t>(b) + 1]; ++k) {
      const int i = level.p_col_row[static_cast<size_t>(k)];
      const double w = level.p_col_w[static_cast<size_t>(k)];
      for (int e = A.start[static_cast<size_t>(i)]; e < A.start[static_cast<size_t>(i) + 1]; ++e) {
        const int j = A.col[static_cast<size_t>(e)];
        int& t = mark[static_cast<size_t>(j)];
        if (t < row_begin) {
          t = static_cast<int>(T.col.size());
          T.col.push_back(j);
        }
        level.to_t.push_back({t, e, w});
      }
    }
    T.start.push_back(static_cast<int>(T.col.size()));
  }
  // A_next = T P: block (b, c) sums w * T(b, j) over the entries (j, c) of P.
  Blocks next;
  next.start.assign(1, 0);
  std::vector<int> cmark(static_cast<size_t>(nc), -1);
  for (int b = 0; b < nc; ++b) {
    const int row_begin = static_cast<int>(next.col.size());
    for (int t = T.start[static_cast<size_t>(b)]; t < T.start[static_cast<size_t>(b) + 1]; ++t) {
      const int j = T.col[static_cast<size_t>(t)];
      for (int k = level.p_row_start[static_cast<size_t>(j)];
           k < level.p_row_start[static_cast<size_t>(j) + 1]; ++k) {
        const int c = level.p_row_col[static_cast<size_t>(k)];
        int& dst = cmark[static_cast<size_t>(c)];
        if (dst < row_begin) {
          dst = static_cast<int>(next.col.size());
          next.col.push_back(c);
        }
        level.to_next.push_back({dst, t, level.p_row_w[static_cast<size_t>(k)]});
      }
    }
    next.start.push_back(static_cast<int>(next.col.size()));
  }
  next.diag.assign(static_cast<size_t>(nc), -1);
  for (int b = 0; b < nc; ++b)
    for (int e = next.start[static_cast<size_t>(b)]; e < next.start[static_cast<size_t>(b) + 1];
         ++e)
      if (next.col[static_cast<size_t>(e)] == b) next.diag[static_cast<size_t>(b)] = e;
  return next;
}

// The strict upper triangle of A by rows; src[e] is entry e's block in A.
Blocks upper_of(const Blocks& A, std::vector<int>& src) {
  Blocks U;
  U.start.assign(1, 0);
  src.clear();
  for (int i = 0; i < A.rows(); ++i) {
    for (int e = A.start[static_cast<size_t>(i)]; e < A.start[static_cast<size_t>(i) + 1]; ++e)
      if (A.col[static_cast<size_t>(e)] > i) {
        U.col.push_back(A.col[static_cast<size_t>(e)]);
        src.push_back(e);
      }
    U.start.push_back(static_cast<int>(U.col.size()));
  }
  return U;
}

}  // namespace

MultigridHierarchy::MultigridHierarchy(const SparseMatrix<double>& pattern,
                                       const SparseMatrix<double>& strength) {
  const int n = static_cast<int>(strength.rows());
  if (pattern.rows() != 3 * n || pattern.cols() != 3 * n || strength.cols() != n)
    throw std::logic_error("multigrid: pattern and strength graph sizes differ");
  // Level 0's blocks from the symmetric pattern: block row i = block column i, read from
  // columns 3i .. 3i + 2, which must hold the same rows in groups of three.
  Level fine;
  Blocks& A = fine.A;
  A.start.assign(1, 0);
  A.diag.assign(static_cast<size_t>(n), -1);
  const int* outer = pattern.outerIndexPtr();
  const int* inner = pattern.innerIndexPtr();
  for (int i = 0; i < n; ++i) {
    const int len = outer[3 * i + 1] - outer[3 * i];
    if (len % 3 != 0 || outer[3 * i + 2] - outer[3 * i + 1] != len ||
        outer[3 * i + 3] - outer[3 * i + 2] != len)
      throw std::logic_error("multigrid: the pattern is not made of full 3x3 blocks");
    for (int p = 0; p < len / 3; ++p) {
      const int row = inner[outer[3 * i] + 3 * p];
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c)
          if (inner[outer[3 * i + r] + 3 * p + c] != row + c || row % 3 != 0)
            throw std::logic_error("multigrid: the pattern is not made of full 3x3 blocks");
      const int j = row / 3;
      if (j == i) A.diag[static_cast<size_t>(i)] = static_cast<int>(A.col.size());
      A.col.push_back(j);
      for (int r = 0; r < 3; ++r) m_fine_offset.push_back(outer[3 * i + r] + 3 * p);
    }
    if (A.diag[static_cast<size_t>(i)] < 0)
      throw std::logic_error("multigrid: the pattern lacks a diagonal block");
    A.start.push_back(static_cast<int>(A.col.size()));
  }
  m_levels.push_back(std::move(fine));
  SparseMatrix<double> S = strength;
  for (;;) {
    Level& level = m_levels.back();
    S = build_transfer(S, level);
    if (level.coarse == 0) break;
    Blocks next = build_plans(level);
    Level coarse;
    coarse.A = std::move(next);
    m_levels.push_back(std::move(coarse));
  }
  for (Level& level : m_levels) level.U = upper_of(level.A, level.u_src);
}

Multigrid::Multigrid(std::shared_ptr<const MultigridHierarchy> hierarchy)
    : m_h(std::move(hierarchy)) {
  const size_t L = m_h->levels().size();
  m_A.resize(L);
  m_U.resize(L);
  m_D.resize(L);
  m_Dinv.resize(L);
  m_b.resize(L);
  m_x.resize(L);
  m_r.resize(L);
  for (size_t l = 0; l < L; ++l) {
    const Blocks& A = m_h->levels()[l].A;
    m_A[l].resize(A.col.size());
    m_U[l].resize(m_h->levels()[l].U.col.size());
    m_D[l].resize(static_cast<size_t>(A.rows()));
    m_Dinv[l].resize(static_cast<size_t>(A.rows()));
    m_b[l].resize(3 * A.rows());
    m_x[l].resize(3 * A.rows());
    m_r[l].resize(3 * A.rows());
  }
}

bool Multigrid::setup(const SparseMatrix<double>& J, bool coarse) {
  coarse = coarse || !m_coarse_ready;
  m_coarse_ready = false;
  const auto& levels = m_h->levels();
  const double* val = J.valuePtr();
  const std::vector<int>& off = m_h->fine_offsets();
  // Level 0's block e of J (all of them only when the coarse levels are made from it).
  auto fine = [&](int e) {
    Block B;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c)
        B(r, c) =
            static_cast<Real>(val[off[3 * static_cast<size_t>(e) + static_cast<size_t>(r)] + c]);
    return B;
  };
  if (coarse)
    for (size_t e = 0; e < m_A[0].size(); ++e) m_A[0][e] = fine(static_cast<int>(e));
  for (size_t l = 0; l < levels.size(); ++l) {
    const Level& level = levels[l];
    const Blocks& A = level.A;
    auto block = [&](int e) { return l == 0 ? fine(e) : m_A[l][static_cast<size_t>(e)]; };
    for (int i = 0; i < A.rows(); ++i) {
      const Matrix3d D = block(A.diag[static_cast<size_t>(i)]).cast<double>();
      // Positive definite by Sylvester's criterion (leading minors; no absolute threshold:
      // a light node's block at a short step is legitimately tiny), and a finite inverse.
      const double minor2 = D(0, 0) * D(1, 1) - D(0, 1) * D(1, 0);
      if (!(D(0, 0) > 0.0) || !(minor2 > 0.0) || !(D.determinant() > 0.0)) return false;
      const Matrix3d inv = D.inverse();
      if (!inv.allFinite()) return false;
      m_Dinv[l][static_cast<size_t>(i)] = inv.cast<Real>();
      m_D[l][static_cast<size_t>(i)] = D.cast<Real>();
    }
    for (size_t e = 0; e < level.u_src.size(); ++e) m_U[l][e] = block(level.u_src[e]);
    if (l + 1 == levels.size()) break;
    if (!coarse) {
      m_coarse_ready = true;
      return true;
    }
    m_T.assign(level.T.col.size(), Block::Zero());
    for (const auto& p : level.to_t)
      m_T[static_cast<size_t>(p.dst)].noalias() +=
          static_cast<Real>(p.w) * m_A[l][static_cast<size_t>(p.src)];
    std::vector<Block>& next = m_A[l + 1];
    std::fill(next.begin(), next.end(), Block::Zero());
    for (const auto& p : level.to_next)
      next[static_cast<size_t>(p.dst)].noalias() +=
          static_cast<Real>(p.w) * m_T[static_cast<size_t>(p.src)];
  }
  // The coarsest level, dense.
  const Blocks& C = levels.back().A;
  Eigen::MatrixXd dense = Eigen::MatrixXd::Zero(3 * C.rows(), 3 * C.rows());
  for (int i = 0; i < C.rows(); ++i)
    for (int e = C.start[static_cast<size_t>(i)]; e < C.start[static_cast<size_t>(i) + 1]; ++e)
      dense.block<3, 3>(3 * i, 3 * C.col[static_cast<size_t>(e)]) =
          m_A.back()[static_cast<size_t>(e)].cast<double>();
  m_coarsest.compute(dense);
  m_coarse_ready = m_coarsest.info() == Eigen::Success;
  return m_coarse_ready;
}

// The smoother and the product read the symmetric A = L + D + U from U and D only: row i's
// lower blocks are the transposes of the blocks (j, i) of U, used by scattering from row j.
void Multigrid::cycle(size_t l) const {
  const auto& levels = m_h->levels();
  if (l + 1 == levels.size()) {
    m_x[l] = m_coarsest.solve(m_b[l].cast<double>()).cast<Real>();
    return;
  }
  const Level& level = levels[l];
  const Blocks& U = level.U;
  const std::vector<Block>& u = m_U[l];
  const std::vector<Block>& dinv = m_Dinv[l];
  const int n = U.rows();
  Vector& x = m_x[l];
  Vector& s = m_r[l];
  const Vector& b = m_b[l];
  // Forward Gauss-Seidel from x = 0: s_i = b_i - sum_{j<i} A_ij x_j is complete when row i is
  // reached, and row i's upper blocks then carry x_i to the later rows.
  s = b;
  for (int i = 0; i < n; ++i) {
    const Vec3 xi = dinv[static_cast<size_t>(i)] * s.segment<3>(3 * i);
    x.segment<3>(3 * i) = xi;
    for (int e = U.start[static_cast<size_t>(i)]; e < U.start[static_cast<size_t>(i) + 1]; ++e)
      s.segment<3>(3 * U.col[static_cast<size_t>(e)]).noalias() -=
          u[static_cast<size_t>(e)].transpose() * xi;
  }
  // Its residual b - A x is -U x (the sweep zeroed b - (L + D) x), restricted row by row.
  Vector& bc = m_b[l + 1];
  bc.setZero();
  for (int i = 0; i < n; ++i) {
    Vec3 ri = Vec3::Zero();
    for (int e = U.start[static_cast<size_t>(i)]; e < U.start[static_cast<size_t>(i) + 1]; ++e)
      ri.noalias() -= u[static_cast<size_t>(e)] * x.segment<3>(3 * U.col[static_cast<size_t>(e)]);
    for (int k = level.p_row_start[static_cast<size_t>(i)];
         k < level.p_row_start[static_cast<size_t>(i) + 1]; ++k)
      bc.segment<3>(3 * level.p_row_col[static_cast<size_t>(k)]) +=
          static_cast<Real>(level.p_row_w[static_cast<size_t>(k)]) * ri;
  }
  cycle(l + 1);
  // Coarse correction, and s = b - L x for the backward sweep, in one pass.
  const Vector& xc = m_x[l + 1];
  s = b;
  for (int i = 0; i < n; ++i) {
    Vec3 xi = x.segment<3>(3 * i);
    for (int k = level.p_row_start[static_cast<size_t>(i)];
         k < level.p_row_start[static_cast<size_t>(i) + 1]; ++k)
      xi += static_cast<Real>(level.p_row_w[static_cast<size_t>(k)]) *
            xc.segment<3>(3 * level.p_row_col[static_cast<size_t>(k)]);
    x.segment<3>(3 * i) = xi;
    for (int e = U.start[static_cast<size_t>(i)]; e < U.start[static_cast<size_t>(i) + 1]; ++e)
      s.segment<3>(3 * U.col[static_cast<size_t>(e)]).noalias() -=
          u[static_cast<size_t>(e)].transpose() * xi;
  }
  // Backward Gauss-Seidel: x_i = D_i^-1 (b_i - (L x)_i - sum_{j>i} A_ij x_j).
  for (int i = n - 1; i >= 0; --i) {
    Vec3 si = s.segment<3>(3 * i);
    for (int e = U.start[static_cast<size_t>(i)]; e < U.start[static_cast<size_t>(i) + 1]; ++e)
      si.noalias() -= u[static_cast<size_t>(e)] * x.segment<3>(3 * U.col[static_cast<size_t>(e)]);
    x.segment<3>(3 * i) = dinv[static_cast<size_t>(i)] * si;
  }
}

void Multigrid::multiply(const VectorXd& x, VectorXd& y) const {
  const Blocks& U = m_h->levels()[0].U;
  const std::vector<Block>& u = m_U[0];
  const std::vector<Block>& d = m_D[0];
  y.resize(x.size());
  for (int i = 0; i < U.rows(); ++i)
    y.segment<3>(3 * i).noalias() = d[static_cast<size_t>(i)] * x.segment<3>(3 * i);
  for (int i = 0; i < U.rows(); ++i) {
    const Vector3d xi = x.segment<3>(3 * i);
    Vector3d yi = y.segment<3>(3 * i);
    for (int e = U.start[static_cast<size_t>(i)]; e < U.start[static_cast<size_t>(i) + 1]; ++e) {
      const int j = U.col[static_cast<size_t>(e)];
      const Block& B = u[static_cast<size_t>(e)];
      yi.noalias() += B * x.segment<3>(3 * j);
      y.segment<3>(3 * j).noalias() += B.transpose() * xi;
    }
    y.segment<3>(3 * i) = yi;
  }
}

void Multigrid::apply(const VectorXd& r, VectorXd& z) const {
  m_b[0] = r.cast<Real>();
  cycle(0);
  z = m_x[0].cast<double>();
}

}  // namespace pbve::mass_spring::detail
