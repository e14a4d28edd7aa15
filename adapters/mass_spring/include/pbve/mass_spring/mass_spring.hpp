#pragma once
/// @file
/// pbve::mass_spring — the built-in physics engine: implicit (backward Euler) mass-spring
/// models for cloth, elastic solids and nearly rigid ("stiff") solids, with exact
/// vector-Jacobian products of a step (adjoint method).
///
/// Equations of motion (paper section 3.1): \f$ M\ddot x + C\dot x - f_{int}(x) = f_{ext} \f$
/// with lumped masses M and Rayleigh damping \f$ C = \alpha M + \beta K \f$. Each substep of
/// length h solves the backward Euler equations
/// \f[ M(v' - v) = h\,(f_{int}(x') + f_c(x') - C(x) v' + m g + u),\quad x' = x + h v' \f]
/// for x' with Newton's method (line search, tolerance Params::newton_tolerance; the exact
/// Hessian while it is positive definite, else the Hessian with the negative stiffness of
/// compressed springs across their axis dropped, plus a step along the negative curvature of
/// the exact Hessian that conjugate gradients met, after which the exact one is tried again:
/// Newton on the projected Hessian alone would converge, slowly, to a saddle of the incremental
/// potential where a symmetric configuration puts one. Conjugate gradients see only the
/// directions that their right sides reach, so an exactly symmetric configuration, e.g. a
/// perfectly flat sheet compressed in its plane, may stay on its saddle with the iterative and
/// multigrid solvers; the direct solver probes with a pseudo-random right side), where
/// K(x) in the damping term is the axial spring stiffness \f$\sum_s k_s u_s u_s^T\f$ (the exact
/// stiffness at rest, always positive semi-definite) evaluated at the start of the substep;
/// its position derivative is part of the adjoint, so step_vjp() is exact. Newton starts from
/// x + h v, or within a step from x + h v + h (v - v_prev) (the previous substep's acceleration
/// carried on) where that has the lower incremental potential; the start changes the result
/// only within the Newton tolerance and depends on the step's input only, so replays are exact.
///
/// Units are SI throughout: metres, kilograms, seconds, newtons, camera frame.

#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "pbve/core/mesh.hpp"
#include "pbve/sim/simulator.hpp"

namespace pbve::mass_spring {

/// Material model families.
enum class Material {
  cloth,    ///< surface only: stretch and shear springs and hinge bending on the triangle mesh
  elastic,  ///< soft solid: surface springs + an embedded interior lattice (keeps its volume)
  stiff,    ///< nearly rigid solid: like elastic with a finer, much stiffer lattice
};

/// Parses "cloth", "elastic" or "stiff"; throws std::invalid_argument otherwise.
Material material_from_string(const std::string& name);
/// The lowercase name of a material.
std::string to_string(Material m);

/// Linear solver of the Newton and adjoint systems (sparse, symmetric).
enum class LinearSolver {
  automatic,  ///< direct up to Params::direct_solver_max_dofs free unknowns, multigrid above
  /// sparse LL^T (CHOLMOD supernodal, pattern analyzed once and shared by clones), factorized
  /// about once per substep: later Newton iterations and substeps run conjugate gradients
  /// preconditioned by that factorization, and factorize again only if those stall
  direct,
  /// conjugate gradients with a 3x3 block-Jacobi preconditioner (no factorization: least
  /// memory, but the iteration count grows with the resolution)
  iterative,
  /// conjugate gradients preconditioned by one algebraic multigrid V-cycle (coarse levels built
  /// once per model from the springs and the rest positions: C/F splitting with linear
  /// interpolation, smoothed aggregation where that does not coarsen; the coarse matrices
  /// formed once per substep): setup and iterations do work linear in the number of nodes
  /// (the iteration count grows where the cloth's bending outweighs inertia at the grid scale:
  /// x1.25 from 4k to 16k vertices of the bench cloth, x1.6 from 16k to 65k), and a finest
  /// level of 2048 nodes or more, a coarser one of 1024 or more, is smoothed by two threads,
  /// as are the Galerkin products and restrictions from such a level (same results with any
  /// number of threads).
  /// Indefinite adjoint systems (exact Hessian of compressed springs) run MINRES
  /// preconditioned by the multigrid of the projected Hessian. Measured (docs/benchmarks.md,
  /// mass_spring): a cloth step 2.3x faster than `direct` at 1k vertices, 6.2x at 4k, 6.4x at
  /// 16k; about as fast on example 1's thin board, whose two layers are tied
  /// (layer_stiffness > 0)
  multigrid,
};

/// A collision plane: nodes are kept on the side `normal` points to (penalty contact with
/// regularized Coulomb friction).
struct Plane {
  Eigen::Vector3d point = Eigen::Vector3d::Zero();     ///< a point on the plane, metres
  Eigen::Vector3d normal = Eigen::Vector3d(0, -1, 0);  ///< towards the free side (normalized)
  double friction = 0.5;                               ///< Coulomb coefficient, >= 0
};

/// A box of a solid with its own lattice stiffness (a soft belly in a stiffer body, say).
struct StiffnessRegion {
  /// Corners of the box in mesh coordinates (the vertices of the mesh given to the
  /// simulator; its rest positions when the mesh has none), min <= max in every coordinate.
  Eigen::Vector3d min = Eigen::Vector3d::Zero();
  Eigen::Vector3d max = Eigen::Vector3d::Zero();
  /// Lattice stiffness inside the box, Pa (> 0); replaces Params::volume_stiffness there.
  double volume_stiffness = 0.0;
};

/// Physical and numerical parameters. Params::preset() fills every field for a material;
/// each field may then be overridden.
///
/// Spring constants are derived from resolution-independent moduli: a spring of rest length
/// L0 standing for an area A (cloth: a third of each adjacent triangle) or a volume V
/// (lattice) gets k = modulus * A / L0^2 (N/m) or k = modulus * V / L0^2, so refining the mesh
/// does not change the material's response to first order.
struct Params {
  Material material = Material::cloth;
  /// Cloth: areal density, kg/m^2 (lumped mass = density * area / 3 per triangle corner).
  /// Solids: volumetric density, kg/m^3 (total mass = density * enclosed volume).
  double density = 0.3;
  /// Membrane stretch modulus of the edge springs, N/m (Young's modulus times thickness).
  double stretch_stiffness = 2000.0;
  /// Shear modulus of the springs across the two opposite vertices of each pair of adjacent
  /// triangles, N/m (0 disables them unless bend_stiffness > 0).
  double shear_stiffness = 100.0;
  /// Bending modulus B, N*m. A hinge (interior edge) whose two triangles are flat at rest
  /// (dihedral angle up to 1e-3 rad) bends by the quadratic energy of isometric surfaces
  /// (Bergou et al. 2006): B / (2 (A0 + A1)) |sum_i K_i x_i|^2 over its four vertices, K the
  /// cotangent weights of the rest hinge, A0 and A1 its triangles' areas. It tends to
  /// 1/2 B (k1 + k2)^2 per unit area (1/2 B k^2 on a cylinder of curvature k), is zero on every
  /// flat shape, and its value at the rest shape is subtracted so a nearly flat rest shape is
  /// at equilibrium. A creased hinge instead adds B / L0^2 to the spring across it (L0: rest
  /// distance of the two opposite vertices), an approximate bending that only stiffens as the
  /// angle grows (no stiffness at the rest angle).
  double bend_stiffness = 1e-4;
  /// Cloth: stiffness modulus of the ties between the two layers of a thin closed surface, N/m
  /// (0 disables them). A board or a thick sheet made into cloth is two layers joined at the
  /// rim; with no self-collision they would drift through each other (the back layer showing
  /// through the front). Each vertex is tied to the nearest vertex of the opposite layer (a
  /// vertex within layer_distance behind it whose normal points the other way) by a spring of
  /// k = layer_stiffness * vertex area / L0^2. The ties keep the layers' distance, not their
  /// alignment, so the layers still slide over each other and bending stays soft.
  double layer_stiffness = 100.0;
  /// Cloth: largest distance between the two layers of a thin closed surface (for the sheet and
  /// for the ties), metres; 0 uses pbve::default_layer_reach(): the mean rest edge length, or
  /// for a thin closed board whose faces lie farther apart, that length doubled until facing
  /// vertices lie within it (at most 5% of the bounding box's diagonal), so that a board's layers
  /// are found however finely it is meshed.
  double layer_distance = 0.0;
  /// Cloth: simulate a thin closed surface (a board: two layers within layer_distance joined
  /// by a rim, pbve::make_thin_sheet()) as one sheet, 1 (default), or as two tied layers, 0.
  /// The sheet's nodes are the vertices of one layer; the other layer and the rim follow it at
  /// their rest offsets in a frame that turns with it (pbve::attached_position()), so the
  /// layers cannot pass through each other. The sheet carries the whole surface's mass (its
  /// density is scaled by surface area / sheet area); anchoring a vertex that follows the
  /// sheet anchors the nodes that carry it. Surfaces that do not split so use the layer ties.
  int single_sheet = 1;
  /// Solids: Young's-modulus-like stiffness of the interior lattice and of the ties between
  /// surface vertices and the lattice, Pa. Unused for cloth.
  double volume_stiffness = 0.0;
  /// Solids: lattice spacing, metres; 0 chooses it from the enclosed volume (about 150 interior
  /// nodes for elastic, 200 for stiff). Unused for cloth.
  double lattice_spacing = 0.0;
  /// Solids: boxes with their own volume_stiffness. A lattice spring or a surface-to-lattice
  /// tie takes the stiffness of the last region that contains its midpoint at rest (in mesh
  /// coordinates, mapped to the rest positions by the best-fitting similarity transform,
  /// which must fit them to 1e-6 of the mesh's size), else volume_stiffness. Default none.
  std::vector<StiffnessRegion> regions;
  /// Rayleigh mass-proportional damping alpha, 1/s (air drag-like; also damps translation).
  double damping_alpha = 0.5;
  /// Rayleigh stiffness-proportional damping beta, s (damps relative motion along springs).
  double damping_beta = 0.01;
  /// Gravitational acceleration, m/s^2, camera frame (+y is down in the image).
  Eigen::Vector3d gravity{0.0, 9.81, 0.0};
  /// Backward Euler substeps per step(); >= 1.
  int substeps = 10;
  /// Collision planes (default none).
  std::vector<Plane> planes;
  /// Penalty stiffness of plane contact per node, N/m (> 0 when planes are given).
  double contact_stiffness = 1e4;
  /// Friction regularization speed, m/s: below it, friction is viscous (> 0).
  double friction_velocity = 1e-3;
  /// Maximum Newton iterations per substep (>= 1).
  int newton_iterations = 30;
  /// Newton stops when the largest position update falls below newton_tolerance times the
  /// mean rest edge length (> 0), or, after a solve on the exact positive definite Hessian,
  /// when the largest mass-scaled residual |r_i| / m_i does (with a positive semi-definite
  /// stiffness, a bound on the next update in the mass norm; in practice far above it node by
  /// node). Gradients from step_vjp() are exact at the converged point, so their relative
  /// accuracy is about this tolerance; tighten it (e.g. 1e-12) for finite-difference
  /// comparisons.
  double newton_tolerance = 1e-6;
  /// Linear solver choice.
  LinearSolver linear_solver = LinearSolver::automatic;
  /// LinearSolver::automatic uses the direct solver up to this many free unknowns (3 per node)
  /// and the multigrid solver above; 0 means multigrid always. Up to 96 free nodes the
  /// multigrid is one dense LL^T, slower than the sparse one; from 144 vertices on it is the
  /// faster, by 1.4x there, 2.3x at 1k, 4.7x at 4k and 5.7x at 16k on a plain cloth (the
  /// direct solver's cost grows about as n^1.5, the multigrid's about linearly up to 4k
  /// vertices and x5 from 4k to 16k; docs/benchmarks.md, mass_spring), and on example 1's
  /// board and example 2's elastic figurine too.
  int direct_solver_max_dofs = 300;
  /// The same limit for a thin closed cloth whose two layers are tied (layer_stiffness > 0,
  /// single_sheet 0), when larger: the multigrid's aggregates do not follow the ties, and
  /// factorizing is as fast or faster up to 3 022 vertices of example 1's two-layer board
  /// (docs/benchmarks.md).
  int direct_solver_max_dofs_layered = 20000;
  /// Iterative solver: relative residual of the adjoint solves in step_vjp() (> 0).
  double adjoint_tolerance = 1e-11;

  /// Defaults for a material:
  /// - cloth: 0.3 kg/m^2, stretch 2000 N/m, shear 100 N/m, bend 1e-4 N*m, layer ties 100 N/m,
  ///   alpha 0.5, beta 0.01;
  /// - elastic: 1000 kg/m^3, lattice 2e4 Pa, surface stretch 200 N/m, alpha 0.5, beta 0.002;
  /// - stiff: 1000 kg/m^3, lattice 2e7 Pa, surface stretch 2e5 N/m, alpha 0.5, beta 2e-4.
  static Params preset(Material m);

  /// Throws std::invalid_argument naming the first invalid field.
  void validate() const;
};

/// Statistics of the last step().
struct StepStats {
  int substeps = 0;               ///< substeps taken
  int newton_iterations = 0;      ///< Newton iterations summed over substeps
  int factorizations = 0;         ///< sparse factorizations summed over substeps
  int cg_iterations = 0;          ///< conjugate gradient iterations summed over substeps
  int max_newton_iterations = 0;  ///< largest per-substep count
  int curvature_steps = 0;        ///< steps along negative curvature (leaving saddles)
  bool converged = true;          ///< every substep reached the tolerance
};

/// The built-in engine. Nodes are the surface vertices (first, in input-mesh order) followed by
/// interior lattice nodes (solids); for a thin closed cloth simulated as one sheet they are the
/// sheet's nodes (its vertices in ascending order), control blocks are per node
/// (ControlLayout::vertex_block maps every surface vertex to the node that carries it most) and
/// anchors() are the nodes' vertices. The state vector of the derivative API is
/// [x (3 * num_nodes()), v (3 * num_nodes())], node-major, x y z per node.
class MassSpringSimulator final : public Simulator {
 public:
  /// @param mesh       topology (triangles); its vertices are not used
  /// @param positions  #V by 3 rest positions, camera frame, metres; the simulation starts here
  ///                   at zero velocity (rest lengths and masses are measured on them)
  /// @param anchors    anchored surface vertex ids (any order, no duplicates); a thin closed
  ///                   cloth simulated as one sheet anchors the nodes that carry them, so
  ///                   anchors() may list other (and fewer) vertices: build
  ///                   StepInput::anchor_targets from anchors(), not from this list
  /// @param params     physics and numerics (validated)
  /// Throws std::invalid_argument on wrong sizes, out-of-range or duplicate anchors, invalid
  /// parameters, or a solid material on a mesh that encloses no volume.
  MassSpringSimulator(const Mesh& mesh, const Vertices& positions, std::vector<int> anchors,
                      const Params& params);
  /// Same, with the mesh's own vertices as rest positions.
  MassSpringSimulator(const Mesh& mesh, std::vector<int> anchors, const Params& params);
  MassSpringSimulator(const MassSpringSimulator& other);
  MassSpringSimulator& operator=(const MassSpringSimulator& other);
  ~MassSpringSimulator() override;

  std::string name() const override { return "mass_spring"; }
  int num_vertices() const override;
  Vertices positions() const override;
  Vertices velocities() const override;
  ControlLayout control_layout() const override;
  std::vector<int> anchors() const override;
  void step(const StepInput& in) override;
  Vertices physical_forces() const override;
  /// |m g| + |net force - m g - control| per vertex (internal, damping and contact forces
  /// together count as one term), averaged over the substeps.
  Eigen::VectorXd physical_force_magnitudes() const override;
  SimState save() const override;
  void restore(const SimState& state) override;
  std::unique_ptr<Simulator> clone() const override;

  bool has_derivatives() const override { return true; }
  int state_dim() const override;
  Eigen::VectorXd position_cotangent(const Vertices& d_positions) const override;
  Vertices position_tangent(const Eigen::VectorXd& d_state) const override;
  /// Exact VJP through the converged Newton solves (implicit function theorem), one sparse
  /// factorization and solve per substep. When `before` and `in` are bitwise those of the last
  /// step() taken by this object, the recorded trajectory is reused; otherwise the step is
  /// replayed from `before` first.
  StepVjp step_vjp(const SimState& before, const StepInput& in,
                   const Eigen::VectorXd& d_state_after) override;
  bool has_linearization() const override { return true; }
  /// The exact linearization of the step (implicit function theorem at the converged Newton
  /// solves): one sparse factorization of the exact Jacobian per substep up front (the
  /// substeps' in parallel), then each jvp() / vjp() costs one triangular solve pair per
  /// substep (a factor of a million entries or more is solved in two parallel parts of its
  /// elimination tree; the same bits with any number of threads). Reuses the recorded
  /// trajectory like step_vjp(), else replays the step from `before`.
  std::unique_ptr<StepLinearization> linearize_step(const SimState& before,
                                                    const StepInput& in) override;

  /// Surface vertices plus interior lattice nodes (or, for a single sheet, the sheet nodes).
  int num_nodes() const;
  /// The thin closed cloth is simulated as one sheet (Params::single_sheet).
  bool single_sheet() const;
  /// All node positions, num_nodes() by 3, metres.
  Vertices node_positions() const;
  /// Lumped node masses, kg (size num_nodes()).
  Eigen::VectorXd node_masses() const;
  /// Number of springs of the model.
  int num_springs() const;
  /// Parameters in use.
  const Params& params() const;
  /// Statistics of the last step().
  const StepStats& last_stats() const;
  /// Kinetic energy 1/2 v^T M v over all nodes, joules.
  double kinetic_energy() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> m_impl;
};

}  // namespace pbve::mass_spring
