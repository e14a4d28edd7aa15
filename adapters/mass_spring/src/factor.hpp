#pragma once
// A sparse factorization of a symmetric matrix of a fixed pattern (both triangles stored):
// supernodal LL^T; simplicial LDL^T (same ordering) when the matrix is indefinite; LU when
// LDL^T meets a zero pivot.

#include <limits>
#include <memory>
#include <utility>

#include <Eigen/Core>
#include <Eigen/SparseCore>
#include <Eigen/SparseLU>

#include "cholesky.hpp"

namespace pbve::mass_spring::detail {

class SymmetricFactor {
 public:
  explicit SymmetricFactor(std::shared_ptr<const CholeskyAnalysis> analysis)
      : m_llt(analysis, SparseCholesky::Kind::llt),
        m_ldlt(std::move(analysis), SparseCholesky::Kind::ldlt) {}

  /// Factorizes A. Returns false when neither LL^T, LDL^T nor LU succeeds.
  bool factorize(const Eigen::SparseMatrix<double>& A) {
    m_used = Used::none;
    if (m_llt.factorize(A)) {
      m_used = Used::llt;
    } else if (m_ldlt.factorize(A)) {
      m_used = Used::ldlt;
    } else {
      m_lu.compute(A);
      if (m_lu.info() == Eigen::Success) m_used = Used::lu;
    }
    return valid();
  }
  bool valid() const { return m_used != Used::none; }
  /// True when A was positive definite (factorized as LL^T).
  bool positive_definite() const { return m_used == Used::llt; }
  /// x = A^-1 b (A symmetric, so also A^-T b).
  Eigen::VectorXd solve(const Eigen::VectorXd& b) const {
    Eigen::VectorXd x;
    switch (m_used) {
      case Used::llt:
        m_llt.solve(b, x);
        break;
      case Used::ldlt:
        m_ldlt.solve(b, x);
        break;
      case Used::lu:
        x = m_lu.solve(b);
        break;
      case Used::none:
        x = Eigen::VectorXd::Constant(b.size(), std::numeric_limits<double>::quiet_NaN());
        break;
    }
    return x;
  }

 private:
  enum class Used { none, llt, ldlt, lu };
  SparseCholesky m_llt, m_ldlt;
  Eigen::SparseLU<Eigen::SparseMatrix<double>> m_lu;
  Used m_used = Used::none;
};

}  // namespace pbve::mass_spring::detail
