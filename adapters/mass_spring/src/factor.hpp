#pragma once
// A sparse factorization of a symmetric matrix of a fixed pattern (both triangles stored):
// supernodal LL^T; simplicial LDL^T (same ordering) when the matrix is indefinite; LU when
// LDL^T meets a zero pivot.

#include <limits>
#include <memory>
#include <mutex>
#include <utility>
#include <vector>

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

/// Factorizations kept for reuse, any thread: a factorization's CHOLMOD workspace and factor
/// storage are allocated on its first use, so short-lived users (step linearizations, made
/// several times per frame) take one here and give it back. The numeric result does not depend
/// on the object's history (every factorization overwrites the whole factor).
class FactorPool {
 public:
  std::unique_ptr<SymmetricFactor> take(std::shared_ptr<const CholeskyAnalysis> analysis) {
    {
      const std::lock_guard<std::mutex> lock(m_mutex);
      if (!m_free.empty()) {
        std::unique_ptr<SymmetricFactor> f = std::move(m_free.back());
        m_free.pop_back();
        return f;
      }
    }
    return std::make_unique<SymmetricFactor>(std::move(analysis));
  }
  void give(std::unique_ptr<SymmetricFactor> factor) {
    if (!factor) return;
    const std::lock_guard<std::mutex> lock(m_mutex);
    if (m_free.size() < max_kept) m_free.push_back(std::move(factor));
  }

 private:
  static constexpr size_t max_kept = 32;
  std::mutex m_mutex;
  std::vector<std::unique_ptr<SymmetricFactor>> m_free;
};

}  // namespace pbve::mass_spring::detail
