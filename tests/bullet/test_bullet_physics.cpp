// Physics sanity of pbve::bullet against closed-form answers, with tolerances from the
// integrator (symplectic Euler: v += a h, x += v h) and from Bullet's collision margin.

#include <algorithm>
#include <cmath>
#include <string>

#include <gtest/gtest.h>

#include "bullet/scenes.hpp"
#include "pbve/bullet/bullet.hpp"
#include "pbve/edit/synth.hpp"

namespace {

using Eigen::Vector3d;
using pbve::Vertices;
using pbve::bullet::BulletSimulator;
using pbve::bullet::Material;
using pbve::bullet::Params;

// A 0.1 m cube [-0.05, 0.05] x [y0, y0 + 0.1] x [0.95, 1.05].
pbve::Mesh cube(double y0) {
  pbve::Mesh m = pbve::make_box_mesh(0.1, 0.1, 0.1);
  m.vertices.rowwise() += Eigen::RowVector3d(0, y0, 1.0);
  return m;
}

Params rigid(Vector3d gravity = Vector3d(0, 9.81, 0)) {
  Params p = Params::preset(Material::rigid);
  p.gravity = gravity;
  return p;
}

// N steps of h from rest under constant acceleration a: x_N = a h^2 N (N + 1) / 2, which is
// a t^2 / 2 with a relative error of exactly 1 / N.
double symplectic_euler_distance(double a, double h, int n) {
  return a * h * h * n * (n + 1) / 2.0;
}

TEST(BulletSteps, ASubstepTooShortForBulletIsAnError) {
  // Bullet skips a step below its epsilon without a word; the adapter says so instead of
  // reporting the anchors' velocities divided by it.
  BulletSimulator sim(cube(0.0), {0}, Params::preset(Material::elastic));
  pbve::StepInput in;
  in.dt = 1e-15;
  try {
    sim.step(in);
    ADD_FAILURE() << "no error for dt 1e-15";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("is too short for Bullet"), std::string::npos) << e.what();
  }
  in.dt = 1.0 / 30.0;
  EXPECT_NO_THROW(sim.step(in));
  EXPECT_TRUE(sim.velocities().allFinite());
}

TEST(BulletRigid, MassPropertiesOfABox) {
  BulletSimulator sim(cube(0.0), {}, rigid());
  ASSERT_EQ(sim.num_bodies(), 1);
  // 1000 kg/m^3 * 1e-3 m^3.
  EXPECT_NEAR(sim.masses()(0), 1.0, 1e-12);
  EXPECT_LT((sim.centers_of_mass().row(0) - Eigen::RowVector3d(0, 0.05, 1.0)).norm(), 1e-12);
}

TEST(BulletRigid, FreeFallFollowsTheIntegrator) {
  Params p = rigid();
  p.substeps = 10;
  BulletSimulator sim(cube(0.0), {}, p);
  const Vertices x0 = sim.positions();
  const int frames = 15;
  const double dt = 1.0 / 30.0;
  pbve::StepInput in;
  in.dt = dt;
  for (int k = 0; k < frames; ++k) sim.step(in);
  const int n = frames * p.substeps;
  const double h = dt / p.substeps;
  const double t = frames * dt;
  const Vertices d = sim.positions() - x0;
  const double expected = symplectic_euler_distance(9.81, h, n);
  for (Eigen::Index i = 0; i < d.rows(); ++i) {
    // Every vertex falls by the same amount (no rotation), as the integrator predicts up to
    // rounding, and within g t^2 / (2 N) of the exact parabola.
    EXPECT_NEAR(d(i, 1), expected, 1e-12);
    EXPECT_NEAR(d(i, 1), 0.5 * 9.81 * t * t, 0.5 * 9.81 * t * t / n * (1 + 1e-9));
    EXPECT_NEAR(d(i, 0), 0.0, 1e-12);
    EXPECT_NEAR(d(i, 2), 0.0, 1e-12);
  }
  // The physical force of a free-falling body is its weight, shared by its vertices.
  const Eigen::Vector3d weight = sim.physical_forces().colwise().sum().transpose();
  EXPECT_LT((weight - Vector3d(0, 9.81, 0)).norm(), 1e-9);
}

TEST(BulletRigid, ForceAndTorqueGiveMassAndInertiaAccelerations) {
  Params p = rigid(Vector3d::Zero());
  p.substeps = 10;
  BulletSimulator sim(cube(0.0), {}, p);
  const double m = sim.masses()(0);
  const double inertia = m * (0.1 * 0.1 + 0.1 * 0.1) / 12.0;  // cube about any axis
  const Vector3d f(0.3, -0.2, 0.5);                           // N
  const double tau = 1e-4;                                    // N m about z
  pbve::StepInput in;
  in.dt = 1.0 / 30.0;
  in.control = Eigen::VectorXd::Zero(6);
  in.control.head<3>() = f;
  sim.step(in);
  // Linear: f = m a through the integrator.
  const double h = in.dt / p.substeps;
  const Vector3d com = sim.centers_of_mass().row(0).transpose();
  const Vector3d expected = Vector3d(0, 0.05, 1.0) + f / m * symplectic_euler_distance(1, h, 10);
  EXPECT_LT((com - expected).norm(), 1e-12);
  EXPECT_LT((sim.velocities().colwise().mean().transpose() - f / m * in.dt).norm(), 1e-12);

  // Angular: a torque about a principal axis of a body at rest spins it at tau / I * t (no
  // gyroscopic term while omega stays along that axis).
  BulletSimulator spin(cube(0.0), {}, p);
  in.control.setZero();
  in.control(5) = tau;
  spin.step(in);
  const double omega = tau / inertia * in.dt;
  const Vertices v = spin.velocities();
  const Vertices x = spin.positions();
  const Vector3d c = spin.centers_of_mass().row(0).transpose();
  for (Eigen::Index i = 0; i < v.rows(); ++i) {
    const Vector3d r = x.row(i).transpose() - c;
    const Vector3d expected_v = Vector3d(0, 0, omega).cross(r);
    EXPECT_LT((v.row(i).transpose() - expected_v).norm(), 1e-9 * omega * 0.1) << "vertex " << i;
  }
}

TEST(BulletRigid, ComesToRestOnTheGroundWithinTheMargin) {
  Params p = rigid();
  const double ground = 0.2;
  p.planes.push_back(pbve::test::ground_at(ground));
  // Bottom face (y = y0 + 0.1) 5 cm above the ground.
  BulletSimulator sim(cube(ground - 0.15), {}, p);
  pbve::StepInput in;
  for (int k = 0; k < 60; ++k) sim.step(in);
  const Vertices x = sim.positions();
  const double lowest = x.col(1).maxCoeff();
  // Contacts between the hull and the plane's box are clipped between their faces (polyhedral
  // contact clipping), so the box rests on the plane itself; the margin is the distance at
  // which contacts become active, and the solver's residual penetration stays below it.
  EXPECT_NEAR(lowest, ground, p.collision_margin);
  // At rest: less than one substep's worth of gravity in any vertex velocity.
  const double h = in.dt / p.substeps;
  EXPECT_LT(sim.velocities().rowwise().norm().maxCoeff(), 9.81 * h);
  // Flat on its face, to within the margin.
  EXPECT_LT(x.col(1).maxCoeff() - x.col(1).minCoeff() - 0.1, p.collision_margin);
}

TEST(BulletRigid, TouchingPiecesStayStackedOnTheGround) {
  // Two cubes sharing a face plane (as the pieces of a fractured object do), the lower one on
  // the ground: both stay where they are.
  Params p = rigid();
  const double ground = 0.2;
  p.planes.push_back(pbve::test::ground_at(ground));
  const pbve::Mesh stack = pbve::test::join(cube(ground - 0.1), cube(ground - 0.2));
  BulletSimulator sim(stack, {}, p);
  ASSERT_EQ(sim.num_bodies(), 2);
  const Vertices x0 = sim.positions();
  pbve::StepInput in;
  for (int k = 0; k < 60; ++k) sim.step(in);
  const Vertices x = sim.positions();
  // Each contact settles within the margin; two contacts in series, and no sliding or tipping
  // beyond that.
  for (Eigen::Index i = 0; i < x.rows(); ++i)
    EXPECT_LT((x.row(i) - x0.row(i)).norm(), 2 * p.collision_margin) << "vertex " << i;
  EXPECT_LT(sim.velocities().rowwise().norm().maxCoeff(), 9.81 * in.dt / p.substeps);
}

// A U-shaped piece open upwards (-y) on the ground, 4 cm cells: two walls on a floor, the
// notch between them 4 cm wide and deep. Concave, so it collides as its triangle mesh.
pbve::Mesh u_shape(double ground) {
  const double cell = 0.04;
  std::vector<Eigen::Vector3i> cells;
  for (int k = 0; k < 2; ++k) {
    for (int i = 0; i < 3; ++i) cells.emplace_back(i, 1, k);  // floor
    cells.emplace_back(0, 0, k);                              // walls
    cells.emplace_back(2, 0, k);
  }
  return pbve::test::voxel_mesh(cells, cell, Vector3d(-0.06, ground - 2 * cell, 0.96));
}

TEST(BulletRigid, ConcavePieceCatchesACubeInItsNotch) {
  const double ground = 0.2;
  Params p = rigid();
  p.planes.push_back(pbve::test::ground_at(ground));
  // A 2.5 cm cube 2 cm above the notch, centred on it.
  pbve::Mesh small = pbve::make_box_mesh(0.025, 0.025, 0.025);
  const double rim = ground - 0.08;  // the top of the walls
  small.vertices.rowwise() += Eigen::RowVector3d(0, rim - 0.02 - 0.025, 1.0);
  const pbve::Mesh scene = pbve::test::join(u_shape(ground), small);
  BulletSimulator sim(scene, {}, p);
  ASSERT_EQ(sim.num_bodies(), 2);
  EXPECT_NEAR(sim.masses()(0), 1000.0 * 10 * 0.04 * 0.04 * 0.04, 1e-9);  // ten cells
  pbve::StepInput in;
  for (int k = 0; k < 45; ++k) sim.step(in);
  const Vertices x = sim.positions();
  const int nu = u_shape(ground).num_vertices();
  // Triangle-mesh contacts are found by GJK between the cube's hull and each triangle, both
  // inflated by the collision margin: the U rests one margin above the ground, and the cube two
  // margins above the floor of the notch, 4 cm below the U's rim (its hull would have held the
  // cube on the rim, 4 cm higher). The contact solver's residual stays within one margin.
  const double m = p.collision_margin;
  const double u_bottom = x.topRows(nu).col(1).maxCoeff();
  EXPECT_NEAR(u_bottom, ground - m, m);
  const double notch_floor = u_bottom - 0.04;
  EXPECT_NEAR(x.bottomRows(8).col(1).maxCoeff(), notch_floor - 2 * m, m);
}

TEST(BulletRigid, PiecesAreSeparateBodiesAndAnchoredOnesFollowTheirTargets) {
  const pbve::Mesh m = pbve::test::join(cube(0.0), cube(0.0));
  pbve::Mesh two = m;
  two.vertices.bottomRows(8).rowwise() += Eigen::RowVector3d(0.3, 0, 0);
  BulletSimulator sim(two, {0, 1, 2}, rigid());
  ASSERT_EQ(sim.num_bodies(), 2);
  const auto layout = sim.control_layout();
  EXPECT_EQ(layout.space, pbve::ControlSpace::body_wrench);
  EXPECT_EQ(layout.vertex_block[0], 0);
  EXPECT_EQ(layout.vertex_block[8], 1);
  const Vertices x0 = sim.positions();
  // Translate the anchors rigidly: the whole anchored cube follows, the other one falls.
  pbve::StepInput in;
  const Eigen::RowVector3d shift(0.02, -0.01, 0.005);
  in.anchor_targets.resize(3, 3);
  for (int a = 0; a < 3; ++a) in.anchor_targets.row(a) = x0.row(a) + shift;
  sim.step(in);
  const Vertices x = sim.positions();
  for (int i = 0; i < 8; ++i)
    EXPECT_LT((x.row(i) - x0.row(i) - shift).norm(), 1e-12) << "vertex " << i;
  for (int i = 8; i < 16; ++i) EXPECT_GT(x(i, 1), x0(i, 1)) << "vertex " << i;
  // Anchored vertices exactly on target.
  for (int a = 0; a < 3; ++a)
    for (int c = 0; c < 3; ++c) EXPECT_EQ(x(a, c), in.anchor_targets(a, c));
}

TEST(BulletCloth, AnchoredAtTwoCornersHangsWithAnchorsOnTarget) {
  const int n = 11;
  const pbve::Mesh grid = pbve::test::grid_mesh(n, 0.3);
  const std::vector<int> anchors{0, n - 1};  // the top corners (y = -0.15)
  BulletSimulator sim(grid, anchors, Params::preset(Material::cloth));
  const Vertices x0 = sim.positions();
  pbve::StepInput in;
  in.anchor_targets.resize(2, 3);
  for (int k = 0; k < 30; ++k) {
    // The anchors slide 2 mm per frame towards +x.
    for (int a = 0; a < 2; ++a)
      in.anchor_targets.row(a) = x0.row(anchors[a]) + Eigen::RowVector3d(0.002 * (k + 1), 0, 0);
    sim.step(in);
    const Vertices x = sim.positions();
    ASSERT_TRUE(x.allFinite());
    for (int a = 0; a < 2; ++a)
      for (int c = 0; c < 3; ++c) ASSERT_EQ(x(anchors[a], c), in.anchor_targets(a, c));
    for (int a = 0; a < 2; ++a) EXPECT_EQ(sim.physical_forces().row(anchors[a]).norm(), 0.0);
  }
  // The free bottom row fell below its start.
  const Vertices x = sim.positions();
  for (int i = n * (n - 1); i < n * n; ++i) EXPECT_GT(x(i, 1), x0(i, 1)) << "vertex " << i;
}

TEST(BulletCloth, NodeMassesAddUpToTheDensityTimesArea) {
  const pbve::Mesh grid = pbve::test::grid_mesh(6, 0.3);
  Params p = Params::preset(Material::cloth);
  BulletSimulator sim(grid, {0}, p);
  const auto layout = sim.control_layout();
  EXPECT_NEAR(layout.block_mass.sum(), p.density * 0.3 * 0.3, 1e-12);
  EXPECT_EQ(sim.masses()(0), 0.0);  // the anchor
}

TEST(BulletCloth, RestsOnTheGroundAtTheMargin) {
  // A horizontal sheet (normal along y) dropped 2 cm onto the ground.
  pbve::Mesh sheet = pbve::test::grid_mesh(6, 0.2);
  for (Eigen::Index i = 0; i < sheet.vertices.rows(); ++i) {
    const double y = sheet.vertices(i, 1);
    sheet.vertices(i, 1) = 0.18;
    sheet.vertices(i, 2) = 1.0 + y;
  }
  Params p = Params::preset(Material::cloth);
  p.planes.push_back(pbve::test::ground_at(0.2));
  BulletSimulator sim(sheet, {}, p);
  pbve::StepInput in;
  for (int k = 0; k < 30; ++k) sim.step(in);
  const Vertices x = sim.positions();
  // Nodes collide when their distance to the plane falls below the margin; each substep's
  // contact projection puts them back on it, and gravity moves them by at most g h^2 into it.
  const double h = in.dt / p.substeps;
  for (Eigen::Index i = 0; i < x.rows(); ++i)
    EXPECT_NEAR(x(i, 1), 0.2 - p.collision_margin, p.collision_margin + 9.81 * h * h)
        << "vertex " << i;
}

// A board made into cloth (refined, 30 x 30 x 1 cm), held at its top edge, split into its
// front face (towards the camera, z = -5 mm), its back face and the rim between them.
struct HeldBoard {
  pbve::Mesh mesh = pbve::refine_mesh(pbve::make_box_mesh(0.3, 0.3, 0.01), 0.03);
  std::vector<int> anchors, front, back;
  HeldBoard() {
    for (int i = 0; i < mesh.num_vertices(); ++i) {
      const double y = mesh.vertices(i, 1), z = mesh.vertices(i, 2);
      if (y < 1e-9)
        anchors.push_back(i);
      else if (z < -0.005 + 1e-9)
        front.push_back(i);
      else if (z > 0.005 - 1e-9)
        back.push_back(i);
    }
  }
  static double mean_z(const Vertices& x, const std::vector<int>& ids) {
    double s = 0.0;
    for (int i : ids) s += x(i, 2);
    return s / static_cast<double>(ids.size());
  }
  // Pushes the front face backwards (no gravity): a force of its weight on every front vertex
  // towards +z (away from the camera). Over 5 steps (1/6 s) a free node would move 14 cm, far
  // more than the 1 cm thickness, while the board, held at its top edge, turns by less than 30
  // degrees. Returns the mean z of the back face minus that of the front face.
  double push_front(BulletSimulator& sim) const {
    pbve::StepInput in;
    in.control = Eigen::VectorXd::Zero(sim.control_layout().size());
    const Eigen::VectorXd m = sim.control_layout().block_mass;
    for (int i : front) in.control(3 * i + 2) = 9.81 * m(i);
    for (int k = 0; k < 5; ++k) sim.step(in);
    const Vertices x = sim.positions();
    EXPECT_TRUE(x.allFinite());
    return mean_z(x, back) - mean_z(x, front);
  }
};

// Simulated as two layers, the board's front face is pushed through its back face unless the
// layers are tied; with ties the back layer is pushed along and stays behind.
TEST(BulletCloth, LayerTiesKeepTheFrontLayerOfABoardInFront) {
  const HeldBoard board;
  auto run = [&](double layer_stiffness) {
    Params p = Params::preset(Material::cloth);
    p.gravity.setZero();
    p.single_sheet = 0;
    p.layer_stiffness = layer_stiffness;
    BulletSimulator sim(board.mesh, board.anchors, p);
    EXPECT_EQ(sim.num_nodes(), board.mesh.num_vertices());
    const double gap = board.push_front(sim);
    return std::make_pair(sim.num_layer_ties(), gap);
  };
  const auto [ties, gap_tied] = run(1.0);
  const auto [no_ties, gap_free] = run(0.0);
  // Every face vertex off the rim is tied once: about half the vertices in pairs.
  EXPECT_GT(ties, static_cast<int>(board.front.size()) / 2);
  EXPECT_EQ(no_ties, 0);
  // Untied, the front layer ends behind the back one. Tied, the layers keep their 1 cm
  // distance (position constraints of stiffness 1), seen along z through the board's turn
  // (cos 30 degrees = 0.87) and the ties' residual stretch: at least half of it remains.
  EXPECT_LT(gap_free, 0.0);
  EXPECT_GT(gap_tied, 0.5 * 0.01);
}

// The same board meshed finer than its 1 cm thickness (mean edge about 5 mm): with the
// default layer distance it is still one sheet, one face's vertices.
TEST(BulletCloth, AFinelyMeshedBoardIsStillOneSheet) {
  const pbve::Mesh mesh = pbve::refine_mesh(pbve::make_box_mesh(0.4, 0.3, 0.01), 0.007);
  const BulletSimulator sim(mesh, {}, Params::preset(Material::cloth));
  EXPECT_EQ(sim.num_layer_ties(), 0);
  const std::vector<int> nodes = sim.node_vertices();
  ASSERT_FALSE(nodes.empty());
  EXPECT_LT(nodes.size(), static_cast<size_t>(mesh.num_vertices() / 2));
  const double side = mesh.vertices(nodes.front(), 2);
  EXPECT_NEAR(std::abs(side), 0.005, 1e-12);
  for (int v : nodes) EXPECT_EQ(mesh.vertices(v, 2), side) << "node vertex " << v;
}

// Simulated as one sheet (the default), one face is the Bullet cloth and every other vertex
// follows it at its rest offset: the board keeps its 1 cm thickness exactly and its mass.
TEST(BulletCloth, ThinBoardIsOneSheetWithItsOtherFaceAttached) {
  const HeldBoard board;
  Params p = Params::preset(Material::cloth);
  p.gravity.setZero();
  BulletSimulator sim(board.mesh, board.anchors, p);
  EXPECT_EQ(sim.num_layer_ties(), 0);
  // The nodes are the vertices of one face (its edge included): all at z = -5 mm or all at +5.
  const std::vector<int> nodes = sim.node_vertices();
  EXPECT_EQ(sim.num_nodes(), static_cast<int>(nodes.size()));
  EXPECT_LT(nodes.size(), static_cast<size_t>(board.mesh.num_vertices() / 2));
  const double side = board.mesh.vertices(nodes.front(), 2);
  EXPECT_NEAR(std::abs(side), 0.005, 1e-12);
  for (int v : nodes) EXPECT_EQ(board.mesh.vertices(v, 2), side) << "node vertex " << v;
  // The blocks share the board's mass as before: density times the whole surface area.
  EXPECT_NEAR(sim.control_layout().block_mass.sum(),
              p.density * pbve::triangle_areas(board.mesh.vertices, board.mesh.triangles).sum(),
              1e-12);
  // Pushing the front face backwards moves the whole board: the faces stay 1 cm apart.
  const double gap = board.push_front(sim);
  EXPECT_GT(gap, 0.0085);  // 1 cm seen through a turn of less than 30 degrees
  EXPECT_LT(gap, 0.0100 + 1e-9);
  const Vertices x = sim.positions();
  // Vertices straight across the board from each other stay 1 cm apart.
  const Vertices& x0 = board.mesh.vertices;
  int across = 0;
  for (const auto& [u, v] : pbve::opposite_layer_pairs(x0, board.mesh.triangles, 0.03)) {
    if (std::abs((x0.row(u) - x0.row(v)).norm() - 0.01) > 1e-12) continue;
    EXPECT_NEAR((x.row(u) - x.row(v)).norm(), 0.01, 1e-12) << "vertices " << u << ", " << v;
    ++across;
  }
  EXPECT_GT(across, static_cast<int>(board.front.size()) / 2);
  // The pushed board moved: more than its thickness.
  EXPECT_GT(HeldBoard::mean_z(x, board.front) - HeldBoard::mean_z(board.mesh.vertices, board.front),
            0.01);
}

// Held only by vertices that are not sheet nodes (the top edge of the face that is not
// simulated, and of the rim), the sheet follows them: the nodes that carry them move with the
// anchors' rigid motion, and the anchors are reported exactly at their targets.
TEST(BulletCloth, SheetHeldByAttachedVerticesFollowsThem) {
  const HeldBoard board;
  const Params p = Params::preset(Material::cloth);
  const std::vector<int> nodes = BulletSimulator(board.mesh, {}, p).node_vertices();
  std::vector<int> anchors;
  for (int i : board.anchors)
    if (!std::binary_search(nodes.begin(), nodes.end(), i)) anchors.push_back(i);
  ASSERT_GT(anchors.size(), 3u);
  BulletSimulator sim(board.mesh, anchors, p);
  const Vertices rest = board.mesh.vertices;
  pbve::StepInput in;
  in.anchor_targets.resize(static_cast<Eigen::Index>(anchors.size()), 3);
  for (int k = 0; k < 20; ++k) {
    for (size_t i = 0; i < anchors.size(); ++i)
      in.anchor_targets.row(static_cast<Eigen::Index>(i)) =
          rest.row(anchors[i]) + Eigen::RowVector3d(0.005 * (k + 1), 0, 0);
    sim.step(in);
    const Vertices x = sim.positions();
    ASSERT_TRUE(x.allFinite());
    for (size_t i = 0; i < anchors.size(); ++i)
      for (int c = 0; c < 3; ++c)
        ASSERT_EQ(x(anchors[i], c), in.anchor_targets(static_cast<Eigen::Index>(i), c));
  }
  // The whole top edge, nodes included, went along: 10 cm to the right.
  const Vertices x = sim.positions();
  for (int i : board.anchors) EXPECT_NEAR(x(i, 0) - rest(i, 0), 0.1, 1e-3) << "vertex " << i;
}

TEST(BulletElastic, BallKeepsItsVolumeUnderItsWeight) {
  // A ball hanging from its top vertex: the volume force resists compression and stretching.
  const pbve::Mesh ball = pbve::test::icosphere(2, 0.05, Vector3d(0, 0, 1));
  int top = 0;
  for (int i = 0; i < ball.num_vertices(); ++i)
    if (ball.vertices(i, 1) < ball.vertices(top, 1)) top = i;
  Params p = Params::preset(Material::elastic);
  BulletSimulator sim(ball, {top}, p);
  pbve::StepInput in;
  for (int k = 0; k < 30; ++k) sim.step(in);
  const Vertices x = sim.positions();
  auto volume = [&](const Vertices& v) {
    double vol = 0;
    for (Eigen::Index f = 0; f < ball.triangles.rows(); ++f)
      vol += v.row(ball.triangles(f, 0))
                 .dot(v.row(ball.triangles(f, 1)).cross(v.row(ball.triangles(f, 2)))) /
             6.0;
    return vol;
  };
  const double v0 = volume(ball.vertices);
  // Weight m g spread over the ball's cross-section pi r^2 is a pressure of rho g 4 r / 3
  // ~ 650 Pa, a relative volume change of ~650 / 2e4 = 3% for the preset's volume stiffness;
  // allow three times that for the non-uniform load.
  EXPECT_NEAR(volume(x) / v0, 1.0, 0.1);
  EXPECT_TRUE(x.allFinite());
}

}  // namespace
