#include "pbve/sim/simulator.hpp"

#include <stdexcept>

namespace pbve {

namespace {
[[noreturn]] void no_derivatives(const Simulator& sim, const char* what) {
  throw std::logic_error(sim.name() + " does not offer derivatives (" + what + ")");
}
}  // namespace

int Simulator::state_dim() const {
  no_derivatives(*this, "state_dim");
}

Eigen::VectorXd Simulator::position_cotangent(const Vertices&) const {
  no_derivatives(*this, "position_cotangent");
}

Vertices Simulator::position_tangent(const Eigen::VectorXd&) const {
  no_derivatives(*this, "position_tangent");
}

StepVjp Simulator::step_vjp(const SimState&, const StepInput&, const Eigen::VectorXd&) {
  no_derivatives(*this, "step_vjp");
}

std::unique_ptr<StepLinearization> Simulator::linearize_step(const SimState&, const StepInput&) {
  no_derivatives(*this, "linearize_step");
}

}  // namespace pbve
