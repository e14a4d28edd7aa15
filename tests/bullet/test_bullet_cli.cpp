// End-to-end: `pbve synth` then `pbve edit` with `engine: bullet`: small board clips (cloth,
// rigid), example 1 through Bullet, and fractures (Voronoi pieces, pieces from an OBJ).

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include <gtest/gtest.h>

#include "pbve/bullet/bullet.hpp"
#include "pbve/core/footage.hpp"
#include "pbve/core/mesh.hpp"
#include "pbve/core/pose.hpp"
#include "pbve/edit/report.hpp"
#include "support/cli.hpp"
#include "support/test_util.hpp"

namespace {

namespace fs = std::filesystem;
using pbve::test::CmdResult;
using pbve::test::pbve_binary;
using pbve::test::pbve_cmd;

// Replaces the first `from` in the file by `to`; false when absent.
bool replace_in(const fs::path& file, const std::string& from, const std::string& to) {
  std::stringstream ss;
  ss << std::ifstream(file).rdbuf();
  std::string text = ss.str();
  const auto at = text.find(from);
  if (at == std::string::npos) return false;
  text.replace(at, from.size(), to);
  std::ofstream(file) << text;
  return true;
}

class BulletCli : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!fs::exists(pbve_binary()))
      GTEST_SKIP() << pbve_binary() << " was not built (PBVE_BUILD_EXAMPLES=OFF)";
    const CmdResult r =
        pbve_cmd("synth --size 160x120 --frames 4 --supersample 1 " + dir.path().string());
    ASSERT_EQ(r.status, 0) << r.output;
    scene = dir / "scene.yaml";
    ASSERT_TRUE(replace_in(scene, "engine: mass_spring", "engine: bullet"));
  }
  pbve::test::TempDir dir;
  fs::path scene;
};

TEST_F(BulletCli, UncontrolledClothRun) {
  const CmdResult r = pbve_cmd("edit " + scene.string() + " --no-control --quiet");
  ASSERT_EQ(r.status, 0) << r.output;
  const pbve::Report rep = pbve::read_report(dir / "report.json");
  EXPECT_EQ(rep.engine, "bullet");
  ASSERT_EQ(rep.frames.size(), 4u);
  EXPECT_TRUE(rep.complete);
  // Gravity acts on the free vertices after the first step.
  for (size_t i = 1; i < rep.frames.size(); ++i) EXPECT_GT(rep.frames[i].physical_force, 0.0);
  EXPECT_EQ(pbve::Footage::open_video(dir / "edited.mp4").frame_count(), 4);
}

TEST_F(BulletCli, ControlRunsThroughCentralDifferences) {
  // Few iterations: this checks the plumbing (clones, save/restore, gradients), not quality.
  ASSERT_TRUE(replace_in(scene, "max_iterations: 20", "max_iterations: 2"));
  const CmdResult r = pbve_cmd("edit " + scene.string() + " --frames 0:2 --quiet");
  ASSERT_EQ(r.status, 0) << r.output;
  const pbve::Report rep = pbve::read_report(dir / "report.json");
  ASSERT_EQ(rep.frames.size(), 2u);
  EXPECT_NE(rep.frames[1].status, "off");
  EXPECT_NE(rep.frames[1].status, "failed");
  EXPECT_GT(rep.frames[1].physical_force, 0.0);
}

TEST_F(BulletCli, RigidBoardFalls) {
  ASSERT_TRUE(replace_in(scene, "material: cloth", "material: rigid"));
  // Without anchors the board is one free rigid body.
  ASSERT_TRUE(replace_in(scene, "anchors:", "# anchors:"));
  const CmdResult r = pbve_cmd("edit " + scene.string() + " --no-control --quiet");
  ASSERT_EQ(r.status, 0) << r.output;
  const pbve::Report rep = pbve::read_report(dir / "report.json");
  EXPECT_EQ(rep.engine, "bullet");
  ASSERT_EQ(rep.frames.size(), 4u);
  EXPECT_GT(rep.frames[2].physical_force, 0.0);
}

// The fractured statue in one picture (`pbve synth --shape statue --image`): 8 Voronoi pieces
// of a block fall 12 cm, land and scatter. Without control they turn faces the picture never
// saw towards the camera; with control (central differences through Bullet, forces bounded
// by twice each piece's weight) those faces stay hidden. Small frames and 20 frames keep it
// quick; the example runs the full clip (docs/examples.md).
TEST(BulletFracture, StatuePiecesScatterAndControlKeepsUnseenFacesHidden) {
  if (!fs::exists(pbve_binary()))
    GTEST_SKIP() << pbve_binary() << " was not built (PBVE_BUILD_EXAMPLES=OFF)";
  pbve::test::TempDir dir;
  const CmdResult s = pbve_cmd(
      "synth --shape statue --motion still --image --frames 20 "
      "--size 320x240 --supersample 1 " +
      dir.path().string());
  ASSERT_EQ(s.status, 0) << s.output;
  const fs::path scene = dir / "scene.yaml";
  const auto [u, c] =
      pbve::test::edit_without_and_with_control(scene.string() + " --quiet", dir / "free");
  ASSERT_EQ(u.status, 0) << u.output;
  ASSERT_EQ(c.status, 0) << c.output;
  const pbve::Report free = pbve::read_report(dir / "free.json");
  const pbve::Report ctrl = pbve::read_report(dir / "report.json");
  ASSERT_EQ(free.frames.size(), 20u);
  ASSERT_EQ(ctrl.frames.size(), 20u);
  EXPECT_TRUE(ctrl.complete);
  EXPECT_EQ(pbve::Footage::open_video(dir / "edited.mp4").frame_count(), 20);
  // The criterion: unconstrained at least 5%, constrained at most 1%.
  EXPECT_GE(free.summary().violation_pct_mean, 5.0);
  EXPECT_LE(ctrl.summary().violation_pct_mean, 1.0);
}

// `pbve synth --engine`: the scene names the engine (and Bullet's reduced control space); the
// fractured statue cannot be mass_spring.
TEST(BulletSynth, EngineOptionWritesTheScene) {
  if (!fs::exists(pbve_binary()))
    GTEST_SKIP() << pbve_binary() << " was not built (PBVE_BUILD_EXAMPLES=OFF)";
  pbve::test::TempDir dir;
  CmdResult r = pbve_cmd("synth --engine bullet --frames 2 --size 64x48 --supersample 1 " +
                         (dir / "b").string());
  ASSERT_EQ(r.status, 0) << r.output;
  const std::string text = pbve::test::read_text(dir / "b" / "scene.yaml");
  EXPECT_NE(text.find("engine: bullet"), std::string::npos) << text;
  EXPECT_NE(text.find("clusters: 16"), std::string::npos) << text;
  r = pbve_cmd("synth --shape statue --engine mass_spring --image --frames 2 --size 64x48 " +
               (dir / "s").string());
  EXPECT_NE(r.status, 0);
  EXPECT_NE(r.output.find("needs engine bullet"), std::string::npos) << r.output;
  r = pbve_cmd("synth --engine physx --frames 2 --size 64x48 " + (dir / "p").string());
  EXPECT_NE(r.status, 0);
  EXPECT_NE(r.output.find("unknown engine"), std::string::npos) << r.output;
}

// The elastic figurine through Bullet (`pbve synth --shape figurine --engine bullet`): the
// scene is Bullet's elastic preset (no mass_spring regions) and the pushed figurine is
// simulated through the first stop (frame 18) without diverging.
TEST(BulletSynth, ElasticFigurineRuns) {
  if (!fs::exists(pbve_binary()))
    GTEST_SKIP() << pbve_binary() << " was not built (PBVE_BUILD_EXAMPLES=OFF)";
  pbve::test::TempDir dir;
  const CmdResult s = pbve_cmd(
      "synth --shape figurine --motion push --engine bullet --frames 24 --size 160x120 "
      "--supersample 1 " +
      dir.path().string());
  ASSERT_EQ(s.status, 0) << s.output;
  const std::string text = pbve::test::read_text(dir / "scene.yaml");
  EXPECT_EQ(text.find("regions"), std::string::npos) << text;
  const CmdResult r = pbve_cmd("edit " + (dir / "scene.yaml").string() + " --no-control --quiet");
  ASSERT_EQ(r.status, 0) << r.output;
  const pbve::Report rep = pbve::read_report(dir / "report.json");
  ASSERT_EQ(rep.frames.size(), 24u);
  EXPECT_TRUE(rep.complete);
  for (const auto& f : rep.frames) EXPECT_EQ(f.substep_factor, 1) << "frame " << f.index;
}

// Example 1 through Bullet, small: `pbve synth --engine bullet` writes the Bullet board scene
// (the board's faces as one sheet, 10 substeps of 10 solver passes, central differences over 16
// clusters); the test coarsens the board to 10 cm edges (130 vertices), renders 320 x 240 and
// runs the first 32 frames, where the swung cloth overshoots the board's first turn and shows
// its back. The criterion: unconstrained at least 5%, constrained at most 1%.
TEST(BulletBoardToCloth, ControlKeepsTheBackOfTheSwungClothHidden) {
  if (!fs::exists(pbve_binary()))
    GTEST_SKIP() << pbve_binary() << " was not built (PBVE_BUILD_EXAMPLES=OFF)";
  pbve::test::TempDir dir;
  const CmdResult s = pbve_cmd("synth --engine bullet --frames 32 --size 320x240 --supersample 1 " +
                               dir.path().string());
  ASSERT_EQ(s.status, 0) << s.output;
  const fs::path scene = dir / "scene.yaml";
  ASSERT_TRUE(replace_in(scene, "refine: 0.05", "refine: 0.1"));
  const auto [u, c] =
      pbve::test::edit_without_and_with_control(scene.string() + " --quiet", dir / "free");
  ASSERT_EQ(u.status, 0) << u.output;
  ASSERT_EQ(c.status, 0) << c.output;
  const pbve::Report free = pbve::read_report(dir / "free.json");
  const pbve::Report ctrl = pbve::read_report(dir / "report.json");
  EXPECT_EQ(ctrl.engine, "bullet");
  ASSERT_EQ(free.frames.size(), 32u);
  ASSERT_EQ(ctrl.frames.size(), 32u);
  EXPECT_TRUE(ctrl.complete);
  EXPECT_GE(free.summary().violation_pct_mean, 5.0);
  EXPECT_LE(ctrl.summary().violation_pct_mean, 1.0);
}

// Fracture pieces from a mesh file: an OBJ with one group per piece, each piece a closed box
// with its own vertices and its cut faces in the material `interior`. The three pieces fill the
// statue block of `pbve synth --shape statue --image` (which the scene then loads instead of
// fracturing it), fall 12 cm, land on the ground and on each other, and stay in the picture.
TEST(BulletFracture, PiecesFromAnObjWithOneGroupPerPiece) {
  if (!fs::exists(pbve_binary()))
    GTEST_SKIP() << pbve_binary() << " was not built (PBVE_BUILD_EXAMPLES=OFF)";
  pbve::test::TempDir dir;
  const CmdResult s = pbve_cmd(
      "synth --shape statue --motion still --image --frames 24 --size 320x240 --supersample 1 " +
      dir.path().string());
  ASSERT_EQ(s.status, 0) << s.output;
  // The block [-0.07, 0.07] x [0, 0.3] x [-0.05, 0.05]: a top half, and a bottom half cut in two.
  struct Box {
    const char* name;
    double x0, x1, y0, y1;
    std::vector<std::string> cut;  // faces on a cut: x0, x1, y0, y1
  };
  const std::vector<Box> boxes = {{"piece_top", -0.07, 0.07, 0.0, 0.15, {"y1"}},
                                  {"piece_left", -0.07, 0.0, 0.15, 0.3, {"y0", "x1"}},
                                  {"piece_right", 0.0, 0.07, 0.15, 0.3, {"y0", "x0"}}};
  // Vertex i of a box: x from bit 0, y from bit 1, z from bit 2; quads counter-clockwise seen
  // from outside (as pbve::make_box_mesh).
  const int quads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4},
                           {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
  const char* sides[6] = {"z0", "z1", "y0", "y1", "x0", "x1"};
  std::ofstream obj(dir / "pieces.obj");
  int base = 1;
  for (const Box& b : boxes) {
    obj << "g " << b.name << "\n";
    for (int i = 0; i < 8; ++i)
      obj << "v " << ((i & 1) ? b.x1 : b.x0) << " " << ((i & 2) ? b.y1 : b.y0) << " "
          << ((i & 4) ? 0.05 : -0.05) << "\n";
    for (int q = 0; q < 6; ++q) {
      const bool cut = std::find(b.cut.begin(), b.cut.end(), sides[q]) != b.cut.end();
      obj << "usemtl " << (cut ? "interior" : "stone") << "\n";
      const int* f = quads[q];
      obj << "f " << base + f[0] << " " << base + f[1] << " " << base + f[2] << "\n";
      obj << "f " << base + f[0] << " " << base + f[2] << " " << base + f[3] << "\n";
    }
    base += 8;
  }
  obj.close();
  const pbve::Mesh pieces = pbve::load_mesh(dir / "pieces.obj");
  ASSERT_EQ(pieces.num_parts(), 3);
  EXPECT_EQ(std::count(pieces.interior.begin(), pieces.interior.end(), 1), 10);

  const fs::path scene = dir / "scene.yaml";
  ASSERT_TRUE(replace_in(scene, "mesh: object.obj", "mesh: pieces.obj"));
  ASSERT_TRUE(replace_in(scene, "  fracture: {pieces: 8, seed: 1}\n", ""));
  const auto [u, c] =
      pbve::test::edit_without_and_with_control(scene.string() + " --quiet", dir / "free");
  ASSERT_EQ(u.status, 0) << u.output;
  ASSERT_EQ(c.status, 0) << c.output;
  for (const char* name : {"free.json", "report.json"}) {
    SCOPED_TRACE(name);
    const pbve::Report r = pbve::read_report(dir / name);
    EXPECT_EQ(r.engine, "bullet");
    EXPECT_TRUE(r.complete);
    ASSERT_EQ(r.frames.size(), 24u);
    // The pieces fall (gravity and then contacts act on them) and stay in the picture.
    for (size_t i = 1; i < r.frames.size(); ++i) EXPECT_GT(r.frames[i].physical_force, 0.0);
    EXPECT_GT(r.frames.back().visible_area_px, 0.5 * r.frames.front().visible_area_px);
  }
  // The same pieces as the engine builds them from the scene: three bodies (the mesh's
  // connected parts) that fall 12 cm onto the ground (y = 0.3) and, within two seconds, come
  // to rest on it and on each other.
  const pbve::PoseTrack track = pbve::load_pose_file(dir / "poses.txt");
  ASSERT_TRUE(track.poses.front());
  pbve::bullet::Params p = pbve::bullet::Params::preset(pbve::bullet::Material::rigid);
  pbve::bullet::Plane ground;
  ground.point = Eigen::Vector3d(0, 0.30, 0);
  ground.friction = 0.6;
  p.planes.push_back(ground);
  pbve::bullet::BulletSimulator sim(pieces, track.poses.front()->apply(pieces.vertices), {}, p);
  ASSERT_EQ(sim.num_bodies(), 3);
  const pbve::Vertices c0 = sim.centers_of_mass();
  pbve::StepInput in;
  in.dt = 1.0 / 30.0;
  for (int k = 0; k < 60; ++k) sim.step(in);
  const pbve::Vertices x = sim.positions();
  EXPECT_LT(x.col(1).maxCoeff(), 0.30 + 1e-3);  // nothing below the ground
  EXPECT_GT(x.col(1).maxCoeff(), 0.30 - 3e-3);  // resting on it
  const pbve::Vertices c1 = sim.centers_of_mass();
  for (int b = 0; b < 3; ++b) EXPECT_GT(c1(b, 1) - c0(b, 1), 0.08) << "piece " << b;
  EXPECT_LT(sim.velocities().rowwise().norm().maxCoeff(), 0.05);
}

}  // namespace
