// Physics of pbve::mass_spring: free fall, f = m a, momentum, settling cloth, stiff preset,
// anchors, elastic spring-back. Tolerances follow from the integrator (backward Euler) and the
// Newton tolerance; each is derived next to its assertion.

#include <cmath>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Geometry>

#include <gtest/gtest.h>

#include "mass_spring/meshes.hpp"
#include "pbve/core/mesh.hpp"
#include "pbve/edit/synth.hpp"
#include "pbve/mass_spring/mass_spring.hpp"

namespace {

using pbve::StepInput;
using pbve::Vertices;
using pbve::mass_spring::MassSpringSimulator;
using pbve::mass_spring::Material;
using pbve::mass_spring::Params;

TEST(MassSpringModel, SolidsNeedAClosedSurface) {
  // A flat sheet 1 m in front of the camera: its tetrahedra from the origin sum to a volume,
  // but it encloses none.
  const pbve::Mesh sheet = pbve::test::grid_mesh(5, 0.4, 1.0);
  for (const Material m : {Material::elastic, Material::stiff}) {
    try {
      MassSpringSimulator sim(sheet, {}, Params::preset(m));
      ADD_FAILURE() << "no error for an open sheet";
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find("needs a closed surface; the edge between vertices"),
                std::string::npos)
          << e.what();
    }
  }
  EXPECT_NO_THROW(MassSpringSimulator(sheet, {}, Params::preset(Material::cloth)));
  const pbve::Mesh ball = pbve::test::icosphere(1, 0.1, {0, 0, 1});
  EXPECT_NO_THROW(MassSpringSimulator(ball, {}, Params::preset(Material::elastic)));
}

TEST(MassSpringModel, ALatticeSpacingFarTooSmallIsAnError) {
  // 1e-12 m across a 0.2 m ball: 2e11 cells per axis, beyond int (the count is checked before
  // it is converted), not a lattice of one cell.
  const pbve::Mesh ball = pbve::test::icosphere(1, 0.1, {0, 0, 1});
  for (const double spacing : {1e-9, 1e-12}) {
    Params p = Params::preset(Material::elastic);
    p.lattice_spacing = spacing;
    try {
      MassSpringSimulator sim(ball, {}, p);
      ADD_FAILURE() << "no error for lattice_spacing " << spacing;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find("lattice cells, more than 2e6; choose a larger one"),
                std::string::npos)
          << e.what();
      EXPECT_NE(std::string(e.what()).find(spacing == 1e-9 ? "1e-09 m" : "1e-12 m"),
                std::string::npos)
          << e.what();
    }
  }
}

TEST(MassSpringPhysics, FreeFallMatchesBackwardEulerBound) {
  // Backward Euler on x'' = g with substep h: v_n = n h g, x_n = x_0 + h^2 g n(n+1)/2
  // = g t^2/2 + g t h/2. The integrator's error against g t^2/2 is therefore exactly
  // g t h / 2 (first order in h), and unstretched springs add no force.
  Params p = Params::preset(Material::cloth);
  p.damping_alpha = 0.0;
  p.damping_beta = 0.0;
  const pbve::Mesh mesh = pbve::test::grid_mesh(6, 0.5);
  MassSpringSimulator sim(mesh, {}, p);
  const Vertices x0 = sim.positions();
  const int frames = 30;
  StepInput in;
  in.dt = 1.0 / 30.0;
  for (int f = 0; f < frames; ++f) sim.step(in);
  const double t = frames * in.dt, h = in.dt / p.substeps, g = p.gravity.y();
  const double exact = 0.5 * g * t * t, bound = 0.5 * g * t * h;
  const Vertices d = sim.positions() - x0;
  for (Eigen::Index i = 0; i < d.rows(); ++i) {
    EXPECT_NEAR(d(i, 1) - exact, bound, 1e-9) << "vertex " << i;
    EXPECT_LE(std::abs(d(i, 1) - exact), bound * (1 + 1e-6));
    EXPECT_NEAR(d(i, 0), 0.0, 1e-9);
    EXPECT_NEAR(d(i, 2), 0.0, 1e-9);
  }
}

// A flat n x n cloth in the horizontal x-z plane (gravity +y is perpendicular to it).
pbve::Mesh horizontal_cloth(int n, double size) {
  pbve::Mesh m = pbve::test::grid_mesh(n, size, 0.0);
  m.vertices.col(1).swap(m.vertices.col(2));
  m.vertices.col(2).array() += 1.0;
  return m;
}

TEST(MassSpringPhysics, UniformForceGivesFEqualsMA) {
  // F_i = m_i a on every vertex of a free cloth (no gravity, no damping): springs stay at rest
  // length, so every vertex follows backward Euler for x'' = a exactly:
  // x(t) = a (t^2 + t h) / 2.
  Params p = Params::preset(Material::cloth);
  p.gravity.setZero();
  p.damping_alpha = p.damping_beta = 0.0;
  MassSpringSimulator sim(pbve::test::grid_mesh(4, 0.2), {}, p);
  const Eigen::Vector3d a(0.3, -0.2, 0.1);
  const Eigen::VectorXd mass = sim.control_layout().block_mass;
  EXPECT_NEAR(mass.sum(), p.density * 0.2 * 0.2, 1e-12);  // lumped masses add up to rho * area
  StepInput in;
  in.control.resize(3 * sim.num_vertices());
  for (int i = 0; i < sim.num_vertices(); ++i) in.control.segment<3>(3 * i) = mass[i] * a;
  const Vertices x0 = sim.positions();
  for (int f = 0; f < 6; ++f) sim.step(in);
  const double t = 6 * in.dt, h = in.dt / p.substeps;
  for (int i = 0; i < sim.num_vertices(); ++i)
    for (int c = 0; c < 3; ++c)
      EXPECT_NEAR(sim.positions()(i, c) - x0(i, c), 0.5 * a[c] * (t * t + t * h), 1e-10);
}

TEST(MassSpringPhysics, ForceOnOneFreeVertexGivesFEqualsMA) {
  // A force on a single vertex over a very short step: the springs respond only after the
  // vertex has moved, so the relative deviation from f = m a is O(k dt^2 / m) ~ 1e-4 here.
  Params p = Params::preset(Material::cloth);
  p.gravity.setZero();
  p.damping_alpha = p.damping_beta = 0.0;
  p.substeps = 1;
  MassSpringSimulator sim(pbve::test::grid_mesh(4, 0.2), {}, p);
  const int v = 5;
  const double m = sim.control_layout().block_mass[v];
  StepInput in;
  in.dt = 1e-4;
  in.control = Eigen::VectorXd::Zero(3 * sim.num_vertices());
  in.control.segment<3>(3 * v) = Eigen::Vector3d(0.0, 0.0, 0.01);
  sim.step(in);
  const double accel = sim.velocities()(v, 2) / in.dt;
  EXPECT_NEAR(accel, 0.01 / m, 1e-3 * 0.01 / m);
}

TEST(MassSpringPhysics, LinearMomentumConservedWithoutGravityAndDamping) {
  // Spring forces are pairwise opposite, so the total momentum changes only by the control
  // impulse. Per substep the Newton residual r (kg m) changes momentum by at most |sum r| / h;
  // with the tolerance tau = 1e-12 x edge length the drift bound below is ~1e-12 kg m/s.
  Params p = Params::preset(Material::cloth);
  p.gravity.setZero();
  p.damping_alpha = p.damping_beta = 0.0;
  p.newton_tolerance = 1e-12;
  MassSpringSimulator sim(pbve::test::grid_mesh(6, 0.3), {}, p);
  auto momentum = [&sim] {
    const Eigen::VectorXd m = sim.node_masses();
    const Vertices v = sim.velocities();
    Eigen::Vector3d P = Eigen::Vector3d::Zero();
    for (int i = 0; i < sim.num_vertices(); ++i) P += m[i] * v.row(i).transpose();
    return P;
  };
  StepInput kick;
  kick.control = Eigen::VectorXd::Zero(3 * sim.num_vertices());
  kick.control.segment<3>(3 * 7) = Eigen::Vector3d(0.05, 0.02, -0.03);
  kick.control.segment<3>(3 * 30) = Eigen::Vector3d(-0.01, 0.04, 0.06);
  sim.step(kick);
  // Impulse of the kick: control held over dt.
  const Eigen::Vector3d impulse =
      kick.dt * (Eigen::Vector3d(0.05, 0.02, -0.03) + Eigen::Vector3d(-0.01, 0.04, 0.06));
  EXPECT_LT((momentum() - impulse).norm(), 1e-12);
  double max_stretch = 0.0;
  for (int f = 0; f < 30; ++f) {
    sim.step(StepInput{});
    EXPECT_LT((momentum() - impulse).norm(), 1e-12) << "frame " << f;
    max_stretch = std::max(max_stretch, sim.kinetic_energy());
  }
  EXPECT_GT(max_stretch, 0.0);  // the cloth really moved
}

TEST(MassSpringPhysics, ClothAnchoredAtTwoCornersSettles) {
  // Horizontal cloth held at two corners falls, swings and comes to rest (Rayleigh damping and
  // the numerical dissipation of backward Euler). Kinetic energy oscillates while it swings,
  // so monotonic decay is checked on the envelope: the peak over each 1 s window after the
  // first second. At rest, the static equilibrium holds and stays. Air drag is raised
  // (alpha = 1/s); the softest (bending) modes creep towards equilibrium overdamped, so 24 s
  // of simulation are needed to reach rest. Each substep is solved to
  // tau = 1e-10 x edge length, so residual motion at rest is ~tau / h per second (~1e-9 m/s);
  // with the default 1e-6 the Newton error alone would move nodes by ~1e-5 m/s.
  const int n = 8;
  Params p = Params::preset(Material::cloth);
  p.damping_alpha = 1.0;
  p.newton_tolerance = 1e-10;
  MassSpringSimulator sim(horizontal_cloth(n, 0.3), {0, n - 1}, p);
  std::vector<double> peaks;
  double peak = 0.0;
  for (int f = 1; f <= 30 * 24; ++f) {
    sim.step(StepInput{});
    peak = std::max(peak, sim.kinetic_energy());
    if (f % 30 == 0) {
      peaks.push_back(peak);
      peak = 0.0;
    }
  }
  EXPECT_GT(peaks[0], 1e-4);  // it really fell
  for (size_t w = 2; w < peaks.size(); ++w) EXPECT_LT(peaks[w], peaks[w - 1]) << "window " << w;
  EXPECT_LT(peaks.back(), 1e-6 * peaks[0]);
  // Equilibrium: gravity and spring forces balance on every free vertex (averaged physical
  // force ~ m * residual acceleration), and the shape no longer changes.
  const Vertices before = sim.positions();
  for (int f = 0; f < 30; ++f) sim.step(StepInput{});
  EXPECT_LT((sim.positions() - before).cwiseAbs().maxCoeff(), 1e-5);
  const Eigen::VectorXd m = sim.control_layout().block_mass;
  for (int i = 0; i < sim.num_vertices(); ++i)
    EXPECT_LT(sim.physical_forces().row(i).norm(), 1e-2 * m[i] * 9.81) << "vertex " << i;
}

TEST(MassSpringPhysics, StiffPresetKeepsEdgeLengthsWithinOnePercent) {
  // A stiff ball held by one vertex falls around it as a pendulum for 1 s; every surface
  // edge stays within 1% of its rest length (the requirement) at every frame.
  const pbve::Mesh mesh = pbve::test::icosphere(2, 0.05, Eigen::Vector3d(0, 0, 1));
  MassSpringSimulator sim(mesh, {0}, Params::preset(Material::stiff));
  EXPECT_GT(sim.num_nodes(), sim.num_vertices());
  const std::vector<double> rest = pbve::test::edge_lengths(mesh.vertices, mesh.triangles);
  double worst = 0.0;
  for (int f = 0; f < 30; ++f) {
    sim.step(StepInput{});
    const std::vector<double> now = pbve::test::edge_lengths(sim.positions(), mesh.triangles);
    for (size_t e = 0; e < now.size(); ++e) worst = std::max(worst, std::abs(now[e] / rest[e] - 1));
  }
  EXPECT_LT(worst, 0.01);
  // and it did move: the centre swung away from below-the-anchor rest position
  EXPECT_GT((sim.positions() - mesh.vertices).rowwise().norm().maxCoeff(), 0.01);
}

TEST(MassSpringPhysics, AnchorsExactlyAtTargetsAfterEveryStep) {
  const int n = 6;
  MassSpringSimulator sim(horizontal_cloth(n, 0.3), {n - 1, 0, n * n - 1},
                          Params::preset(Material::cloth));
  EXPECT_EQ(sim.anchors(), (std::vector<int>{0, n - 1, n * n - 1}));  // sorted
  StepInput in;
  in.anchor_targets.resize(3, 3);
  for (int f = 0; f < 20; ++f) {
    for (int k = 0; k < 3; ++k)
      in.anchor_targets.row(k) = sim.positions().row(sim.anchors()[static_cast<size_t>(k)]) +
                                 Eigen::RowVector3d(0.01 * std::sin(f + k), 0.003 * f, -0.002);
    sim.step(in);
    for (int k = 0; k < 3; ++k)
      for (int c = 0; c < 3; ++c)  // bitwise: the target is assigned at the last substep
        EXPECT_EQ(sim.positions()(sim.anchors()[static_cast<size_t>(k)], c),
                  in.anchor_targets(k, c));
    EXPECT_EQ(sim.physical_forces().row(0).norm(), 0.0);
  }
  // Empty targets: anchors stay where they are.
  const Vertices before = sim.positions();
  sim.step(StepInput{});
  for (int a : sim.anchors()) EXPECT_EQ(sim.positions().row(a), before.row(a));
}

TEST(MassSpringPhysics, ElasticBodyWobblesAndReturnsToRestShape) {
  // A free elastic ball (no gravity) is pushed on one side for 0.1 s, deforms, wobbles and
  // returns to its rest shape. Shape is compared by edge lengths (rigid motion removed).
  Params p = Params::preset(Material::elastic);
  p.gravity.setZero();
  const pbve::Mesh mesh = pbve::test::icosphere(2, 0.05, Eigen::Vector3d(0, 0, 1));
  MassSpringSimulator sim(mesh, {}, p);
  ASSERT_GT(sim.num_nodes(), sim.num_vertices() + 50);  // interior lattice
  const std::vector<double> rest = pbve::test::edge_lengths(mesh.vertices, mesh.triangles);
  auto deformation = [&] {
    const std::vector<double> now = pbve::test::edge_lengths(sim.positions(), mesh.triangles);
    double worst = 0.0;
    for (size_t e = 0; e < now.size(); ++e) worst = std::max(worst, std::abs(now[e] / rest[e] - 1));
    return worst;
  };
  StepInput push;
  push.control = Eigen::VectorXd::Zero(3 * sim.num_vertices());
  const double total_mass = sim.node_masses().sum();
  for (int i = 0; i < sim.num_vertices(); ++i)
    if (mesh.vertices(i, 0) > 0.03) push.control[3 * i] = -0.2 * total_mass * 9.81 / 10;
  double max_deformation = 0.0;
  for (int f = 0; f < 3; ++f) {
    sim.step(push);
    max_deformation = std::max(max_deformation, deformation());
  }
  std::vector<double> history;
  for (int f = 0; f < 90; ++f) {
    sim.step(StepInput{});
    history.push_back(deformation());
    max_deformation = std::max(max_deformation, deformation());
  }
  EXPECT_GT(max_deformation, 0.02);  // a visible deformation
  // It wobbles: the deformation measure rises again after first falling (an oscillation).
  int rises = 0;
  for (size_t f = 1; f + 1 < history.size(); ++f)
    if (history[f] > history[f - 1] && history[f] > history[f + 1]) ++rises;
  EXPECT_GE(rises, 2);
  EXPECT_LT(history.back(), 0.1 * max_deformation);  // and springs back to near its rest shape
  EXPECT_LT(history.back(), 0.005);
}

TEST(MassSpringPhysics, GroundPlaneStopsFallingCloth) {
  // Penalty contact: at rest on the plane, each node penetrates by about m g / k_c.
  Params p = Params::preset(Material::cloth);
  pbve::mass_spring::Plane ground;
  ground.point = Eigen::Vector3d(0, 0.05, 0);
  ground.normal = Eigen::Vector3d(0, -1, 0);
  p.planes = {ground};
  MassSpringSimulator sim(horizontal_cloth(6, 0.3), {}, p);
  for (int f = 0; f < 60; ++f) sim.step(StepInput{});
  const double max_mass = sim.node_masses().maxCoeff();
  const double y = sim.positions().col(1).maxCoeff();
  EXPECT_GT(y, 0.05 - 0.01);                                         // it reached the plane
  EXPECT_LT(y, 0.05 + 1.5 * max_mass * 9.81 / p.contact_stiffness);  // and did not pass it
  EXPECT_LT(sim.velocities().cwiseAbs().maxCoeff(), 1e-3);
}

}  // namespace

namespace {

// The board of example 1 (1 cm thick) meshed finer than its thickness, as `pbve bench
// --vertices 8000` refines it: with the default layer distance it is still one sheet, its
// nodes one face's vertices.
TEST(MassSpringCloth, AFinelyMeshedBoardIsStillOneSheet) {
  const pbve::Mesh mesh = pbve::refine_mesh(pbve::make_box_mesh(0.4, 0.3, 0.01), 0.007);
  ASSERT_GT(mesh.num_vertices(), 4000);
  std::vector<int> anchors;
  for (int i = 0; i < mesh.num_vertices(); ++i)
    if (std::abs(mesh.vertices(i, 1)) < 1e-9 && std::abs(mesh.vertices(i, 0)) <= 0.05)
      anchors.push_back(i);
  const MassSpringSimulator sim(mesh, anchors, Params::preset(Material::cloth));
  EXPECT_TRUE(sim.single_sheet());
  EXPECT_LT(sim.num_nodes(), mesh.num_vertices() / 2);
}

// Largest deviation, over the vertex pairs facing each other across a 1 cm board made into
// cloth, of their distance from the thickness, while the board is twisted about its held
// middle (the motion of example 1).
double worst_layer_gap_error(double layer_stiffness, int single_sheet) {
  const double thickness = 0.01;
  const pbve::Mesh mesh = pbve::refine_mesh(pbve::make_box_mesh(0.4, 0.3, thickness), 0.05);
  Params p = Params::preset(Material::cloth);
  p.layer_stiffness = layer_stiffness;
  p.single_sheet = single_sheet;
  p.substeps = 3;
  std::vector<int> anchors;
  for (int i = 0; i < mesh.num_vertices(); ++i)
    if (std::abs(mesh.vertices(i, 1)) < 1e-9 && std::abs(mesh.vertices(i, 0)) <= 0.05)
      anchors.push_back(i);
  // Front (z < 0) and back (z > 0) vertices at the same (x, y) of the faces (not the rim).
  std::vector<std::pair<int, int>> pairs;
  for (int i = 0; i < mesh.num_vertices(); ++i)
    for (int j = 0; j < mesh.num_vertices(); ++j)
      if (mesh.vertices(i, 2) < 0 && mesh.vertices(j, 2) > 0 &&
          (mesh.vertices.row(i).head<2>() - mesh.vertices.row(j).head<2>()).norm() < 1e-9 &&
          std::abs(mesh.vertices(i, 0)) < 0.19 && mesh.vertices(i, 1) > 0.01 &&
          mesh.vertices(i, 1) < 0.29)
        pairs.emplace_back(i, j);
  EXPECT_GT(pairs.size(), 20u);
  MassSpringSimulator sim(mesh, anchors, p);
  EXPECT_EQ(sim.single_sheet(), single_sheet == 1);
  // A single sheet holds the nodes that carry the anchored vertices: those are its anchors().
  anchors = sim.anchors();
  double worst = 0.0;
  StepInput in;
  in.anchor_targets.resize(static_cast<Eigen::Index>(anchors.size()), 3);
  for (int f = 1; f <= 45; ++f) {
    const double yaw = 1.4 * std::sin(2 * 3.14159265358979 * 0.9 * f / 30.0);
    const Eigen::Matrix3d R = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitY()).toRotationMatrix();
    for (size_t k = 0; k < anchors.size(); ++k)
      in.anchor_targets.row(static_cast<Eigen::Index>(k)) =
          (R * mesh.vertices.row(anchors[k]).transpose()).transpose();
    sim.step(in);
    const Vertices x = sim.positions();
    for (const auto& [i, j] : pairs)
      worst = std::max(worst, std::abs((x.row(i) - x.row(j)).norm() - thickness));
  }
  return worst;
}

}  // namespace

TEST(MassSpringPhysics, LayerTiesKeepTheTwoFacesOfAThinBoardApart) {
  // With the ties, the faces of the twisted cloth board stay about one thickness apart: the
  // gap changes by less than half the thickness (the ties are springs, so it is not exact).
  // Without them the faces drift through each other (the back face would show through the
  // front one): gaps change by more than the thickness.
  const double with_ties =
      worst_layer_gap_error(Params::preset(Material::cloth).layer_stiffness, 0);
  const double without = worst_layer_gap_error(0.0, 0);
  EXPECT_LT(with_ties, 0.005);
  EXPECT_GT(without, 0.01);
}

TEST(MassSpringPhysics, ASingleSheetKeepsTheTwoFacesOfAThinBoardApart) {
  // Simulated as one sheet, a back vertex over a front node sits at that node plus its rest
  // offset turned by an orthonormal frame: the gap is the thickness up to rounding (1e-12 m is
  // a thousand times the rounding of 0.3 m coordinates), whatever the motion.
  EXPECT_LT(worst_layer_gap_error(0.0, 1), 1e-12);
}
