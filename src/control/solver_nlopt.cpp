// NLopt back end: LD_SLSQP, LD_MMA, LD_LBFGS, LN_COBYLA.

#include <cmath>
#include <exception>
#include <stdexcept>
#include <vector>

#include <nlopt.hpp>

#include "control/solvers.hpp"

namespace pbve::detail {

namespace {

struct NloptData {
  const SolverProblem* problem = nullptr;
  std::exception_ptr error;
  bool cancelled = false;
  int evaluations = 0;
};

double objective(const std::vector<double>& z, std::vector<double>& grad, void* data) {
  auto* d = static_cast<NloptData*>(data);
  try {
    if (d->problem->cancelled && d->problem->cancelled()) throw ControlCancelled{};
    ++d->evaluations;
    return d->problem->objective(z.data(), grad.empty() ? nullptr : grad.data());
  } catch (const ControlCancelled&) {
    d->cancelled = true;
  } catch (...) {
    d->error = std::current_exception();
  }
  throw nlopt::forced_stop();
}

void constraints(unsigned /*m*/, double* c, unsigned /*n*/, const double* z, double* jac,
                 void* data) {
  auto* d = static_cast<NloptData*>(data);
  try {
    d->problem->constraints(z, c, jac);
    return;
  } catch (...) {
    d->error = std::current_exception();
  }
  throw nlopt::forced_stop();
}

nlopt::algorithm algorithm(ControlSolver solver) {
  switch (solver) {
    case ControlSolver::slsqp:
      return nlopt::LD_SLSQP;
    case ControlSolver::mma:
      return nlopt::LD_MMA;
    case ControlSolver::lbfgs:
      return nlopt::LD_LBFGS;
    case ControlSolver::cobyla:
      return nlopt::LN_COBYLA;
    case ControlSolver::ipopt:
      break;
  }
  throw std::invalid_argument("solve_nlopt: not an NLopt solver");
}

}  // namespace

SolverOutcome solve_nlopt(const SolverProblem& problem, const Eigen::VectorXd& z0,
                          const ControlOptions& options) {
  const auto n = static_cast<unsigned>(problem.n);
  nlopt::opt opt(algorithm(options.solver), n);
  NloptData data;
  data.problem = &problem;
  opt.set_min_objective(objective, &data);
  if (problem.m > 0) {
    if (options.solver == ControlSolver::lbfgs)
      throw std::invalid_argument("the hard-constraint mode needs slsqp, mma, cobyla or ipopt");
    opt.add_inequality_mconstraint(constraints, &data,
                                   std::vector<double>(static_cast<size_t>(problem.m), 1e-8));
  }
  opt.set_lower_bounds(std::vector<double>(problem.lb.data(), problem.lb.data() + n));
  opt.set_upper_bounds(std::vector<double>(problem.ub.data(), problem.ub.data() + n));
  opt.set_maxeval(options.max_evaluations);
  opt.set_ftol_rel(options.ftol_rel);
  opt.set_xtol_abs(options.xtol_abs);
  if (options.time_limit_s > 0.0) opt.set_maxtime(options.time_limit_s);
  if (options.solver == ControlSolver::cobyla) {
    // First simplex: a quarter of each block's weight, inside the bounds.
    std::vector<double> step(n, 0.25);
    for (unsigned i = 0; i < n; ++i)
      if (std::isfinite(problem.ub[i])) step[i] = std::min(step[i], 0.5 * problem.ub[i]);
    opt.set_initial_step(step);
  }

  std::vector<double> z(z0.data(), z0.data() + n);
  double f = 0.0;
  SolverOutcome out;
  nlopt::result r = nlopt::FAILURE;
  try {
    r = opt.optimize(z, f);
    out.message = "nlopt result " + std::to_string(static_cast<int>(r));
  } catch (const nlopt::forced_stop&) {
    r = nlopt::FORCED_STOP;
    out.message = "forced stop";
  } catch (const nlopt::roundoff_limited&) {
    r = nlopt::ROUNDOFF_LIMITED;
    out.message = "roundoff limited";
  } catch (const std::exception& e) {
    r = nlopt::FAILURE;
    out.message = e.what();
  }
  if (data.error) std::rethrow_exception(data.error);
  switch (r) {
    case nlopt::SUCCESS:
    case nlopt::STOPVAL_REACHED:
    case nlopt::FTOL_REACHED:
    case nlopt::XTOL_REACHED:
    case nlopt::ROUNDOFF_LIMITED:
      out.status = ControlStatus::converged;
      break;
    case nlopt::MAXEVAL_REACHED:
    case nlopt::MAXTIME_REACHED:
      out.status = ControlStatus::iteration_limit;
      break;
    case nlopt::FORCED_STOP:
      out.status = data.cancelled ? ControlStatus::cancelled : ControlStatus::failed;
      break;
    default:
      out.status = ControlStatus::failed;
      break;
  }
  out.iterations = data.evaluations;
  out.z = Eigen::Map<const Eigen::VectorXd>(z.data(), problem.n);
  return out;
}

}  // namespace pbve::detail
