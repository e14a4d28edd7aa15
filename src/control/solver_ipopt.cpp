// Ipopt back end: primal-dual interior point with a limited-memory (L-BFGS) Hessian.

#include <cmath>
#include <exception>
#include <limits>
#include <stdexcept>
#include <vector>

#include <IpIpoptApplication.hpp>
#include <IpSolveStatistics.hpp>
#include <IpTNLP.hpp>

#include "control/solvers.hpp"

namespace pbve::detail {

namespace {

using Ipopt::Index;
using Ipopt::Number;

class ControlTnlp : public Ipopt::TNLP {
 public:
  ControlTnlp(const SolverProblem& problem, const Eigen::VectorXd& z0)
      : m_problem(problem), m_z0(z0), m_z(z0) {}

  bool get_nlp_info(Index& n, Index& m, Index& nnz_jac_g, Index& nnz_h_lag,
                    IndexStyleEnum& index_style) override {
    n = m_problem.n;
    m = m_problem.m;
    nnz_jac_g = m_problem.n * m_problem.m;
    nnz_h_lag = 0;
    index_style = C_STYLE;
    return true;
  }
  bool get_bounds_info(Index n, Number* x_l, Number* x_u, Index m, Number* g_l,
                       Number* g_u) override {
    for (Index i = 0; i < n; ++i) {
      x_l[i] = std::isfinite(m_problem.lb[i]) ? m_problem.lb[i] : -1e20;
      x_u[i] = std::isfinite(m_problem.ub[i]) ? m_problem.ub[i] : 1e20;
    }
    for (Index j = 0; j < m; ++j) {
      g_l[j] = -1e20;
      g_u[j] = 0.0;
    }
    return true;
  }
  bool get_starting_point(Index n, bool, Number* x, bool, Number*, Number*, Index, bool,
                          Number*) override {
    for (Index i = 0; i < n; ++i) x[i] = m_z0[i];
    return true;
  }
  bool eval_f(Index, const Number* x, bool, Number& obj_value) override {
    return guard([&] { obj_value = m_problem.objective(x, nullptr); });
  }
  bool eval_grad_f(Index, const Number* x, bool, Number* grad_f) override {
    return guard([&] { m_problem.objective(x, grad_f); });
  }
  bool eval_g(Index, const Number* x, bool, Index m, Number* g) override {
    if (m == 0) return true;
    return guard([&] { m_problem.constraints(x, g, nullptr); });
  }
  bool eval_jac_g(Index n, const Number* x, bool, Index m, Index, Index* iRow, Index* jCol,
                  Number* values) override {
    if (m == 0) return true;
    if (values == nullptr) {
      for (Index j = 0, k = 0; j < m; ++j)
        for (Index i = 0; i < n; ++i, ++k) {
          iRow[k] = j;
          jCol[k] = i;
        }
      return true;
    }
    return guard([&] {
      std::vector<double> c(static_cast<size_t>(m));
      m_problem.constraints(x, c.data(), values);
    });
  }
  void finalize_solution(Ipopt::SolverReturn, Index n, const Number* x, const Number*,
                         const Number*, Index, const Number*, const Number*, Number,
                         const Ipopt::IpoptData*, Ipopt::IpoptCalculatedQuantities*) override {
    m_z = Eigen::Map<const Eigen::VectorXd>(x, n);
  }
  bool intermediate_callback(Ipopt::AlgorithmMode, Index iter, Number, Number, Number, Number,
                             Number, Number, Number, Number, Index, const Ipopt::IpoptData*,
                             Ipopt::IpoptCalculatedQuantities*) override {
    m_iterations = iter;
    if (m_error) return false;
    if (m_problem.cancelled && m_problem.cancelled()) {
      m_cancelled = true;
      return false;
    }
    return true;
  }

  const Eigen::VectorXd& solution() const { return m_z; }
  int iterations() const { return m_iterations; }
  bool cancelled() const { return m_cancelled; }
  std::exception_ptr error() const { return m_error; }

 private:
  template <class F>
  bool guard(F&& f) {
    if (m_error) return false;
    try {
      f();
      return true;
    } catch (...) {
      m_error = std::current_exception();
      return false;
    }
  }

  const SolverProblem& m_problem;
  Eigen::VectorXd m_z0, m_z;
  int m_iterations = 0;
  bool m_cancelled = false;
  std::exception_ptr m_error;
};

}  // namespace

SolverOutcome solve_ipopt(const SolverProblem& problem, const Eigen::VectorXd& z0,
                          const ControlOptions& options) {
  Ipopt::SmartPtr<Ipopt::IpoptApplication> app = IpoptApplicationFactory();
  app->Options()->SetIntegerValue("print_level", 0);
  app->Options()->SetStringValue("sb", "yes");
  app->Options()->SetStringValue("hessian_approximation", "limited-memory");
  app->Options()->SetStringValue("mu_strategy", "adaptive");
  app->Options()->SetIntegerValue("max_iter", options.max_evaluations);
  app->Options()->SetNumericValue("tol", std::max(options.ftol_rel, 1e-8));
  app->Options()->SetNumericValue("acceptable_tol", 1e-4);
  if (options.time_limit_s > 0.0)
    app->Options()->SetNumericValue("max_cpu_time", options.time_limit_s);
  if (app->Initialize() != Ipopt::Solve_Succeeded)
    throw std::runtime_error("Ipopt failed to initialize");

  Ipopt::SmartPtr<ControlTnlp> tnlp = new ControlTnlp(problem, z0);
  const Ipopt::ApplicationReturnStatus r = app->OptimizeTNLP(Ipopt::SmartPtr<Ipopt::TNLP>(tnlp));
  if (tnlp->error()) std::rethrow_exception(tnlp->error());

  SolverOutcome out;
  out.z = tnlp->solution();
  out.iterations = tnlp->iterations();
  out.message = "ipopt status " + std::to_string(static_cast<int>(r));
  switch (r) {
    case Ipopt::Solve_Succeeded:
    case Ipopt::Solved_To_Acceptable_Level:
    case Ipopt::Search_Direction_Becomes_Too_Small:
    case Ipopt::Feasible_Point_Found:
      out.status = ControlStatus::converged;
      break;
    case Ipopt::Maximum_Iterations_Exceeded:
    case Ipopt::Maximum_CpuTime_Exceeded:
      out.status = ControlStatus::iteration_limit;
      break;
    case Ipopt::User_Requested_Stop:
      out.status = tnlp->cancelled() ? ControlStatus::cancelled : ControlStatus::failed;
      break;
    default:
      out.status = ControlStatus::failed;
      break;
  }
  return out;
}

}  // namespace pbve::detail
