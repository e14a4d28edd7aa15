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

StepVjp Simulator::step_vjp(const SimState&, const StepInput&, const Eigen::VectorXd&) {
  no_derivatives(*this, "step_vjp");
}

}  // namespace pbve
