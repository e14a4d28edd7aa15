#pragma once
// Solver back ends of the control optimizer (NLopt and Ipopt), behind one small interface.
// Implementation-only header.

#include <functional>
#include <string>

#include <Eigen/Core>

#include "pbve/control/optimizer.hpp"

namespace pbve::detail {

/// Thrown by an objective when the cancel hook fired.
struct ControlCancelled {};

/// min f(z) s.t. c(z) <= 0 (m constraints), lb <= z <= ub.
struct SolverProblem {
  int n = 0;
  int m = 0;
  /// Objective; writes the gradient (n entries) when grad is not null.
  std::function<double(const double* z, double* grad)> objective;
  /// Constraints c (m entries) and, when jac is not null, their Jacobian (m x n row-major).
  std::function<void(const double* z, double* c, double* jac)> constraints;
  /// Called once per solver iteration (Ipopt) or evaluation (NLopt); true = stop.
  std::function<bool()> cancelled;
  Eigen::VectorXd lb, ub;  ///< +-infinity allowed
};

struct SolverOutcome {
  ControlStatus status = ControlStatus::converged;
  int iterations = 0;
  std::string message;
  Eigen::VectorXd z;  ///< the solver's final point
};

SolverOutcome solve_nlopt(const SolverProblem& problem, const Eigen::VectorXd& z0,
                          const ControlOptions& options);
SolverOutcome solve_ipopt(const SolverProblem& problem, const Eigen::VectorXd& z0,
                          const ControlOptions& options);

}  // namespace pbve::detail
