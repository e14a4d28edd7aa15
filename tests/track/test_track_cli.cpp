// `pbve track` end to end: pose file and overlay written, errors for a missing initial pose and
// bad correspondences.

#include <algorithm>
#include <csignal>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "pbve/core/footage.hpp"
#include "pbve/core/pose.hpp"
#include "pbve/edit/synth.hpp"
#include "pbve/track/tracker.hpp"
#include "support/cli.hpp"
#include "support/test_util.hpp"

namespace {

namespace fs = std::filesystem;
using pbve::test::CmdResult;
using pbve::test::pbve_binary;
using pbve::test::pbve_cmd;
using pbve::test::read_text;

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

TEST_F(TrackCli, InitialPoseAndCorrespondencesTogetherAreAUsageError) {
  std::ofstream(dir / "pairs.txt") << "0 10 10\n";
  const CmdResult r =
      pbve_cmd(base() + "--initial-pose " + (dir / "init.txt").string() + " --correspondences " +
               (dir / "pairs.txt").string() + " -o " + (dir / "tracked.txt").string());
  EXPECT_EQ(r.status, 2) << r.output;
  EXPECT_NE(r.output.find("--initial-pose and --correspondences exclude each other"),
            std::string::npos)
      << r.output;
  EXPECT_FALSE(fs::exists(dir / "tracked.txt"));
}

TEST_F(TrackCli, OutputsThatAreInputsOrEachOtherAreRefusedBeforeAnyWork) {
  const std::string init = read_text(dir / "init.txt");
  CmdResult r = pbve_cmd(base() + "--initial-pose " + (dir / "init.txt").string() + " -o " +
                         (dir / "sub" / ".." / "init.txt").string());
  EXPECT_EQ(r.status, 1) << r.output;  // as `pbve edit` refuses its outputs
  EXPECT_NE(r.output.find("would overwrite the input"), std::string::npos) << r.output;
  EXPECT_EQ(read_text(dir / "init.txt"), init);
  const std::string clip = read_text(dir / "clip.mp4");
  r = pbve_cmd(base() + "--initial-pose " + (dir / "init.txt").string() + " -o " +
               (dir / "a.txt").string() + " --overlay " + (dir / "clip.mp4").string());
  EXPECT_EQ(r.status, 1) << r.output;
  EXPECT_EQ(read_text(dir / "clip.mp4"), clip);
  r = pbve_cmd(base() + "--initial-pose " + (dir / "init.txt").string() + " -o " +
               (dir / "a.txt").string() + " --log " + (dir / "a.txt").string());
  EXPECT_EQ(r.status, 1) << r.output;
  EXPECT_NE(r.output.find("two outputs are the same file"), std::string::npos) << r.output;
  r = pbve_cmd(base() + "--initial-pose " + (dir / "init.txt").string() + " -o " +
               (dir / "a.txt").string() + " --log " + (dir / "no_such" / "log.csv").string());
  EXPECT_EQ(r.status, 1) << r.output;
  EXPECT_NE(r.output.find("the output folder"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("frame "), std::string::npos) << r.output;  // nothing tracked
  EXPECT_FALSE(fs::exists(dir / "a.txt"));
}

TEST_F(TrackCli, SigtermStopsWithoutWritingAnything) {
  const CmdResult s =
      pbve_cmd("synth --motion orbit --frames 240 --supersample 1 " + d() + "/long");
  ASSERT_EQ(s.status, 0) << s.output;
  pbve::test::PbveProcess p({"track", (dir / "long" / "clip.mp4").string(),
                             (dir / "long" / "object.obj").string(), "--camera",
                             "600,600,319.5,239.5", "--initial-pose", (dir / "init.txt").string(),
                             "-o", (dir / "long" / "tracked.txt").string(), "--overlay",
                             (dir / "long" / "overlay.mp4").string()});
  ASSERT_TRUE(p.started());
  ASSERT_TRUE(p.wait_for_line("frame 30/240")) << p.output();
  p.send(SIGTERM);
  EXPECT_EQ(p.wait(), 130) << p.output();
  EXPECT_NE(p.output().find("interrupted at frame"), std::string::npos) << p.output();
  for (const char* name :
       {"tracked.txt", "tracked.partial.txt", "overlay.mp4", "overlay.partial.mp4"})
    EXPECT_FALSE(fs::exists(dir / "long" / name)) << name;
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

// Pairs no pose can come from (mesh points on one line, or all one point) are an error naming
// the file and what is wrong with them, with status 1 and nothing written; OpenCV's assertion
// messages used to reach the terminal instead.
TEST_F(TrackCli, DegenerateCorrespondencesNameTheFileAndWhatIsWrong) {
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"0 0 0 300 200\n0.1 0 0 310 205\n0.2 0 0 320 210\n0.3 0 0 330 215\n",
       "pairs.txt: correspondences: all 4 mesh points lie on one line"},
      {"0.1 0.1 0.1 300 200\n0.1 0.1 0.1 310 205\n0.1 0.1 0.1 320 210\n0.1 0.1 0.1 330 215\n",
       "pairs.txt: correspondences: all 4 mesh points are the same point"},
      {"3 300 200\n3 310 205\n3 320 210\n3 330 215\n",
       "pairs.txt: correspondences: all 4 mesh points are the same point"},
  };
  for (const auto& [text, what] : cases) {
    std::ofstream(dir / "pairs.txt") << text;
    const CmdResult r = pbve_cmd(base() + "--correspondences " + (dir / "pairs.txt").string() +
                                 " -o " + (dir / "tracked.txt").string() + " --quiet");
    EXPECT_EQ(r.status, 1) << r.output;
    EXPECT_NE(r.output.find("pbve track: error: "), std::string::npos) << r.output;
    EXPECT_NE(r.output.find(what), std::string::npos) << r.output;
    EXPECT_EQ(r.output.find("OpenCV"), std::string::npos) << r.output;
    EXPECT_FALSE(fs::exists(dir / "tracked.txt"));
  }
}

TEST_F(TrackCli, ObjectLeavingTheViewForGoodExitsWithStatus1AndLostFrames) {
  // The board of the fixture's clip, still for 6 frames, then moving right out of the image.
  const pbve::Mesh mesh = pbve::load_mesh(dir / "object.obj");
  const pbve::Pose first = *pbve::load_pose_file(dir / "init.txt").poses[0];
  const cv::Mat background = pbve::make_background(cv::Size(640, 480), 7);
  pbve::Camera cam;
  cam.fx = cam.fy = 600;
  cam.cx = 319.5;
  cam.cy = 239.5;
  cam.width = 640;
  cam.height = 480;
  {
    pbve::VideoWriter w(dir / "leaving.mkv", 30.0, cv::Size(640, 480));
    for (int t = 0; t < 30; ++t) {
      pbve::Pose p = first;
      p.translation.x() += t < 6 ? 0.0 : 0.05 * (t - 6);
      w.write(pbve::render_object(mesh, p, cam, pbve::procedural_texture(0.06), background, 1));
    }
    w.close();
  }
  const CmdResult r =
      pbve_cmd("track " + (dir / "leaving.mkv").string() + " " + (dir / "object.obj").string() +
               " --camera 600,600,319.5,239.5 --initial-pose " + (dir / "init.txt").string() +
               " -o " + (dir / "tracked.txt").string() + " --quiet");
  EXPECT_EQ(r.status, 1) << r.output;
  EXPECT_NE(r.output.find("the object left the view at frame"), std::string::npos) << r.output;
  const pbve::PoseTrack t = pbve::load_pose_file(dir / "tracked.txt");
  ASSERT_EQ(t.size(), 30);
  EXPECT_TRUE(t.poses[0]);
  EXPECT_FALSE(t.poses[29]);
}

// The synthesized scene with `poses: track` (and `extra` keys after it) instead of its pose file.
std::string tracking_scene(const fs::path& dir, const std::string& extra) {
  std::ifstream in(dir / "scene.yaml");
  std::stringstream ss;
  ss << in.rdbuf();
  std::string text = ss.str();
  const std::string from = "  poses: poses.txt\n";
  const size_t at = text.find(from);
  if (at == std::string::npos) return {};
  text.replace(at, from.size(), "  poses: track\n" + extra);
  std::ofstream(dir / "track_scene.yaml") << text;
  return text;
}

int line_of(const std::string& text, const std::string& needle) {
  const size_t at = text.find(needle);
  return at == std::string::npos
             ? -1
             : 1 + static_cast<int>(std::count(text.begin(), text.begin() + at, '\n'));
}

TEST_F(TrackCli, SceneWithPosesTrackTracksFirstThenEdits) {
  ASSERT_FALSE(tracking_scene(dir.path(), "  initial_pose: init.txt\n").empty());
  const CmdResult r = pbve_cmd("edit " + (dir / "track_scene.yaml").string() + " --no-control");
  ASSERT_EQ(r.status, 0) << r.output;
  EXPECT_NE(r.output.find("tracked poses:"), std::string::npos) << r.output;
  // The tracked poses next to the edited video, one per frame, close to the true ones.
  const pbve::PoseTrack tracked = pbve::load_pose_file(dir / "edited.poses.txt");
  const pbve::PoseTrack truth = pbve::load_pose_file(dir / "poses.txt");
  const pbve::Mesh mesh = pbve::load_mesh(dir / "object.obj");
  pbve::Camera cam;
  cam.fx = cam.fy = 600;
  cam.cx = 319.5;
  cam.cy = 239.5;
  cam.width = 640;
  cam.height = 480;
  ASSERT_EQ(tracked.size(), 12);
  for (int t = 0; t < 12; ++t) {
    ASSERT_TRUE(tracked.poses[static_cast<size_t>(t)]) << "frame " << t;
    EXPECT_LE(pbve::reprojection_error_px(mesh, cam, *tracked.poses[static_cast<size_t>(t)],
                                          *truth.poses[static_cast<size_t>(t)]),
              5.0)
        << "frame " << t;
  }
  std::ifstream report(dir / "report.json");
  std::stringstream rs;
  rs << report.rdbuf();
  EXPECT_NE(rs.str().find("\"tracking\""), std::string::npos);
  EXPECT_NE(rs.str().find("\"lost_frames\": []"), std::string::npos) << rs.str().substr(0, 400);
  EXPECT_TRUE(fs::exists(dir / "edited.mp4"));
}

TEST_F(TrackCli, PosesTrackTracksOnlyUpToTheEditedRange) {
  // An edit of frames 2-5 needs poses from frame 0 (the initial pose) to 5, not the whole clip.
  ASSERT_FALSE(tracking_scene(dir.path(), "  initial_pose: init.txt\n").empty());
  const CmdResult r =
      pbve_cmd("edit " + (dir / "track_scene.yaml").string() + " --no-control --frames 2:6");
  ASSERT_EQ(r.status, 0) << r.output;
  const pbve::PoseTrack tracked = pbve::load_pose_file(dir / "edited.poses.txt");
  ASSERT_EQ(tracked.size(), 6);
  EXPECT_EQ(tracked.lost_count(), 0);
  EXPECT_EQ(pbve::Footage::open_video(dir / "edited.mp4").frame_count(), 4);
  // A range past the clip is refused before any tracking: no poses written.
  fs::remove(dir / "edited.poses.txt");
  const CmdResult past =
      pbve_cmd("edit " + (dir / "track_scene.yaml").string() + " --no-control --frames 2:13");
  EXPECT_EQ(past.status, 1) << past.output;
  EXPECT_NE(past.output.find("frames 2:13 requested, but the footage has 12 frames"),
            std::string::npos)
      << past.output;
  EXPECT_FALSE(fs::exists(dir / "edited.poses.txt"));
}

TEST_F(TrackCli, EngineSettingsAreCheckedBeforeTracking) {
  // A bad material parameter or material is found before any tracking: no poses written.
  for (const std::string& bad :
       {std::string("  density: -1\n"), std::string("  material: rigid\n")}) {
    std::string text = tracking_scene(dir.path(), "  initial_pose: init.txt\n");
    ASSERT_FALSE(text.empty());
    if (bad.find("material") != std::string::npos)
      text.replace(text.find("  material: cloth\n"), 17, bad);
    else
      text.replace(text.find("simulation:\n"), 12, "simulation:\n" + bad);
    std::ofstream(dir / "track_scene.yaml") << text;
    const CmdResult r = pbve_cmd("edit " + (dir / "track_scene.yaml").string() + " --no-control");
    EXPECT_EQ(r.status, 1) << r.output;
    const std::string key = bad.substr(2, bad.find(':') - 2);
    EXPECT_NE(r.output.find("track_scene.yaml:" + std::to_string(line_of(text, bad)) +
                            ": key 'simulation." + key + "'"),
              std::string::npos)
        << r.output;
    EXPECT_EQ(r.output.find("tracked poses"), std::string::npos) << r.output;
    EXPECT_FALSE(fs::exists(dir / "edited.poses.txt")) << bad;
  }
}

TEST_F(TrackCli, PosesTrackWithoutAnInitialPoseNamesTheKeyAndLine) {
  const std::string text = tracking_scene(dir.path(), "");
  ASSERT_FALSE(text.empty());
  const CmdResult r = pbve_cmd("edit " + (dir / "track_scene.yaml").string());
  EXPECT_EQ(r.status, 1) << r.output;
  const std::string where =
      "track_scene.yaml:" + std::to_string(line_of(text, "poses: track")) + ": key 'object.poses'";
  EXPECT_NE(r.output.find(where), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("needs the pose in the first frame"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir / "edited.mp4"));
}

TEST_F(TrackCli, TrackingKeysWithoutPosesTrackAreErrors) {
  std::ifstream in(dir / "scene.yaml");
  std::stringstream ss;
  ss << in.rdbuf();
  std::string text = ss.str();
  const std::string from = "  poses: poses.txt\n";
  text.replace(text.find(from), from.size(), from + "  initial_pose: init.txt\n");
  std::ofstream(dir / "bad.yaml") << text;
  const CmdResult r = pbve_cmd("edit " + (dir / "bad.yaml").string());
  EXPECT_EQ(r.status, 1) << r.output;
  const std::string where = "bad.yaml:" + std::to_string(line_of(text, "initial_pose")) +
                            ": key 'object.initial_pose': only used with 'poses: track'";
  EXPECT_NE(r.output.find(where), std::string::npos) << r.output;
  // A missing initial pose file names its key.
  tracking_scene(dir.path(), "  initial_pose: missing.txt\n");
  const CmdResult m = pbve_cmd("edit " + (dir / "track_scene.yaml").string());
  EXPECT_EQ(m.status, 1) << m.output;
  EXPECT_NE(m.output.find("key 'object.initial_pose': initial pose file not found"),
            std::string::npos)
      << m.output;
}

}  // namespace
