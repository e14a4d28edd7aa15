// The shared adapter conformance suite on pbve::mass_spring: cloth, elastic and stiff, and
// cloth and elastic with the multigrid linear solver.

#include "mass_spring/meshes.hpp"
#include "pbve/core/mesh.hpp"
#include "pbve/edit/synth.hpp"
#include "pbve/mass_spring/mass_spring.hpp"
#include "pbve/testing/simulator_conformance.hpp"

namespace {

using pbve::Vertices;
using pbve::mass_spring::LinearSolver;
using pbve::mass_spring::MassSpringSimulator;
using pbve::mass_spring::Material;
using pbve::mass_spring::Params;
using pbve::testing::ConformanceCase;

// Newton is converged far below the suite's finite-difference step so that central
// differences see the smooth implicit function.
Params tight(Material m) {
  Params p = Params::preset(m);
  p.newton_tolerance = 1e-12;
  p.damping_beta = 1e-4;
  return p;
}

// f = m a probe: a displaced node feels its springs after O(k T^2 / m) and the stiffness
// damping after O(beta k T / m). For the light cloth corner (k ~ 700 N/m, m 1.8e-4 kg) a probe
// of T = 20 x 5e-6 s keeps both near 4% with beta = 1e-4 s (the presets' beta = 0.01 s would
// need T ~ 1e-6 s, where per-substep displacements fall below the resolution of doubles at
// 1 m from the camera). The cases therefore use beta = 1e-4 s.
constexpr double fma_dt = 5e-6;

// The multigrid cases: the 6 x 6 cloth is below the hierarchy's coarsest size (96 nodes), so
// it is one dense level and checks the solver's paths; the elastic ball with its lattice at
// 1.5 cm has 273 free nodes, above that size, so it checks the V-cycle. (A 10 x 10 or 12 x 12 cloth
// fails VjpMatchesCentralDifferences, by 1.3% and 107%, with the direct solver as well, whose
// adjoint agrees with the multigrid one: the suite's input is not smooth enough there for its
// central differences.)
ConformanceCase cloth_case(LinearSolver solver = LinearSolver::automatic) {
  ConformanceCase c;
  c.fma_dt = fma_dt;
  c.name = solver == LinearSolver::multigrid ? "cloth_multigrid" : "cloth";
  c.make = [solver] {
    Params p = tight(Material::cloth);
    p.linear_solver = solver;
    return std::make_unique<MassSpringSimulator>(pbve::test::grid_mesh(6, 0.3),
                                                 std::vector<int>{0, 5}, p);
  };
  return c;
}

ConformanceCase solid_case(Material m, const char* name,
                           LinearSolver solver = LinearSolver::automatic) {
  ConformanceCase c;
  c.name = name;
  c.make = [m, solver] {
    Params p = tight(m);
    p.linear_solver = solver;
    p.lattice_spacing = solver == LinearSolver::multigrid ? 0.015 : 0.03;
    return std::make_unique<MassSpringSimulator>(
        pbve::test::icosphere(1, 0.06, Eigen::Vector3d(0, 0, 1)), std::vector<int>{0}, p);
  };
  // The stiff preset's springs are ~100x stiffer: a 5x shorter probe keeps k T^2 / m and
  // beta k T / m at the same few percent.
  c.fma_dt = m == Material::stiff ? fma_dt / 5 : fma_dt;
  return c;
}

// A thin closed board simulated as one sheet (Params::single_sheet): anchors() are the sheet
// nodes that carry the anchored corner, the other face and the rim follow the sheet.
ConformanceCase board_case() {
  ConformanceCase c;
  c.fma_dt = fma_dt;
  c.name = "thin_board";
  c.make = [] {
    const pbve::Mesh mesh = pbve::refine_mesh(pbve::make_box_mesh(0.2, 0.15, 0.01), 0.05);
    std::vector<int> anchors;
    for (int i = 0; i < mesh.num_vertices(); ++i)
      if (mesh.vertices(i, 1) < 1e-9 && mesh.vertices(i, 0) < -0.09) anchors.push_back(i);
    Vertices x = mesh.vertices;
    x.col(2).array() += 1.0;
    return std::make_unique<MassSpringSimulator>(mesh, x, anchors, tight(Material::cloth));
  };
  return c;
}

INSTANTIATE_TEST_SUITE_P(MassSpring, SimulatorConformance,
                         ::testing::Values(cloth_case(), solid_case(Material::elastic, "elastic"),
                                           solid_case(Material::stiff, "stiff"), board_case(),
                                           cloth_case(LinearSolver::multigrid),
                                           solid_case(Material::elastic, "elastic_multigrid",
                                                      LinearSolver::multigrid)),
                         pbve::testing::case_name);

}  // namespace
