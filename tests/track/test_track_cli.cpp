// `pbve track` end to end: pose file and overlay written, errors for a missing initial pose and
// bad correspondences.

#include <filesystem>
#include <fstream>
#include <string>

#include <gtest/gtest.h>

#include "pbve/core/footage.hpp"
#include "pbve/core/pose.hpp"
#include "support/cli.hpp"
#include "support/test_util.hpp"

namespace {

namespace fs = std::filesystem;
using pbve::test::CmdResult;
using pbve::test::pbve_binary;
using pbve::test::pbve_cmd;

class TrackCli : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!fs::exists(pbve_binary()))
      GTEST_SKIP() << pbve_binary() << " was not built (PBVE_BUILD_EXAMPLES=OFF)";
    const CmdResult r = pbve_cmd("synth --motion orbit --frames 12 --supersample 1 " + d());
    ASSERT_EQ(r.status, 0) << r.output;
    // The first true pose as the initial pose.
    std::ifstream in(dir / "poses.txt");
    std::string line;
    while (std::getline(in, line) && (line.empty() || line[0] == '#')) {
    }
    std::ofstream(dir / "init.txt") << line << "\n";
  }
  std::string d() const { return dir.path().string(); }
  std::string base() const {
    return "track " + (dir / "clip.mp4").string() + " " + (dir / "object.obj").string() +
           " --camera 600,600,319.5,239.5 ";
  }
  pbve::test::TempDir dir;
};

TEST_F(TrackCli, WritesOnePosePerFrameAndAnOverlay) {
  const CmdResult r =
      pbve_cmd(base() + "--initial-pose " + (dir / "init.txt").string() + " -o " +
               (dir / "tracked.txt").string() + " --overlay " + (dir / "overlay.mp4").string() +
               " --truth " + (dir / "poses.txt").string() + " --quiet");
  ASSERT_EQ(r.status, 0) << r.output;
  const pbve::PoseTrack t = pbve::load_pose_file(dir / "tracked.txt");
  EXPECT_EQ(t.size(), 12);
  EXPECT_EQ(t.lost_count(), 0);
  EXPECT_EQ(pbve::Footage::open_video(dir / "overlay.mp4").frame_count(), 12);
  EXPECT_NE(r.output.find("reprojection error against"), std::string::npos) << r.output;
}

TEST_F(TrackCli, FourVertexCorrespondencesStartItToo) {
  // Vertices 0, 1, 2 and 7 of the board at their true pixels in frame 0.
  const pbve::Pose p = *pbve::load_pose_file(dir / "init.txt").poses[0];
  const pbve::Mesh m = pbve::load_mesh(dir / "object.obj");
  std::ofstream f(dir / "pairs.txt");
  f << "# vertex u v\n";
  for (int v : {0, 1, 2, 7}) {
    const Eigen::Vector3d c = p.apply(Eigen::Vector3d(m.vertices.row(v)));
    f << v << " " << 600 * c.x() / c.z() + 319.5 << " " << 600 * c.y() / c.z() + 239.5 << "\n";
  }
  f.close();
  const CmdResult r = pbve_cmd(base() + "--correspondences " + (dir / "pairs.txt").string() +
                               " -o " + (dir / "tracked.txt").string() + " --quiet");
  ASSERT_EQ(r.status, 0) << r.output;
  EXPECT_EQ(pbve::load_pose_file(dir / "tracked.txt").size(), 12);
}

TEST_F(TrackCli, MissingInitialPoseIsAUsageError) {
  const CmdResult r = pbve_cmd(base() + "-o " + (dir / "tracked.txt").string());
  EXPECT_EQ(r.status, 2) << r.output;
  EXPECT_NE(r.output.find("the initial pose is missing"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir / "tracked.txt"));
}

TEST_F(TrackCli, BadCorrespondenceLineNamesFileAndLine) {
  std::ofstream(dir / "pairs.txt") << "0 10 10\n1 20 x\n";
  const CmdResult r = pbve_cmd(base() + "--correspondences " + (dir / "pairs.txt").string() +
                               " -o " + (dir / "tracked.txt").string());
  EXPECT_EQ(r.status, 1) << r.output;
  EXPECT_NE(r.output.find("pairs.txt:2: expected a number, found 'x'"), std::string::npos)
      << r.output;
  EXPECT_FALSE(fs::exists(dir / "tracked.txt"));
}

}  // namespace
