#pragma once
// A sparse factorization of a symmetric matrix of a fixed pattern (both triangles stored):
// LDL^T, with LU as the fallback for matrices LDL^T cannot factorize (singular leading minors
// of an indefinite matrix).

#include <Eigen/Core>
#include <Eigen/SparseCholesky>
#include <Eigen/SparseCore>
#include <Eigen/SparseLU>

namespace pbve::mass_spring::detail {

class SymmetricFactor {
 public:
  /// Factorizes A (the pattern is analyzed on first use). Returns false when neither LDL^T
  /// nor LU succeeds.
  bool factorize(const Eigen::SparseMatrix<double>& A) {
    if (!m_analyzed) {
      m_ldlt.analyzePattern(A);
      m_analyzed = true;
    }
    m_ldlt.factorize(A);
    m_lu_used = m_ldlt.info() != Eigen::Success;
    if (m_lu_used) {
      m_lu.compute(A);
      m_valid = m_lu.info() == Eigen::Success;
    } else {
      m_valid = true;
    }
    return m_valid;
  }
  bool valid() const { return m_valid; }
  /// x = A^-1 b (A symmetric, so also A^-T b).
  Eigen::VectorXd solve(const Eigen::VectorXd& b) const {
    return m_lu_used ? Eigen::VectorXd(m_lu.solve(b)) : Eigen::VectorXd(m_ldlt.solve(b));
  }

 private:
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>, Eigen::Lower> m_ldlt;
  Eigen::SparseLU<Eigen::SparseMatrix<double>> m_lu;
  bool m_analyzed = false, m_valid = false, m_lu_used = false;
};

}  // namespace pbve::mass_spring::detail
