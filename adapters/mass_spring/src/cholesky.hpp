#pragma once
// Sparse Cholesky factorizations (CHOLMOD) of symmetric matrices of one fixed pattern: the
// symbolic analysis (fill-reducing ordering, supernodes) is done once per pattern and shared,
// read-only, by every factorization of a matrix with that pattern, in any thread; each
// factorization owns its numeric factor and workspace.
//
// Results are bit-reproducible: BLAS runs single-threaded (OpenBLAS is set to one thread on
// first use) and CHOLMOD's OpenMP loops run in the calling thread. Two factorizations of the
// same matrix with the same analysis give the same bits, whichever thread computes them.

#include <memory>

#include <Eigen/Core>
#include <Eigen/SparseCore>

#include "shared_once.hpp"

namespace pbve::mass_spring::detail {

/// The symbolic analysis of a symmetric pattern (both triangles stored; the lower one is read).
class CholeskyAnalysis {
 public:
  /// Orders the pattern (the better of AMD and METIS nested dissection by fill) and computes
  /// the supernodal structure of L.
  explicit CholeskyAnalysis(const Eigen::SparseMatrix<double>& pattern);
  ~CholeskyAnalysis();
  CholeskyAnalysis(const CholeskyAnalysis&) = delete;
  CholeskyAnalysis& operator=(const CholeskyAnalysis&) = delete;

  Eigen::Index size() const;
  /// Nonzeros of the factor L and flops of one numeric factorization (CHOLMOD's estimates).
  double factor_nonzeros() const;
  double factor_flops() const;
  /// Whether solves with the LL^T factor run in two parallel parts of the elimination tree
  /// (large factors; the same bits whether the parts run in parallel or in turn).
  bool splits_solves() const;

  struct Impl;
  const Impl& impl() const { return *m_impl; }

 private:
  std::unique_ptr<Impl> m_impl;
};

/// An analysis computed on first use, once, whichever thread asks first.
using SharedCholeskyAnalysis = SharedOnce<CholeskyAnalysis>;

/// A numeric factorization A = L L^T (supernodal), or A = L D L^T (simplicial, no pivoting:
/// also for indefinite matrices whose leading minors are nonsingular) of matrices with the
/// analyzed pattern. Copies start empty (they share the analysis, not the factor).
class SparseCholesky {
 public:
  enum class Kind { llt, ldlt };

  SparseCholesky();
  explicit SparseCholesky(std::shared_ptr<const CholeskyAnalysis> analysis, Kind kind = Kind::llt);
  SparseCholesky(const SparseCholesky& other);
  SparseCholesky& operator=(const SparseCholesky& other);
  ~SparseCholesky();

  /// Factorizes A (same pattern as the analysis, values of both triangles equal). Returns false
  /// when A is not positive definite (LL^T) or a pivot is zero (LDL^T); the factor is then
  /// invalid until the next successful factorization.
  bool factorize(const Eigen::SparseMatrix<double>& A);
  bool valid() const { return m_valid; }
  /// True when default-constructed (no analysis).
  bool empty() const { return !m_analysis; }
  Kind kind() const { return m_kind; }
  /// x = A^-1 b for the last successfully factorized A. Uses this object's workspace: one call
  /// at a time per object. LL^T on a large factor: the triangular solves run over the supernodes
  /// in two parallel parts (CholeskyAnalysis::splits_solves()); else CHOLMOD solves.
  void solve(const Eigen::VectorXd& b, Eigen::VectorXd& x) const;

 private:
  struct Numeric;
  void split_solve(const Eigen::VectorXd& b, Eigen::VectorXd& x) const;
  std::shared_ptr<const CholeskyAnalysis> m_analysis;
  Kind m_kind = Kind::llt;
  std::unique_ptr<Numeric> m_numeric;
  bool m_valid = false;
};

}  // namespace pbve::mass_spring::detail
