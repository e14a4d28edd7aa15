#pragma once
/// @file
/// The energy of one frame (paper section 3.3): E = lC EC + lF EF + lT ET.
///
/// Pure functions on Eigen types, no simulator: the control layer chains the position gradient
/// through the simulation.
///
/// Notation: "constrained" triangles are those not observed in the input frame (v_j = 0) and
/// not interior; only they enter EC. The facing value s_j = <n_j, c_j> / (|n_j| |c_j|) is
/// negative when triangle j faces the camera (see visibility.hpp).

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "pbve/core/mesh.hpp"
#include "pbve/visibility/visibility.hpp"

namespace pbve {

/// #N by k per-entity control vectors (k = 3 for per-vertex forces; the rows are whatever
/// control entities the simulator exposes, the norm is taken per row).
using ForceMatrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

/// Constrained mask, #F: 1 where observed_in_input is 0 and interior is 0. `interior` may be
/// empty (no interior faces). Throws InputError on size mismatch.
std::vector<std::uint8_t> constrained_triangles(const std::vector<std::uint8_t>& observed_in_input,
                                                const std::vector<std::uint8_t>& interior);

// ---------------------------------------------------------------------------------------------
// EC, exact (paper eq. 2)

/// Value and parts of the exact, binary visibility energy.
struct ExactVisibilityEnergy {
  /// EC = sum over violating triangles of a_j / A (dimensionless, in [0, 1]).
  double value = 0.0;
  int violating_count = 0;         ///< triangles with v_j = 0, v_j^S = 1, not interior
  double violating_area_px = 0.0;  ///< sum of a_j over violating triangles, pixels^2
  /// A: the projected area of all triangles visible in the simulated state (pixels^2), i.e.
  /// the visible object area measured per triangle. With this A, EC is the fraction of the
  /// visible object that violates, the metric's measure in per-triangle form.
  double total_area_px = 0.0;
};

/// EC = sum_j delta(v_j^S, 1 - v_j) a_j / A, a_j = simulated.projected_area_px[j] and A as in
/// ExactVisibilityEnergy::total_area_px. Interior triangles never violate.
/// @param observed_in_input #F, v_j
/// @param simulated         visibility of the simulated state (v_j^S and a_j)
/// @param interior          #F or empty
ExactVisibilityEnergy visibility_energy_exact(const std::vector<std::uint8_t>& observed_in_input,
                                              const TriangleVisibility& simulated,
                                              const std::vector<std::uint8_t>& interior);

// ---------------------------------------------------------------------------------------------
// EC, smooth

/// Shape of the smooth penalty phi(s) on the facing value s of a constrained triangle.
enum class SmoothPenalty {
  /// phi(s) = max(0, mu - s)^2: zero while the triangle faces away by more than the margin,
  /// growing quadratically as it turns towards the camera (C1, kink of the second derivative
  /// at s = mu).
  quadratic,
  /// Clamped log barrier phi(s) = -(s - mu)^2 log(s / mu) for s_floor < s < mu, 0 for s >= mu
  /// (C2 at mu), continued below s_floor by its second-order Taylor expansion at s_floor so
  /// that it stays finite for triangles that already face the camera.
  log_barrier,
};

/// Settings of the smooth visibility term.
struct SmoothVisibilityOptions {
  SmoothPenalty penalty = SmoothPenalty::quadratic;
  /// Margin mu > 0 on the facing value (dimensionless, s in [-1, 1]).
  double margin = 0.05;
  /// s_floor of the log barrier, as a fraction of the margin (0 < value < 1).
  double barrier_floor = 0.01;
};

/// Penalty phi(s) and its derivatives (exposed for tests and solvers).
struct PenaltyValue {
  double value = 0.0, d1 = 0.0, d2 = 0.0;
};
PenaltyValue smooth_penalty(double s, const SmoothVisibilityOptions& options);

/// Value and gradient of the smooth term.
struct SmoothVisibilityEnergy {
  double value = 0.0;
  /// #V by 3, dEC/dx (per mesh unit); zero rows for vertices of unconstrained triangles.
  Vertices gradient;
  int active_count = 0;  ///< constrained triangles with a non-zero penalty
};

/// EC_smooth = sum over constrained j of w_j phi(s_j), with the analytic gradient with respect
/// to every vertex position.
///
/// @param vertices    #V by 3, camera frame
/// @param triangles   #F by 3
/// @param constrained #F, 1 for triangles entering the term (see constrained_triangles())
/// @param weights     #F, w_j >= 0, treated as constants (not differentiated); e.g.
///                    area_weights() of the input-frame mesh
///
/// Triangles hidden in the input by occlusion while front-facing have s_j < 0 there already;
/// the facing penalty is then a proxy that pushes them to turn away. Pass a mask without them
/// to leave them alone.
SmoothVisibilityEnergy visibility_energy_smooth(const Vertices& vertices,
                                                const Triangles& triangles,
                                                const std::vector<std::uint8_t>& constrained,
                                                const Eigen::VectorXd& weights,
                                                const SmoothVisibilityOptions& options = {});

/// w_j = area_j / sum_k area_k (3-D triangle areas), #F; the constant weights suggested for
/// the smooth term (evaluate them on the input-frame mesh).
Eigen::VectorXd area_weights(const Vertices& vertices, const Triangles& triangles);

/// Facing value s of triangle (a, b, c) and its gradients ds/da, ds/db, ds/dc; all zero for
/// a degenerate triangle or a centroid at the origin.
struct FacingGradient {
  double s = 0.0;
  Eigen::Vector3d da = Eigen::Vector3d::Zero(), db = Eigen::Vector3d::Zero(),
                  dc = Eigen::Vector3d::Zero();
};
FacingGradient facing_gradient(const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                               const Eigen::Vector3d& c);

// ---------------------------------------------------------------------------------------------
// EF, ET (paper eqs. 3, 4) with smoothed norms

/// Value and gradient of a force term.
struct ForceEnergy {
  double value = 0.0;
  ForceMatrix gradient;  ///< same shape as the forces
};

/// EF = sum_i (sqrt(|f_i|^2 + eps^2) - eps): the paper's sum of norms, smoothed at 0 (the
/// error is below eps per row). `forces` #N by k, eps > 0 in force units.
ForceEnergy force_energy(const ForceMatrix& forces, double eps);

/// ET = sum_i (sqrt(|f_i - f~_i|^2 + eps^2) - eps), f~ the previous frame's forces (same shape).
/// The gradient is with respect to `forces`.
ForceEnergy temporal_energy(const ForceMatrix& forces, const ForceMatrix& previous_forces,
                            double eps);

// ---------------------------------------------------------------------------------------------
// E (paper eq. 1)

/// Weights and smoothing of the frame energy.
struct EnergyWeights {
  double visibility = 1.0;  ///< lC
  double force = 1e-3;      ///< lF
  double temporal = 1e-3;   ///< lT
  double force_eps = 1e-6;  ///< eps of the smoothed norms, force units
  SmoothVisibilityOptions smooth;
};

/// E = lC EC_smooth + lF EF + lT ET for one frame, with gradients.
struct FrameEnergy {
  double value = 0.0;
  double visibility = 0.0;      ///< EC_smooth (unweighted)
  double force = 0.0;           ///< EF (unweighted)
  double temporal = 0.0;        ///< ET (unweighted)
  Vertices gradient_positions;  ///< dE/dx, #V by 3
  ForceMatrix gradient_forces;  ///< dE/df, #N by k
};

/// The weighted frame energy; see visibility_energy_smooth(), force_energy() and
/// temporal_energy() for the arguments. `previous_forces` may be empty (0 rows): ET is then
/// measured against zero forces.
FrameEnergy frame_energy(const Vertices& vertices, const Triangles& triangles,
                         const std::vector<std::uint8_t>& constrained,
                         const Eigen::VectorXd& weights, const ForceMatrix& forces,
                         const ForceMatrix& previous_forces, const EnergyWeights& energy_weights);

}  // namespace pbve
