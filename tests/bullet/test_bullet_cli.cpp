// End-to-end: `pbve synth` then `pbve edit` with `engine: bullet` on a small board clip.

#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include <gtest/gtest.h>

#include "pbve/core/footage.hpp"
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
  const CmdResult u =
      pbve_cmd("edit " + scene.string() + " --no-control -o " + (dir / "free.mp4").string() +
               " --report " + (dir / "free.json").string() + " --quiet");
  ASSERT_EQ(u.status, 0) << u.output;
  const CmdResult c = pbve_cmd("edit " + scene.string() + " --quiet");
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

}  // namespace
