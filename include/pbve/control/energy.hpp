#pragma once
/// @file
/// The smooth terms of the control energy E = lC EC + lF EF + lT ET (paper section 3.3).
///
/// - EC, the visibility term: for every triangle j that must stay unseen (not observed in the
///   input frame, or flagged interior), a barrier on its facing value
///   \f[ s_j = \frac{\langle n_j, c_j \rangle}{|n_j|\,|c_j|}, \f]
///   positive while the triangle turns its back to the camera (the paper's visibility test is
///   s_j < 0). With margin mu and sigma = s_j / mu the per-triangle penalty is
///   \f[ \phi(\sigma) = -(\sigma - 1)^2 \ln \sigma \quad (\sigma_c \le \sigma < 1), \f]
///   zero for sigma >= 1 (C2 there), and below sigma_c its second-order Taylor expansion at
///   sigma_c (convex, finite everywhere, C2), so a start in the violating region still has a
///   well-defined, steep energy: the paper's "soft constraint with barrier functions".
///   EC = sum_j w_j phi(s_j / mu), w_j = area_j / total area (fixed weights, see
///   visibility_weights()).
/// - EF = sum_b rho(f_b), ET = sum_b rho(f_b - f~_b): smoothed norms
///   rho(f) = sqrt(|f|^2 + eps_b^2) - eps_b, differentiable at 0 (paper Eqs. 3 and 4).
///
/// These live here, with analytic gradients checked against central differences in
/// tests/control/test_energy.cpp.

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "pbve/core/mesh.hpp"

namespace pbve {

/// Shape of the visibility barrier (see the file comment).
struct VisibilityBarrier {
  /// mu: facing value (cosine, dimensionless) below which a must-stay-hidden triangle is
  /// penalized. 0.05 is about 3 degrees short of edge-on.
  double margin = 0.05;
  /// sigma_c in (0, 1): the log barrier is used on [sigma_c, 1), its quadratic extension
  /// below.
  double clamp = 0.1;
};

/// The barrier phi(sigma) and, optionally, d phi / d sigma.
double visibility_barrier(double sigma, const VisibilityBarrier& barrier, double* derivative);

/// Facing value s_j of the triangle (a, b, c) (camera at the origin) and, when `grad` is not
/// null, its gradient: rows 0, 1, 2 = d s / d a, d s / d b, d s / d c (1/metres).
/// Returns 0 (gradient 0) for degenerate triangles or a centroid at the camera centre.
double facing_value(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c,
                    Eigen::Matrix3d* grad);

/// Default weights w_j = area_j / sum of areas, #F, from positions `vertices` (#V by 3).
Eigen::VectorXd visibility_weights(const Vertices& vertices, const Triangles& triangles);

/// EC = sum over triangles with penalized[j] != 0 of weights[j] * phi(s_j / margin).
/// vertices: #V by 3, camera frame, metres; penalized, weights: #F. When `gradient` is not
/// null it is resized to #V by 3 and receives dEC / d vertices (1/metres). Dimensionless.
double visibility_energy(const Vertices& vertices, const Triangles& triangles,
                         const std::vector<std::uint8_t>& penalized, const Eigen::VectorXd& weights,
                         const VisibilityBarrier& barrier, Vertices* gradient);

/// The occlusion part of the visibility term: a must-stay-hidden vertex p that lies behind an
/// observed triangle T (on the camera ray through p) must stay behind T's plane. Without it a
/// back layer pushed through the front one (a thin closed surface simulated as cloth has no
/// self-collision) shows its unobserved side although every triangle still faces away.
struct OcclusionPair {
  int vertex = 0;           ///< p
  int triangle = 0;         ///< T, a triangle observed in the input frame
  double rest_depth = 0.0;  ///< depth of p behind T's plane in the reference shape, metres (> 0)
  double weight = 0.0;      ///< w_p, p's share of the surface area (dimensionless)
};

/// h = -<n_T, p - a_T> / rest_depth, n_T = T's unit normal: 1 in the reference shape (and any
/// rigid motion of it), 0 when p reaches T's plane, negative beyond. `grad` (optional) receives
/// dh / d(p, a_T, b_T, c_T), rows 0 to 3 (1/metres). 0 (gradient 0) for a degenerate T.
double occlusion_depth(const Vertices& vertices, const Triangles& triangles,
                       const OcclusionPair& pair, Eigen::Matrix<double, 4, 3>* grad);

/// E_O = sum over pairs of w_p phi(h_p / margin) with the barrier phi of visibility_energy()
/// (barrier.margin is here a fraction of the rest depth, e.g. 0.5: the penalty starts when p
/// has come halfway to T's plane). `gradient` (optional) is resized to #V by 3 and receives
/// dE_O / d vertices (1/metres).
double occlusion_energy(const Vertices& vertices, const Triangles& triangles,
                        const std::vector<OcclusionPair>& pairs, const VisibilityBarrier& barrier,
                        Vertices* gradient);

/// The pairs of one frame: every vertex of a `penalized` triangle that is on no `observed`
/// triangle, paired with the first observed triangle that the ray from the camera (the origin)
/// to it meets at positions `current` (#V by 3, camera frame) — none for a vertex nothing
/// observed hides. rest_depth is measured on `reference` (#V by 3, e.g. the rest shape; any
/// rigid motion of it gives the same), pairs with a rest depth below `min_depth` metres are
/// dropped, weights are vertex area shares on `reference`. penalized, observed: #F.
std::vector<OcclusionPair> occlusion_pairs(const Vertices& current, const Vertices& reference,
                                           const Triangles& triangles,
                                           const std::vector<std::uint8_t>& penalized,
                                           const std::vector<std::uint8_t>& observed,
                                           double min_depth);

/// sum_b sqrt(|x_b|^2 + eps_b^2) - eps_b over consecutive blocks x_b of `block` entries of x
/// (x.size() = eps.size() * block). `gradient` (optional) receives d/dx, same size as x.
double smoothed_norm_sum(const Eigen::VectorXd& x, int block, const Eigen::VectorXd& eps,
                         Eigen::VectorXd* gradient);

}  // namespace pbve
