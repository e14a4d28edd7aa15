#pragma once
// Preconditioned conjugate gradients that count their iterations, for the solver tests and
// benchmarks (the engine's own CG is internal to the simulator).

#include <Eigen/Core>
#include <Eigen/SparseCore>

namespace pbve::test {

/// CG on A x = b from x = 0 to |r| <= tol |b|, with multiply(p, Ap) computing Ap = A p and
/// precondition(r, z) computing z = M^-1 r. Returns the iterations, or -1 if not converged in
/// 1000 or on breakdown (p^T A p not positive).
template <class Multiply, class Precondition>
int pcg_iterations(Multiply multiply, const Eigen::VectorXd& b, double tol,
                   Precondition precondition, Eigen::VectorXd& x) {
  x = Eigen::VectorXd::Zero(b.size());
  Eigen::VectorXd r = b, z, Ap;
  precondition(r, z);
  Eigen::VectorXd p = z;
  double rz = r.dot(z);
  for (int it = 1; it <= 1000; ++it) {
    multiply(p, Ap);
    const double pAp = p.dot(Ap);
    if (!(pAp > 0.0)) return -1;
    x += (rz / pAp) * p;
    r -= (rz / pAp) * Ap;
    if (r.norm() <= tol * b.norm()) return it;
    precondition(r, z);
    const double rz_new = r.dot(z);
    p = z + (rz_new / rz) * p;
    rz = rz_new;
  }
  return -1;
}

/// The same with a sparse matrix A.
template <class Precondition>
int pcg_iterations(const Eigen::SparseMatrix<double>& A, const Eigen::VectorXd& b, double tol,
                   Precondition precondition, Eigen::VectorXd& x) {
  return pcg_iterations([&A](const Eigen::VectorXd& p, Eigen::VectorXd& Ap) { Ap = A * p; }, b, tol,
                        precondition, x);
}

}  // namespace pbve::test
