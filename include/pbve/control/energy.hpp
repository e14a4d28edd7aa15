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

/// sum_b sqrt(|x_b|^2 + eps_b^2) - eps_b over consecutive blocks x_b of `block` entries of x
/// (x.size() = eps.size() * block). `gradient` (optional) receives d/dx, same size as x.
double smoothed_norm_sum(const Eigen::VectorXd& x, int block, const Eigen::VectorXd& eps,
                         Eigen::VectorXd* gradient);

}  // namespace pbve
