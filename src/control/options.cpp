// The optimizer's option types: names, parsing and ControlOptions::validate(), apart from the
// optimizer so that the scene reader (and its fuzz target) needs no solver library.

#include <cmath>
#include <sstream>
#include <stdexcept>
#include <string>

#include "pbve/control/optimizer.hpp"
#include "pbve/core/error.hpp"

namespace pbve {

const char* to_string(ControlStatus status) {
  switch (status) {
    case ControlStatus::converged:
      return "converged";
    case ControlStatus::iteration_limit:
      return "iteration_limit";
    case ControlStatus::failed:
      return "failed";
    case ControlStatus::cancelled:
      return "cancelled";
  }
  return "unknown";
}

const char* to_string(ControlSolver solver) {
  switch (solver) {
    case ControlSolver::slsqp:
      return "slsqp";
    case ControlSolver::mma:
      return "mma";
    case ControlSolver::lbfgs:
      return "lbfgs";
    case ControlSolver::cobyla:
      return "cobyla";
    case ControlSolver::ipopt:
      return "ipopt";
  }
  return "unknown";
}

ControlSolver parse_control_solver(const std::string& name) {
  for (ControlSolver s : {ControlSolver::slsqp, ControlSolver::mma, ControlSolver::lbfgs,
                          ControlSolver::cobyla, ControlSolver::ipopt})
    if (name == to_string(s)) return s;
  throw std::invalid_argument("unknown solver '" + name +
                              "' (expected slsqp, mma, lbfgs, cobyla or ipopt)");
}

namespace {

std::string describe(double value) {
  std::ostringstream s;
  s << value;
  return s.str();
}

[[noreturn]] void bad_option(const char* field, const std::string& message) {
  throw InputError(message, {}, 0, std::string("ControlOptions::") + field);
}

// Each check refuses NaN as well: NaN fails every comparison.
void require_non_negative(double value, const char* field) {
  if (!(value >= 0.0 && std::isfinite(value)))
    bad_option(field, "must be a finite number >= 0, got " + describe(value));
}
void require_positive(double value, const char* field) {
  if (!(value > 0.0 && std::isfinite(value)))
    bad_option(field, "must be a finite number > 0, got " + describe(value));
}
void require_open_unit(double value, const char* field) {
  if (!(value > 0.0 && value < 1.0))
    bad_option(field, "must be greater than 0 and less than 1, got " + describe(value));
}
void require_unit_from_zero(double value, const char* field) {
  if (!(value >= 0.0 && value < 1.0))
    bad_option(field, "must be at least 0 and less than 1, got " + describe(value));
}
void require_at_least(int value, int least, const char* field) {
  if (value < least)
    bad_option(field,
               "must be at least " + std::to_string(least) + ", got " + std::to_string(value));
}
// An enumerator of `E` from `first` to `last` (a value cast from an integer may be neither).
template <class E>
void require_enumerator(E value, E first, E last, const char* field) {
  const auto v = static_cast<int>(value);
  if (v < static_cast<int>(first) || v > static_cast<int>(last))
    bad_option(field, "is not one of its enumerators (value " + std::to_string(v) + ")");
}

}  // namespace

void ControlOptions::validate() const {
  require_non_negative(weights.visibility, "weights.visibility");
  require_non_negative(weights.force, "weights.force");
  require_non_negative(weights.temporal, "weights.temporal");
  require_open_unit(barrier.margin, "barrier.margin");
  require_open_unit(barrier.clamp, "barrier.clamp");
  require_enumerator(solver, ControlSolver::slsqp, ControlSolver::ipopt, "solver");
  require_enumerator(gradient, GradientMode::automatic, GradientMode::adjoint, "gradient");
  require_enumerator(constraint, ConstraintMode::soft, ConstraintMode::hard, "constraint");
  require_enumerator(initial_guess, InitialGuess::zero, InitialGuess::previous, "initial_guess");
  require_at_least(window, 1, "window");
  require_enumerator(active_set, ActiveSet::at_risk, ActiveSet::all, "active_set");
  if (!std::isfinite(active_band))
    bad_option("active_band", "must be a finite number, got " + describe(active_band));
  require_at_least(active_rings, 0, "active_rings");
  require_at_least(clusters, 0, "clusters");
  require_unit_from_zero(occlusion_margin, "occlusion_margin");
  require_non_negative(force_bound, "force_bound");
  require_positive(torque_arm, "torque_arm");
  require_positive(force_smoothing, "force_smoothing");
  require_positive(fd_step, "fd_step");
  require_at_least(difference_rings, 0, "difference_rings");
  require_at_least(max_linearizations, 1, "max_linearizations");
  require_unit_from_zero(linearized_ftol_initial, "linearized_ftol_initial");
  require_non_negative(model_ftol_rel, "model_ftol_rel");
  require_at_least(max_evaluations, 1, "max_evaluations");
  require_non_negative(ftol_rel, "ftol_rel");
  require_non_negative(xtol_abs, "xtol_abs");
  require_non_negative(time_limit_s, "time_limit_s");
  if (constraint == ConstraintMode::hard && solver == ControlSolver::lbfgs)
    bad_option("solver",
               "lbfgs cannot take the hard-constraint mode (constraint = hard): use "
               "slsqp, mma, cobyla or ipopt");
}

}  // namespace pbve
