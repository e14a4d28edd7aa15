#include "pbve/sim/simulator.hpp"

#include <stdexcept>
#include <string>

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

namespace {
[[noreturn]] void broken(const Simulator& sim, const std::string& what) {
  throw std::logic_error("engine '" + sim.name() + "': " + what);
}
}  // namespace

void check_simulator(const Simulator& sim) {
  const int n = sim.num_vertices();
  if (n < 0) broken(sim, "num_vertices() is " + std::to_string(n));
  const auto rows = [&](Eigen::Index r, const char* what) {
    if (r != n)
      broken(sim, std::string(what) + " has " + std::to_string(r) + " rows, num_vertices() " +
                      std::to_string(n));
  };
  rows(sim.positions().rows(), "positions()");
  rows(sim.velocities().rows(), "velocities()");
  const std::vector<int> anchors = sim.anchors();
  for (size_t i = 0; i < anchors.size(); ++i) {
    if (anchors[i] < 0 || anchors[i] >= n)
      broken(sim, "anchors() lists vertex " + std::to_string(anchors[i]) + ", outside 0.." +
                      std::to_string(n - 1));
    if (i > 0 && anchors[i] <= anchors[i - 1])
      broken(sim, "anchors() are not sorted and distinct (" + std::to_string(anchors[i - 1]) +
                      " before " + std::to_string(anchors[i]) + ")");
  }
  const ControlLayout layout = sim.control_layout();
  if (layout.num_blocks < 0)
    broken(sim, "control_layout().num_blocks is " + std::to_string(layout.num_blocks));
  if (layout.block_mass.size() != layout.num_blocks)
    broken(sim, "control_layout().block_mass has " + std::to_string(layout.block_mass.size()) +
                    " entries for " + std::to_string(layout.num_blocks) + " blocks");
  if (layout.block_arm.size() != 0 && layout.block_arm.size() != layout.num_blocks)
    broken(sim, "control_layout().block_arm has " + std::to_string(layout.block_arm.size()) +
                    " entries for " + std::to_string(layout.num_blocks) + " blocks");
  if (layout.vertex_block.size() != static_cast<size_t>(n))
    broken(sim, "control_layout().vertex_block has " + std::to_string(layout.vertex_block.size()) +
                    " entries for " + std::to_string(n) + " surface vertices");
  for (size_t v = 0; v < layout.vertex_block.size(); ++v)
    if (layout.vertex_block[v] < -1 || layout.vertex_block[v] >= layout.num_blocks)
      broken(sim, "control_layout().vertex_block of vertex " + std::to_string(v) + " is " +
                      std::to_string(layout.vertex_block[v]) + ", not -1 or a block below " +
                      std::to_string(layout.num_blocks));
}

Eigen::VectorXd checked_force_magnitudes(const Simulator& sim) {
  Eigen::VectorXd f = sim.physical_force_magnitudes();
  if (f.size() != sim.num_vertices())
    broken(sim, "physical_force_magnitudes() has " + std::to_string(f.size()) +
                    " entries, num_vertices() " + std::to_string(sim.num_vertices()));
  // (Non-finite values are left to the caller's divergence checks: a blown-up simulation is
  // not an adapter bug.)
  for (Eigen::Index v = 0; v < f.size(); ++v)
    if (f[v] < 0.0)
      broken(sim, "physical_force_magnitudes() of vertex " + std::to_string(v) + " is " +
                      std::to_string(f[v]) + " (a sum of norms: >= 0)");
  return f;
}

}  // namespace pbve
