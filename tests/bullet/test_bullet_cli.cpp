// End-to-end: `pbve synth` then `pbve edit` with `engine: bullet` on a small board clip.

#include <sys/wait.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include <gtest/gtest.h>

#include "pbve/core/footage.hpp"
#include "pbve/edit/report.hpp"
#include "support/test_util.hpp"

namespace {

namespace fs = std::filesystem;

const fs::path kPbve = fs::path(PBVE_BINARY_DIR) / "bin" / "pbve";

struct CmdResult {
  int status = -1;
  std::string output;
};

CmdResult pbve_cmd(const std::string& args) {
  const std::string cmd = kPbve.string() + " " + args + " 2>&1";
  CmdResult r;
  FILE* p = ::popen(cmd.c_str(), "r");
  if (!p) return r;
  char buf[4096];
  while (size_t n = std::fread(buf, 1, sizeof buf, p)) r.output.append(buf, n);
  const int st = ::pclose(p);
  r.status = WIFEXITED(st) ? WEXITSTATUS(st) : -1;
  return r;
}

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
    if (!fs::exists(kPbve)) GTEST_SKIP() << kPbve << " was not built (PBVE_BUILD_EXAMPLES=OFF)";
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

}  // namespace
