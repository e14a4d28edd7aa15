#pragma once
/// @file
/// The control-force optimizer (paper section 3.3): every frame, find small control forces
/// that keep the triangles not observed in the input frame turned away from the camera, apply
/// them and step the simulator.
///
/// For a window of W frames t+1 .. t+W (W = 1 by default) the optimizer minimizes
/// \f[ E(u_1..u_W) = \sum_k \lambda_C E_C(x_k) + \lambda_F E_F(u_k) + \lambda_T E_T(u_k - u_{k-1}),
/// \f]
/// x_k the simulated surface positions after step k, u_0 = f~ the forces committed in the
/// previous frame (energy.hpp defines the terms), then commits u_1 (receding horizon) and
/// steps the simulator once.
///
/// Variables. Only the control blocks of the *active set* are optimized (the rest stay
/// zero): by default the blocks moving vertices of must-stay-hidden triangles whose facing
/// value is below `active_band` now or in the predicted step without control, grown by
/// `active_rings` rings of vertex adjacency, plus blocks that carried a force in the previous
/// frame; ActiveSet::all optimizes every free block. Internally each force component is
/// expressed in units of its block's weight m_b * g0 (g0 = 9.80665 m/s^2; torques in units
/// of m_b * g0 * arm_b, arm_b from ControlLayout::block_arm or torque_arm), which makes the
/// problem well scaled for every solver.
///
/// Gradients. The visibility term is differentiated by central differences through
/// Simulator::save()/restore() (any engine; 2 simulations per variable, parallel over
/// clones with TBB and bit-identical to the serial path), by compressed central differences
/// (forces on vertices far enough apart probed together: 2 simulations per variable of one
/// vertex and per colour of a distance colouring of the active vertices, see
/// ControlOptions::difference_rings) or by the adjoint (one forward pass and one chain of
/// Simulator::step_vjp() back through the window) when the simulator offers derivatives.
/// EF and ET have analytic gradients.

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "pbve/control/energy.hpp"
#include "pbve/core/mesh.hpp"
#include "pbve/sim/simulator.hpp"

namespace pbve {

/// Optimization algorithm.
enum class ControlSolver {
  slsqp,   ///< NLopt LD_SLSQP (sequential quadratic programming)
  mma,     ///< NLopt LD_MMA (method of moving asymptotes)
  lbfgs,   ///< NLopt LD_LBFGS (low-storage BFGS)
  cobyla,  ///< NLopt LN_COBYLA (derivative-free; use with the active set on small problems)
  ipopt,   ///< Ipopt interior point with limited-memory Hessian (the paper used KNITRO's)
};

/// How the gradient of the visibility term is obtained.
enum class GradientMode {
  automatic,  ///< adjoint when Simulator::has_derivatives(), compressed differences otherwise
  central,    ///< central differences through save/restore (any simulator)
  /// Central differences with compressed probes (Curtis-Powell-Reid): the response of a
  /// one-frame step to the force on one vertex is taken as zero beyond
  /// ControlOptions::difference_rings rings of vertex adjacency, so the forces on vertices
  /// whose neighbourhoods of that radius do not overlap are perturbed together and each
  /// surface vertex's response is credited to the one of them it is near. An approximation
  /// (what lies beyond the rings is dropped), exact up to rounding for an engine whose
  /// one-frame response is that local. Applies to one force per vertex in one-frame windows;
  /// clusters, body wrenches and longer windows use plain central differences.
  compressed,
  adjoint,  ///< Simulator::step_vjp(); throws std::invalid_argument when not offered
};

/// The mode `mode` resolves to for `sim`: automatic becomes adjoint when the simulator has
/// derivatives, compressed otherwise. Throws std::invalid_argument for adjoint on a simulator
/// without derivatives.
GradientMode resolve_gradient(const Simulator& sim, GradientMode mode);

/// Which control blocks are optimized.
enum class ActiveSet {
  at_risk,  ///< blocks near must-stay-hidden triangles close to turning visible (default)
  all,      ///< every block that moves a free vertex (the paper's formulation)
};

/// Starting point of every frame's optimization.
enum class InitialGuess {
  zero,      ///< f = 0, as the paper (default)
  previous,  ///< the forces committed in the previous frame (warm start)
};

/// How the visibility requirement enters the problem.
enum class ConstraintMode {
  soft,  ///< barrier penalty lC EC in the objective (the paper's choice; default)
  /// Hard inequality s_j >= margin for every at-risk must-stay-hidden triangle, objective
  /// lF EF + lT ET; for comparison only. Needs slsqp, mma, cobyla or ipopt, and uses central
  /// differences for the constraint Jacobian (one probe pair gives every constraint).
  hard,
};

/// Outcome of one frame's optimization.
enum class ControlStatus {
  converged,        ///< a stopping tolerance was met (or nothing needed optimizing)
  iteration_limit,  ///< max_evaluations / max_iterations or the time limit was reached
  failed,           ///< the solver reported a failure; the best point seen is applied
  cancelled,        ///< the cancel hook asked to stop; the best point seen is applied
};

/// Readable name of a status ("converged", ...).
const char* to_string(ControlStatus status);
/// Readable name of a solver ("slsqp", ...); parse_control_solver() is its inverse and throws
/// std::invalid_argument for an unknown name.
const char* to_string(ControlSolver solver);
ControlSolver parse_control_solver(const std::string& name);

/// Weights of the energy terms (the scene file's control.weights); each finite and >= 0.
struct ControlWeights {
  double visibility = 1.0;  ///< lC (EC is dimensionless)
  double force = 1e-3;      ///< lF, per newton of smoothed control force magnitude
  double temporal = 1e-3;   ///< lT, per newton of smoothed force change between frames
};

/// Settings of ControlOptimizer. Defaults follow the paper where it says something.
struct ControlOptions {
  /// Throws InputError naming the first invalid field (key() "ControlOptions::FIELD", e.g.
  /// "ControlOptions::weights.force") and its value: NaN or infinite numbers, negative weights
  /// and tolerances, a barrier margin or clamp outside (0, 1), fd_step, torque_arm or
  /// force_smoothing not positive, counts below their minimum, enumerators out of range, and
  /// the hard-constraint mode with lbfgs. The ranges are given with each field below.
  /// ControlOptimizer calls it wherever it takes options.
  void validate() const;

  ControlWeights weights;
  /// The visibility barrier: margin (a cosine) and clamp each in (0, 1).
  VisibilityBarrier barrier;
  ControlSolver solver = ControlSolver::slsqp;
  GradientMode gradient = GradientMode::automatic;
  ConstraintMode constraint = ConstraintMode::soft;
  InitialGuess initial_guess = InitialGuess::zero;
  /// Frames optimized together (receding horizon; the paper used 10); at least 1.
  int window = 1;

  ActiveSet active_set = ActiveSet::at_risk;
  /// A must-stay-hidden triangle is at risk when its facing value s_j (dimensionless) is below
  /// this in the current state or in a predicted uncontrolled step of the window. Finite; at
  /// most -1 selects no triangle, above 1 every one.
  double active_band = 0.3;
  /// Rings of vertex adjacency added around the vertices of at-risk triangles (>= 0).
  int active_rings = 2;
  /// Reduced control space for vertex forces: 0 (default) optimizes one force per active
  /// block; K > 0 groups the active blocks into at most K spatial clusters (farthest-point
  /// seeds and Lloyd iterations on their current positions) and optimizes one acceleration
  /// per cluster, each block b of cluster c receiving m_b a_c. That is 3K variables per frame
  /// instead of 3 x active blocks: central differences then cost 6K simulations per gradient,
  /// which makes black-box engines practical, at the price of smoother (less sparse) forces.
  /// Ignored for body wrenches (already 6 numbers per body). At least 0.
  int clusters = 0;
  /// Occlusion term of EC (energy.hpp, OcclusionPair): a vertex of a must-stay-hidden triangle
  /// that an observed triangle hides (on the camera ray through it, at the start of the
  /// frame) is penalized when it comes closer to that triangle's plane than this fraction of
  /// its depth behind it in the reference shape (set_reference_shape()). In [0, 1); 0 disables
  /// the term; it needs ControlFrameInput::observed.
  double occlusion_margin = 0.5;
  /// Penalize interior triangles (Mesh::interior) like unobserved ones. Off by default:
  /// interior faces are drawn in a uniform colour, and the pieces of a fracture must open to
  /// show them; the violation metric does not count them either.
  bool penalize_interior = false;

  /// Optional box bound on every control component, in units of the block's weight m_b g0
  /// (torques: m_b g0 arm_b); 0 = unbounded. A bound B limits |f_b| to sqrt(3) B m_b g0.
  /// Finite and >= 0.
  double force_bound = 0.0;
  /// Lever arm (metres, finite and > 0) of body_wrench blocks whose simulator gives none
  /// (ControlLayout::block_arm): torques are scaled by m_b g0 torque_arm and count as the force
  /// |tau| / torque_arm in EF and ET.
  double torque_arm = 0.1;
  /// Smoothing of the norms in EF and ET, in units of the block weight: eps_b = this * m_b g0.
  /// Finite and > 0.
  double force_smoothing = 1e-2;

  /// Central-difference step, relative to the block weight: h_b = fd_step * m_b g0 newtons
  /// (finite and > 0). The default is cbrt(machine epsilon), which balances the O(h^2)
  /// truncation error against the O(eps / h) round-off of central differences.
  double fd_step = 6.0554544523933395e-06;
  /// Run central-difference probes in parallel over simulator clones (TBB). The result is
  /// bit-identical to the serial path.
  bool parallel = true;
  /// Compressed differences (GradientMode::compressed): rings of vertex adjacency (on the
  /// optimizer's triangles) within which a vertex force is assumed to move the surface in one
  /// frame. Vertices probed together are at least 2 * difference_rings + 1 edges apart; a
  /// larger value is more accurate and needs more probes (docs/benchmarks.md measures the
  /// gradient error of each value on Bullet cloth). At least 0.
  int difference_rings = 2;

  /// Search on the linearized dynamics, with adjoint gradients and a simulator that offers
  /// Simulator::linearize_step(), or with (compressed) central differences and a one-frame
  /// window. Each outer iteration linearizes the window at the current controls (one
  /// linearization per frame; with differences, the response of the surface positions to
  /// every variable, estimated by the same probes as one gradient), runs the solver on the
  /// energy of that model (each evaluation and gradient a product with the linearizations
  /// instead of a simulation, at most max_evaluations of them), then simulates the solver's
  /// point: it is kept when it lowers the true energy, else half and a quarter of the move
  /// are tried, and the search stops when none does or the true energy improves by less than
  /// ftol_rel. At most max_linearizations outer iterations. Off: every evaluation simulates
  /// the window. The responses take 3 numbers per variable and per surface vertex (compressed:
  /// per vertex of its rings); when they would exceed 1.25e8 numbers (1 GB), every evaluation
  /// simulates instead.
  bool linearized = true;
  int max_linearizations = 4;  ///< at least 1
  /// Linearized search: it also stops after an outer iteration that lowers the true energy by
  /// less than this fraction of the energy at the initial guess (0 = never). The first outer
  /// iterations remove the violation, which dominates the initial energy; once a move gains
  /// less than 0.1% of it, the next ones only trim the force terms further (example 1:
  /// docs/benchmarks.md, "The linearized search's stop rule"). In [0, 1).
  double linearized_ftol_initial = 1e-3;
  /// Linearized search: relative energy tolerance of the solver on the model (finite and >= 0;
  /// ftol_rel when that is larger).
  double model_ftol_rel = 1e-4;

  /// Stopping: objective evaluations (NLopt) / iterations (Ipopt, at least 1), relative
  /// tolerance on the energy, absolute tolerance on the variables (units of block weight),
  /// wall-clock limit in seconds per frame (0 = none); the last three finite and >= 0.
  int max_evaluations = 200;
  double ftol_rel = 1e-6;
  double xtol_abs = 1e-5;
  double time_limit_s = 0.0;
};

/// What the optimizer needs to know about one frame of the window.
struct ControlFrameInput {
  double dt = 1.0 / 30.0;  ///< seconds (the frame interval)
  /// Anchor positions at the end of the step (Simulator::anchors() order, camera frame);
  /// empty = anchors stay.
  Vertices anchor_targets;
  /// #F, 1 = triangle not observed in this input frame (v_j = 0): it must stay hidden.
  std::vector<std::uint8_t> unobserved;
  /// #F, 1 = triangle observed in this input frame (v_j = 1), or empty (no occlusion term in
  /// this frame; another size is an error). Needed by the occlusion term
  /// (ControlOptions::occlusion_margin): the vertices of must-stay-hidden triangles that
  /// observed ones hide must stay behind them. (Not simply !unobserved: a triangle may be
  /// neither, e.g. unobserved but too close to edge-on to be penalized.)
  std::vector<std::uint8_t> observed;
};

/// Progress reported after every objective evaluation.
struct ControlProgress {
  int evaluations = 0;       ///< objective evaluations so far in this frame
  double energy = 0.0;       ///< energy of the latest evaluation
  double best_energy = 0.0;  ///< lowest energy so far
};

/// Hooks for long runs (either may be empty). `cancel` is polled at every evaluation
/// (NLopt) or iteration (Ipopt).
struct ControlCallbacks {
  std::function<void(const ControlProgress&)> progress;
  std::function<bool()> cancel;
};

/// Per-frame result.
struct ControlFrameResult {
  ControlStatus status = ControlStatus::converged;
  ControlSolver solver = ControlSolver::slsqp;
  bool adjoint = false;  ///< the gradient came from step_vjp (else central differences)
  std::string message;   ///< the solver's own return code / message
  int iterations = 0;  ///< solver iterations (NLopt: objective evaluations; linearized: model ones)
  int evaluations = 0;           ///< objective evaluations (each one simulates the window)
  bool linearized = false;       ///< the search ran on linearized dynamics (linearized option)
  int linearizations = 0;        ///< linearized search: outer iterations
  int model_evaluations = 0;     ///< linearized search: evaluations of the linearized model
  int gradient_evaluations = 0;  ///< gradients computed
  /// Simulations run by central differences (gradients and linearizations), one frame each.
  int probes = 0;
  int active_blocks = 0;  ///< control blocks optimized (per window frame)
  int variables = 0;  ///< optimization variables (active_blocks * block size * W; 3 per cluster)

  /// Energy terms of the committed step (first window frame): EC of the positions after the
  /// step, EF and ET of the committed forces; energy = lC EC + lF EF + lT ET.
  double energy = 0.0;
  double visibility_energy = 0.0;
  double force_energy = 0.0;
  double temporal_energy = 0.0;
  double initial_energy = 0.0;  ///< window energy at the initial guess
  double final_energy = 0.0;    ///< window energy at the solution

  /// Sum over blocks of the control force norm |f_b| (newtons; the force part of wrenches).
  double control_force = 0.0;
  /// Sum over free vertices of Simulator::physical_force_magnitudes() in the committed step (N).
  double physical_force = 0.0;
  /// The committed control vector (ControlLayout::size()).
  Eigen::VectorXd control;

  double total_ms = 0.0;     ///< whole call: active set, solve, final step
  double solve_ms = 0.0;     ///< inside the solver
  double gradient_ms = 0.0;  ///< inside gradient computations
};

/// Energy and gradient of a window at given controls (testing and diagnostics).
struct ControlEnergyEval {
  double energy = 0.0;
  double visibility_energy = 0.0;  ///< sum over the window of EC (before lC)
  double force_energy = 0.0;       ///< sum over the window of EF
  double temporal_energy = 0.0;    ///< sum over the window of ET
  /// dE/du, W * ControlLayout::size() entries (frame-major), newtons^-1; entries of blocks not
  /// in the active set are 0.
  Eigen::VectorXd gradient;
  int probes = 0;  ///< one-frame simulations run by (compressed) central differences
};

/// The per-frame / windowed control-force optimizer. Holds the previous frame's forces (f~)
/// between calls, so use one instance per simulated sequence.
class ControlOptimizer {
 public:
  /// `triangles` (#F by 3, indices of Simulator surface vertices) is the surface the
  /// visibility term sees; `interior` (#F or empty) flags interior triangles.
  /// Throws InputError from ControlOptions::validate() for invalid options.
  ControlOptimizer(Triangles triangles, std::vector<std::uint8_t> interior = {},
                   ControlOptions options = {});

  const ControlOptions& options() const { return m_options; }
  /// Takes new options after ControlOptions::validate() (InputError; the old ones are kept).
  void set_options(const ControlOptions& options);

  /// Optimizes the controls for the frames of `window` (the first is frame t+1; at most
  /// options().window are used, fewer at the end of a sequence) starting from `sim`'s current
  /// state, commits the first frame's forces and steps `sim` once with them. Throws
  /// std::invalid_argument for an empty window or wrong sizes.
  ///
  /// The committed step is not simulated again: `sim` is restored to the state saved right
  /// after that step in the evaluation that found the forces (bit-identical to stepping, by
  /// the save/restore contract). So afterwards sim.physical_forces() may describe another
  /// step of the search; the result's `physical_force` is the committed step's.
  ControlFrameResult step(Simulator& sim, std::span<const ControlFrameInput> window,
                          const ControlCallbacks& callbacks = {});

  /// Steps `sim` once without control (recording f~ = 0) and fills the force and visibility
  /// figures of the result: the uncontrolled baseline.
  ControlFrameResult step_uncontrolled(Simulator& sim, const ControlFrameInput& frame);

  /// Energy and gradient of the window at controls `u` (W * ControlLayout::size(), frame-major;
  /// empty = zero) with the current f~, over the blocks of `active` (empty = every free
  /// block), with the gradient mode `mode` (automatic resolves as in step()). Leaves `sim` in
  /// its state on entry.
  ControlEnergyEval evaluate(Simulator& sim, std::span<const ControlFrameInput> window,
                             const Eigen::VectorXd& u, GradientMode mode,
                             const std::vector<int>& active = {});

  /// Blocks the active-set rule selects for this window from `sim`'s current state (sorted;
  /// leaves `sim` in its state on entry).
  std::vector<int> active_blocks(Simulator& sim, std::span<const ControlFrameInput> window);

  /// The forces committed by the last step() (f~ of the next frame); empty before the first.
  const Eigen::VectorXd& previous_control() const { return m_previous; }
  /// Forgets f~ and the reference shape (start of a new sequence).
  void reset() {
    m_previous.resize(0);
    m_reference.resize(0, 3);
  }
  /// The reference shape of the occlusion term (ControlOptions::occlusion_margin): by default
  /// the simulator's positions at the first step() or step_uncontrolled() after construction
  /// or reset() — the rest state, where the simulation starts. Set it to use another.
  void set_reference_shape(const Vertices& positions) { m_reference = positions; }
  const Vertices& reference_shape() const { return m_reference; }

 private:
  Triangles m_triangles;
  std::vector<std::uint8_t> m_interior;
  ControlOptions m_options;
  Eigen::VectorXd m_previous;
  Vertices m_reference;
  std::vector<std::vector<int>> m_adjacency;

  void capture_reference(const Simulator& sim);

  // active_blocks(); when `predicted` is not null and the rule simulates the window without
  // control (ActiveSet::at_risk), it receives the surface positions after each of its frames,
  // and `first` / `first_physical` the state and physical force magnitudes after the first.
  std::vector<int> select_blocks(Simulator& sim, std::span<const ControlFrameInput> window,
                                 std::vector<Vertices>* predicted, SimState* first,
                                 Eigen::VectorXd* first_physical);
};

}  // namespace pbve
