#pragma once
// The immutable part of a mass-spring simulator: nodes, masses, springs, anchors and the
// sparsity pattern of the free-free system matrix (shared between clones).

#include <array>
#include <memory>
#include <optional>
#include <vector>

#include <Eigen/Core>
#include <Eigen/SparseCore>

#include "cholesky.hpp"
#include "factor.hpp"
#include "multigrid.hpp"
#include "pbve/core/mesh.hpp"
#include "pbve/core/thin_sheet.hpp"
#include "pbve/mass_spring/mass_spring.hpp"

namespace pbve::mass_spring::detail {

struct Spring {
  int a = 0, b = 0;   // node ids
  double rest = 0.0;  // rest length, m
  double k = 0.0;     // stiffness, N/m
  // Isotropic linear coupling, N/m: adds 1/2 iso |x_b - x_a|^2 to the energy. Carries the
  // quadratic bending energy of flat hinges; may be negative (each hinge's sum is PSD).
  double iso = 0.0;
};

struct Model {
  Params params;
  int num_surface = 0;
  int num_nodes = 0;
  Eigen::VectorXd mass;  // per node, kg
  Eigen::VectorXd rest;  // 3 * num_nodes rest positions (surface + lattice)
  std::vector<Spring> springs;
  // Per node (3 * num_nodes, or empty): the quadratic bending force of the rest shape, which
  // the flat-hinge bending energy subtracts so the rest shape is at equilibrium.
  Eigen::VectorXd bend_rest_force;
  int flat_hinges = 0;          // hinges with the quadratic bending energy (the rest: springs)
  std::vector<int> anchors;     // sorted surface vertex ids
  std::vector<int> free_index;  // per node: free block index, or -1 for anchors
  std::vector<int> free_nodes;  // free block -> node
  double char_length = 1.0;     // mean rest edge length of the surface, m
  int layer_ties = 0;           // springs tying the two layers of a thin closed cloth

  // Free-free system matrix pattern (3 * #free square, both triangles stored, 3x3 blocks).
  Eigen::SparseMatrix<double> pattern;
  // For a block (r, c), offset[j] = index into valuePtr() of entry (3r, 3c + j); rows 3r+1,
  // 3r+2 follow. Diagonal blocks per free block, off-diagonal (a,b) and (b,a) per spring
  // (-1 when an end is anchored).
  std::vector<std::array<int, 3>> diag_offset;
  std::vector<std::array<int, 6>> spring_offset;
  // Per free block f, the springs with an end at f in increasing spring order: entries
  // incident_start[f] .. incident_start[f + 1] - 1 of incident_spring, and incident_column[k],
  // the index (0 or 3) into the spring's spring_offset of its off-diagonal block in f's columns
  // (-1 when the other end is anchored). Lets each block column be assembled on its own.
  std::vector<int> incident_start, incident_spring, incident_column;
  // Symbolic analysis of `pattern` for the sparse Cholesky factorizations, made on first use
  // and shared by every clone.
  std::shared_ptr<SharedCholeskyAnalysis> cholesky = std::make_shared<SharedCholeskyAnalysis>();
  // Factorizations of that pattern for reuse (step linearizations), shared by every clone.
  std::shared_ptr<FactorPool> factor_pool = std::make_shared<FactorPool>();
  // Multigrid hierarchy of `pattern` (LinearSolver::multigrid), made on first use and shared by
  // every clone.
  std::shared_ptr<SharedMultigridHierarchy> multigrid =
      std::make_shared<SharedMultigridHierarchy>();
};

/// The sheet of a thin closed cloth (Params::single_sheet), or nothing when the surface does not
/// split into one layer and the rest, or the input is invalid (build_model() reports that).
std::optional<ThinSheet> thin_sheet_of(const Mesh& mesh, const Vertices& positions,
                                       const std::vector<int>& anchors, const Params& params);
/// Total triangle area, m^2.
double surface_area(const Vertices& positions, const Triangles& triangles);

/// Builds the model; throws std::invalid_argument on bad input.
Model build_model(const Mesh& mesh, const Vertices& positions, std::vector<int> anchors,
                  const Params& params);

}  // namespace pbve::mass_spring::detail
