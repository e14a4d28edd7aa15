#pragma once
/// @file
/// The Simulator seam: the interface every physics engine adapter implements.
///
/// The optimizer treats the engine as a black box (paper section 3.2). An adapter exposes
/// the **surface vertices** the visibility energy sees (input-mesh vertex order, camera
/// frame, metres), a **control space** (a force per vertex, or a force + torque per rigid
/// body), **anchors** whose positions are prescribed each step, exact **save/restore**,
/// **clone**, and optionally **derivatives** (vector-Jacobian products of one step).

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "pbve/core/mesh.hpp"

namespace pbve {

/// What a control block acts on.
enum class ControlSpace {
  vertex_force,  ///< one 3-D force per surface vertex (deformables); anchored blocks are ignored
  body_wrench,   ///< one force + torque (6 numbers) per rigid body, applied at its centre of mass
};

/// Layout of the control vector u passed to Simulator::step().
///
/// u has `num_blocks * block_size()` entries; block b occupies u[b*k .. b*k + k - 1] with
/// k = 3 (force, newtons) or 6 (force in newtons, then torque in newton-metres), camera frame.
struct ControlLayout {
  ControlSpace space = ControlSpace::vertex_force;
  int num_blocks = 0;          ///< surface vertices (vertex_force) or bodies (body_wrench)
  Eigen::VectorXd block_mass;  ///< kg: mass of the vertex / body each block acts on
  /// body_wrench only, optional: each body's lever arm in metres (e.g. its radius of gyration
  /// about the centre of mass). The optimizer counts a torque tau as a force |tau| / arm and
  /// scales it by m_b g0 arm. Empty: ControlOptions::torque_arm for every body.
  Eigen::VectorXd block_arm;
  std::vector<int> vertex_block;  ///< per surface vertex: the block that moves it (-1: none)

  int block_size() const { return space == ControlSpace::vertex_force ? 3 : 6; }
  int size() const { return num_blocks * block_size(); }
};

/// A complete snapshot of a simulator's dynamic state (opaque; adapter-defined layout).
/// Restoring it and stepping again must replay bit for bit.
struct SimState {
  std::vector<double> values;
  std::vector<std::uint8_t> bytes;  ///< for adapters that need raw engine data
};

/// Input of one step (one frame interval; substeps are the adapter's business).
struct StepInput {
  double dt = 1.0 / 30.0;   ///< seconds
  Eigen::VectorXd control;  ///< size ControlLayout::size(), or empty for zero control
  /// Positions of the anchors (#anchors by 3, order of Simulator::anchors()) at the end of
  /// the step, camera frame; linearly interpolated from their current positions across
  /// substeps. Empty: anchors stay where they are. Build it from the simulator's anchors(),
  /// which may differ from the ids an adapter was given (mass_spring's single sheet anchors
  /// the sheet nodes that carry them).
  Vertices anchor_targets;
};

/// Result of Simulator::step_vjp(): gradients of a scalar L with respect to the inputs of
/// one step, given its gradient with respect to the step's output state.
struct StepVjp {
  Eigen::VectorXd state;    ///< dL/d(state before the step), size Simulator::state_dim()
  Eigen::VectorXd control;  ///< dL/du, size ControlLayout::size()
};

/// The linearization of one step at a point (the step taken from a state `before` with an
/// input `in`): its Jacobian with respect to the state before the step and the control,
/// applied forward (jvp) and transposed (vjp). Made by Simulator::linearize_step(); holds what
/// it needs (e.g. factorizations), so many products cost far less than as many steps. An
/// optimizer uses it to search on the linearized dynamics between true steps.
class StepLinearization {
 public:
  virtual ~StepLinearization() = default;
  /// Tangent of the state after the step, d s1 = (ds1/ds0) d_state_before + (ds1/du) d_control
  /// (sizes Simulator::state_dim() and ControlLayout::size(); either may be empty for zero).
  virtual Eigen::VectorXd jvp(const Eigen::VectorXd& d_state_before,
                              const Eigen::VectorXd& d_control) = 0;
  /// The transpose: given g = dL/ds1, dL/ds0 and dL/du (what Simulator::step_vjp() returns).
  virtual StepVjp vjp(const Eigen::VectorXd& d_state_after) = 0;
  /// Simulator::position_tangent() at the state after the step: the tangent of the surface
  /// positions (#V by 3) along a tangent of that state (empty for zero).
  virtual Vertices position_tangent(const Eigen::VectorXd& d_state_after) const = 0;
  /// Simulator::position_cotangent() at the state after the step (its transpose).
  virtual Eigen::VectorXd position_cotangent(const Vertices& d_positions_after) const = 0;
};

/// The abstract physics engine interface.
///
/// Contract (checked by the conformance suite, include/pbve/testing/simulator_conformance.hpp):
/// - positions() returns num_vertices() rows in input-mesh order, camera frame, metres;
/// - after step(), anchors are exactly at their targets;
/// - restore(save()) followed by the same steps reproduces positions bit for bit;
/// - clone() is independent and steps identically;
/// - a force f on a free block of mass m accelerates it by f / m;
/// - wrong sizes throw std::invalid_argument; a legal step never produces NaN;
/// - a simulator and its clones share no mutable state: each may be stepped on its own thread
///   at the same time as the others (the optimizer steps clones in parallel).
class Simulator {
 public:
  virtual ~Simulator() = default;

  /// Short engine name, e.g. "mass_spring".
  virtual std::string name() const = 0;

  /// Number of surface vertices (rows of positions()).
  virtual int num_vertices() const = 0;
  /// Surface vertex positions, #V by 3, camera frame, metres.
  virtual Vertices positions() const = 0;
  /// Surface vertex velocities, #V by 3, metres per second.
  virtual Vertices velocities() const = 0;

  /// Layout of the control vector.
  virtual ControlLayout control_layout() const = 0;

  /// Indices of anchored surface vertices (sorted). Anchored vertices are moved only by
  /// their targets, never by the engine.
  virtual std::vector<int> anchors() const = 0;

  /// Advances the simulation by in.dt with the control held constant over the step.
  /// Throws std::invalid_argument on wrong sizes or dt <= 0.
  virtual void step(const StepInput& in) = 0;

  /// Forces other than the control acting on the surface vertices during the last step
  /// (#V by 3, newtons: gravity, internal/elastic, damping, contact), averaged over the
  /// substeps — the "physical force" the report compares control forces against.
  /// Zero rows for anchored vertices.
  virtual Vertices physical_forces() const = 0;

  /// Per surface vertex (#V), the sum of the norms of the external forces (gravity, contact)
  /// and of the internal ones (elastic, damping) acting on it during the last step, averaged
  /// over the substeps, newtons; zero for anchored vertices. This is the report's
  /// `physical_force` (the scale control forces are compared with): unlike the norm of the
  /// net force it does not vanish when the forces balance, e.g. a cloth hanging at rest has
  /// 2 m g per vertex. The default returns the row norms of physical_forces(); engines that
  /// know their force terms override it.
  virtual Eigen::VectorXd physical_force_magnitudes() const {
    return physical_forces().rowwise().norm();
  }

  /// Complete dynamic state.
  virtual SimState save() const = 0;
  /// Restores a state made by save() of this simulator or of a clone.
  virtual void restore(const SimState& state) = 0;
  /// Independent copy in the same state.
  virtual std::unique_ptr<Simulator> clone() const = 0;

  // ----- optional derivatives ---------------------------------------------------------

  /// True when state_dim(), position_cotangent() and step_vjp() are implemented.
  virtual bool has_derivatives() const { return false; }
  /// Size of the differentiable state vector (adapter-defined; e.g. positions and velocities
  /// of all nodes).
  virtual int state_dim() const;
  /// The state cotangent corresponding to a cotangent on positions() (#V by 3): for
  /// L(positions(state)), returns dL/dstate given dL/dpositions, at the current state (the map
  /// from state to positions may be nonlinear, e.g. surface vertices that follow a sheet).
  virtual Eigen::VectorXd position_cotangent(const Vertices& d_positions) const;
  /// The transpose of position_cotangent(): the tangent of positions() (#V by 3) along a state
  /// tangent d_state (state_dim() entries) at the current state.
  virtual Vertices position_tangent(const Eigen::VectorXd& d_state) const;
  /// Vector-Jacobian product of one step: the step taken from `before` with `in` maps state
  /// s0 to s1; given g = dL/ds1, returns dL/ds0 and dL/du. Leaves this simulator in an
  /// unspecified state (callers restore()).
  virtual StepVjp step_vjp(const SimState& before, const StepInput& in,
                           const Eigen::VectorXd& d_state_after);

  /// True when linearize_step() is implemented (implies has_derivatives()).
  virtual bool has_linearization() const { return false; }
  /// The linearization of the step taken from `before` with `in` (see StepLinearization):
  /// independent of this simulator afterwards. Leaves this simulator in an unspecified state
  /// (callers restore()).
  virtual std::unique_ptr<StepLinearization> linearize_step(const SimState& before,
                                                            const StepInput& in);
};

/// Checks the sizes and indices pbve relies on beyond the types (the editor and
/// ControlOptimizer call it before using an engine): positions() and velocities() have
/// num_vertices() rows; anchors() are sorted, distinct surface vertices; the control layout has
/// block_mass (and block_arm, unless empty) with one entry per block and vertex_block with one
/// entry per surface vertex, each -1 or a block. Throws std::logic_error naming the engine and
/// the first violation.
void check_simulator(const Simulator& sim);

/// sim.physical_force_magnitudes(), checked to have one entry per surface vertex, none
/// negative (throws std::logic_error naming the engine otherwise).
Eigen::VectorXd checked_force_magnitudes(const Simulator& sim);

}  // namespace pbve
