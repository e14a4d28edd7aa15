// The shared adapter conformance suite on pbve::bullet: cloth, elastic and stiff soft bodies
// and rigid bodies, each above a ground plane it reaches during the replay checks.

#include <algorithm>
#include <thread>

#include "bullet/scenes.hpp"
#include "pbve/bullet/bullet.hpp"
#include "pbve/edit/synth.hpp"
#include "pbve/testing/simulator_conformance.hpp"

namespace {

using pbve::bullet::BulletSimulator;
using pbve::bullet::Material;
using pbve::bullet::Params;
using pbve::testing::ConformanceCase;

// The f = m a probe pushes one node for N = fma_steps substeps. Bullet's links and shape
// matching are position based: each substep moves a node a fraction c of the way back
// (c ~ stiffness times the node's share of the link's inverse mass, summed over its links),
// which acts as a spring of period 2 pi / sqrt(c) substeps whatever dt is, and reduces the
// probe's displacement by about c N^2 / 12. The symplectic Euler integrator adds N(N+1)/2
// instead of N^2/2 steps of h^2 a: +1/N. With N = 20 and c ~ 1.5e-3 (a cloth corner: two links
// of stiffness 1e-3) the two stay near 5% each and of opposite sign, inside the suite's 10%; a
// sphere node has about six links, so the solids use 2e-4 (and shape matching 2e-4).
// The presets' stiffnesses (0.2 to 1) would make a single node answer with its neighbours.
Params compliant(Material m) {
  Params p = Params::preset(m);
  p.linear_stiffness = m == Material::cloth ? 1e-3 : 2e-4;
  p.bending_stiffness = 0.0;
  p.damping = 0.0;  // kDP removes a fraction of the velocity per substep: -kDP N / 3
  if (m != Material::cloth) p.shape_matching = 2e-4;
  p.substeps = 1;
  p.planes.push_back(pbve::test::ground_at(0.2));
  return p;
}

ConformanceCase cloth_case() {
  ConformanceCase c;
  c.name = "cloth";
  c.make = [] {
    return std::make_unique<BulletSimulator>(pbve::test::grid_mesh(6, 0.3), std::vector<int>{0, 5},
                                             compliant(Material::cloth));
  };
  return c;
}

ConformanceCase solid_case(Material m, const char* name) {
  ConformanceCase c;
  c.name = name;
  c.make = [m] {
    Params p = compliant(m);
    p.planes[0] = pbve::test::ground_at(0.1);
    return std::make_unique<BulletSimulator>(
        pbve::test::icosphere(1, 0.06, Eigen::Vector3d(0, 0, 1)), std::vector<int>{0}, p);
  };
  // The volume force is a spring of k ~ volume_stiffness * a^2 / V0 per node (a: node area):
  // ~3e3 N/m or more on a 0.02 kg node for the stiff preset, period < 20 ms. A 0.2 ms probe
  // keeps its effect, (omega T)^2 / 12, below 0.1%.
  if (m == Material::stiff) c.fma_dt = 1e-5;
  return c;
}

ConformanceCase rigid_case() {
  ConformanceCase c;
  c.name = "rigid";
  c.make = [] {
    // Two spheres: the left one anchored (kinematic), the right one free, 4 cm above the
    // ground, which it reaches after ~0.09 s.
    const pbve::Mesh m =
        pbve::test::join(pbve::test::icosphere(1, 0.06, Eigen::Vector3d(-0.15, 0, 1)),
                         pbve::test::icosphere(1, 0.06, Eigen::Vector3d(0.15, 0, 1)));
    Params p = Params::preset(Material::rigid);
    p.planes.push_back(pbve::test::ground_at(0.1));
    return std::make_unique<BulletSimulator>(m, std::vector<int>{0}, p);
  };
  // 10 substeps per step: N = 200 integrator steps, +0.5%.
  return c;
}

// The replay, clone and anchor properties with the presets themselves (stiff links, bending,
// shape matching, and a pressure), where the f = m a probe does not apply.
TEST(BulletPresets, ReplayCloneAndAnchorsAreExact) {
  for (Material m : {Material::cloth, Material::elastic, Material::stiff, Material::rigid}) {
    SCOPED_TRACE(pbve::bullet::to_string(m));
    ConformanceCase c;
    c.name = pbve::bullet::to_string(m);
    c.make = [m] {
      Params p = Params::preset(m);
      if (m == Material::elastic) p.pressure = 500.0;
      p.planes.push_back(pbve::test::ground_at(0.1));
      if (m == Material::cloth)
        return std::make_unique<BulletSimulator>(pbve::test::grid_mesh(8, 0.3),
                                                 std::vector<int>{0, 7}, p);
      if (m == Material::rigid)
        return std::make_unique<BulletSimulator>(
            pbve::test::join(pbve::test::icosphere(1, 0.06, Eigen::Vector3d(-0.15, 0, 1)),
                             pbve::test::icosphere(1, 0.06, Eigen::Vector3d(0.15, 0, 1))),
            std::vector<int>{0}, p);
      return std::make_unique<BulletSimulator>(
          pbve::test::icosphere(2, 0.06, Eigen::Vector3d(0, 0, 1)), std::vector<int>{0}, p);
    };
    c.steps = 10;
    EXPECT_TRUE(pbve::testing::check_layout(c));
    EXPECT_TRUE(pbve::testing::check_save_restore(c));
    EXPECT_TRUE(pbve::testing::check_restore_into_clone(c));
    EXPECT_TRUE(pbve::testing::check_clone(c));
    EXPECT_TRUE(pbve::testing::check_anchors(c));
    EXPECT_TRUE(pbve::testing::check_determinism(c));
    EXPECT_TRUE(pbve::testing::check_large_step(c));
  }
}

// A board made into cloth, simulated as one sheet with its other face and rim attached: replay,
// clones and anchors stay exact, held by its whole top edge or only by vertices that are not
// sheet nodes (their carrying nodes then follow the anchors' rigid fit).
TEST(BulletPresets, ThinSheetReplaysExactly) {
  const pbve::Mesh board = pbve::refine_mesh(pbve::make_box_mesh(0.3, 0.2, 0.01), 0.05);
  std::vector<int> top;
  for (int i = 0; i < board.num_vertices(); ++i)
    if (board.vertices(i, 1) < 1e-9) top.push_back(i);
  Params p = Params::preset(Material::cloth);
  p.planes.push_back(pbve::test::ground_at(0.25));
  const std::vector<int> nodes = BulletSimulator(board, {}, p).node_vertices();
  ASSERT_LT(nodes.size(), static_cast<size_t>(board.num_vertices()));
  std::vector<int> attached_top;
  for (int i : top)
    if (!std::binary_search(nodes.begin(), nodes.end(), i)) attached_top.push_back(i);
  for (const auto& anchors : {top, attached_top}) {
    SCOPED_TRACE(anchors.size());
    ConformanceCase c;
    c.name = "thin_sheet";
    c.make = [&board, anchors, p] { return std::make_unique<BulletSimulator>(board, anchors, p); };
    c.steps = 10;
    EXPECT_TRUE(pbve::testing::check_layout(c));
    EXPECT_TRUE(pbve::testing::check_save_restore(c));
    EXPECT_TRUE(pbve::testing::check_restore_into_clone(c));
    EXPECT_TRUE(pbve::testing::check_clone(c));
    EXPECT_TRUE(pbve::testing::check_anchors(c));
    EXPECT_TRUE(pbve::testing::check_determinism(c));
    EXPECT_TRUE(pbve::testing::check_large_step(c));
  }
}

// A concave piece (triangle-mesh contacts, btGImpactMeshShape), anchored, with a cube falling
// into its notch: replay and clones stay exact.
TEST(BulletPresets, ConcavePieceReplaysExactly) {
  ConformanceCase c;
  c.name = "concave";
  c.make = [] {
    std::vector<Eigen::Vector3i> cells;
    for (int k = 0; k < 2; ++k) {
      for (int i = 0; i < 3; ++i) cells.emplace_back(i, 1, k);
      cells.emplace_back(0, 0, k);
      cells.emplace_back(2, 0, k);
    }
    pbve::Mesh cube = pbve::make_box_mesh(0.025, 0.025, 0.025);
    cube.vertices.rowwise() += Eigen::RowVector3d(0, -0.03, 1.0);
    const pbve::Mesh scene = pbve::test::join(
        pbve::test::voxel_mesh(cells, 0.04, Eigen::Vector3d(-0.06, 0.0, 0.96)), cube);
    return std::make_unique<BulletSimulator>(scene, std::vector<int>{0},
                                             Params::preset(Material::rigid));
  };
  c.steps = 10;
  EXPECT_TRUE(pbve::testing::check_save_restore(c));
  EXPECT_TRUE(pbve::testing::check_restore_into_clone(c));
  EXPECT_TRUE(pbve::testing::check_clone(c));
  EXPECT_TRUE(pbve::testing::check_anchors(c));
  EXPECT_TRUE(pbve::testing::check_determinism(c));
}

// Clones stepped concurrently (as the optimizer's parallel central differences do; rigid clones
// share their hull shapes) give the same results as one after the other.
TEST(BulletClones, StepConcurrentlyAsTheyDoInSequence) {
  for (Material m : {Material::cloth, Material::rigid}) {
    SCOPED_TRACE(pbve::bullet::to_string(m));
    Params p = Params::preset(m);
    p.planes.push_back(pbve::test::ground_at(0.1));
    const pbve::Mesh mesh =
        m == Material::cloth
            ? pbve::test::grid_mesh(12, 0.3)
            : pbve::test::join(pbve::test::icosphere(2, 0.06, Eigen::Vector3d(-0.15, 0, 1)),
                               pbve::test::icosphere(2, 0.06, Eigen::Vector3d(0.15, 0, 1)));
    BulletSimulator base(mesh, {0}, p);
    pbve::StepInput in;
    base.step(in);
    const int n = 4;
    std::vector<std::unique_ptr<pbve::Simulator>> clones;
    for (int i = 0; i < n; ++i) clones.push_back(base.clone());
    auto run = [&](pbve::Simulator& s, int i) {
      pbve::StepInput k = in;
      k.control = Eigen::VectorXd::Constant(s.control_layout().size(), 0.01 * (i + 1));
      for (int j = 0; j < 15; ++j) s.step(k);
    };
    std::vector<std::thread> threads;
    for (int i = 0; i < n; ++i) threads.emplace_back([&, i] { run(*clones[i], i); });
    for (auto& t : threads) t.join();
    for (int i = 0; i < n; ++i) {
      auto serial = base.clone();
      run(*serial, i);
      EXPECT_TRUE(pbve::testing::detail::bit_equal(clones[i]->positions(), serial->positions(),
                                                   "concurrent vs sequential clone"));
    }
  }
}

INSTANTIATE_TEST_SUITE_P(Bullet, SimulatorConformance,
                         ::testing::Values(cloth_case(), solid_case(Material::elastic, "elastic"),
                                           solid_case(Material::stiff, "stiff"), rigid_case()),
                         pbve::testing::case_name);

}  // namespace
