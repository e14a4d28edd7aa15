#pragma once
// Algebraic multigrid for the symmetric 3x3-block systems of a model (the Newton and adjoint
// matrices J = M (1 + h alpha) + h^2 K + ... on the free nodes), used as the preconditioner of
// conjugate gradients.
//
// Everything that depends only on the topology is built once per model and shared by clones
// (MultigridHierarchy): the coarse spaces of every level, found from the rest springs'
// stiffness between free nodes - by C/F splitting when the nodes' rest positions are given
// (about a quarter of a level's nodes kept, with their positions, the others interpolated
// linearly from them), on every level where that coarsens, and below that or without positions
// by smoothed aggregation (one translation per aggregate and direction, smoothed once with the
// stiffness graph) - the coarse matrices' patterns and the plans of their Galerkin products. A
// matrix then costs only its numeric setup (Multigrid::setup(): one pass over each level's Galerkin
// plan, the inverses of the diagonal blocks and a dense LL^T of the coarsest level, a few hundred
// unknowns at most), and a V-cycle costs a few matrix-vector products: both linear in the number of
// nodes.

#include <memory>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <Eigen/SparseCore>

#include "shared_once.hpp"

namespace pbve::mass_spring::detail {

/// The fixed part of a hierarchy.
class MultigridHierarchy {
 public:
  /// pattern: the free-free matrix pattern (3n x 3n, full 3x3 blocks, both triangles stored).
  /// strength: n x n, symmetric, off-diagonal entries >= 0 (the stiffness connecting two free
  /// nodes, N/m), pattern within the pattern's blocks. Throws std::logic_error if the pattern
  /// is not made of full 3x3 blocks.
  /// rest: n x 3, the nodes' rest positions, or empty; with them, levels coarsen by C/F
  /// splitting with affine interpolation while that coarsens, then (and without them) by
  /// smoothed aggregation.
  MultigridHierarchy(const Eigen::SparseMatrix<double>& pattern,
                     const Eigen::SparseMatrix<double>& strength,
                     const Eigen::MatrixX3d& rest = Eigen::MatrixX3d());

  /// Block sparse rows: row i's blocks are start[i] .. start[i + 1] - 1, in column col[e];
  /// diag[i] is the diagonal block of row i.
  struct Blocks {
    std::vector<int> start, col, diag;
    int rows() const { return static_cast<int>(start.size()) - 1; }
  };
  /// One block += weight * another (indices into two block arrays).
  struct PlanEntry {
    int dst, src;
    double w;
  };
  struct Level {
    Blocks A;  // the level's matrix pattern
    // Prolongator to this level from the next (scalar weights, times the 3x3 identity), by
    // rows (this level's nodes) and by columns (the next level's nodes); empty on the coarsest.
    std::vector<int> p_row_start, p_row_col, p_col_start, p_col_row;
    std::vector<double> p_row_w, p_col_w;
    int coarse = 0;  // nodes of the next level
    // Galerkin product A_next = P^T A P in two passes through T = P^T A (pattern `T`):
    // T[dst] += w A[src], then A_next[dst] += w T[src]. Both plans are in the order of their
    // destination rows (the next level's nodes): row b's entries are to_t[t_plan[b] ..
    // t_plan[b + 1]) and to_next[next_plan[b] .. next_plan[b + 1]), and write only to row b, so
    // rows can be summed in parallel with the serial result.
    Blocks T;
    std::vector<PlanEntry> to_t, to_next;
    std::vector<int> t_plan, next_plan;
    // The V-cycle's order of the level's nodes: position k is node order[k]. On a large level
    // (not the coarsest), two parts with no coupling between them, then their separator: positions
    // [0, part[0]) and [part[0], part[1]) are smoothed in parallel, [part[1], n) after them
    // (before them backwards); elsewhere the natural order, one part (part[0] = part[1] = n).
    // The smoother is Gauss-Seidel in that order whether or not threads run it.
    std::vector<int> order;
    int part[2] = {0, 0};
    // In that order: the strict upper triangle of A by rows (U.diag unused) and, per entry and
    // per diagonal block, its block in A; the smoother and the product read only these (A is
    // symmetric), half of A's memory traffic.
    Blocks U;
    std::vector<int> u_src, d_src;
    // The prolongator in the orders of this level and the next: by rows (this level's
    // positions; columns the next level's positions) and by columns (the next level's
    // positions; rows this level's positions).
    std::vector<int> c_row_start, c_row_col, c_col_start, c_col_row;
    std::vector<double> c_row_w, c_col_w;
  };
  const std::vector<Level>& levels() const { return m_levels; }
  /// Level 0's blocks in the pattern: entry (r, c) of block e is valuePtr()[fine_offsets()[3 e +
  /// r] + c] (J is symmetric, so block row i is read from the columns 3 i .. 3 i + 2).
  const std::vector<int>& fine_offsets() const { return m_fine_offset; }

 private:
  std::vector<Level> m_levels;
  std::vector<int> m_fine_offset;
};

/// A hierarchy built on first use, once, whichever thread asks first.
using SharedMultigridHierarchy = SharedOnce<MultigridHierarchy>;

/// The numeric part: the Galerkin matrices of one J and their smoothers. (Single precision
/// would halve the matrix traffic that bounds a V-cycle's speed, but at 16k cloth vertices it
/// made Newton take 84 iterations per step instead of 50: CG on the exact Hessian broke down.
/// Single-precision storage with double arithmetic kept the iterations but was slower: the
/// conversions cost more than the traffic saved.)
class Multigrid {
 public:
  using Real = double;
  using Block = Eigen::Matrix<Real, 3, 3>;
  using Vector = Eigen::Matrix<Real, Eigen::Dynamic, 1>;

  Multigrid() = default;
  explicit Multigrid(std::shared_ptr<const MultigridHierarchy> hierarchy);
  bool empty() const { return !m_h; }

  /// Sets up for J (the hierarchy's pattern). Returns false if a diagonal block or the
  /// coarsest matrix is not positive definite (J is then not either; apply() must not be
  /// called). With coarse = false, only the finest level (the smoother and multiply()) takes
  /// J and the coarser levels keep the Galerkin matrices of the last full setup (which must
  /// have succeeded, else this is a full setup): the V-cycle stays symmetric positive definite
  /// for a positive definite J and is a good preconditioner for a J close to the last one
  /// (the next Newton iterations of a substep), at a third of the cost.
  bool setup(const Eigen::SparseMatrix<double>& J, bool coarse = true);
  /// z = one V-cycle on J z = r from z = 0: forward block Gauss-Seidel before, backward after
  /// each coarse correction, so a symmetric positive definite operator when J is.
  void apply(const Eigen::VectorXd& r, Eigen::VectorXd& z) const;
  /// y = J x for the J of the last setup() (its free-free blocks, read from the upper triangle).
  void multiply(const Eigen::VectorXd& x, Eigen::VectorXd& y) const;

 private:
  void cycle(size_t level) const;

  std::shared_ptr<const MultigridHierarchy> m_h;
  // Per level: all blocks (for the Galerkin products), the strict upper triangle's blocks, the
  // diagonal blocks and their inverses.
  std::vector<std::vector<Block>> m_A, m_U, m_D, m_Dinv;
  std::vector<Block> m_T;
  // Made from an empty matrix, not default-constructed: Eigen's default LLT leaves its
  // ComputationInfo uninitialized, which moving a Multigrid would then read.
  Eigen::LLT<Eigen::MatrixXd> m_coarsest{Eigen::MatrixXd(0, 0)};
  bool m_coarse_ready = false;                // the last full setup succeeded
  mutable std::vector<Vector> m_b, m_x, m_r;  // per level: right side, iterate, residual
  mutable Vector m_sep[2];     // split levels: each part's contributions to the separator rows
  mutable Vector m_in, m_out;  // multiply(): x and y in the finest level's order
};

}  // namespace pbve::mass_spring::detail
