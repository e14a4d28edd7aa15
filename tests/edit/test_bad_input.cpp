// Bad input through the pbve command: every case must fail (or warn) with a message that says
// what is wrong and where (file, line, key), and leave no file under the output names — the
// edited video and the report are written under temporary names and renamed when complete.
//
// Each case starts from a tiny synthetic scene (64x48 pixels, 3 frames, --no-control) and
// breaks one thing in it.

#include <algorithm>
#include <filesystem>
#include <initializer_list>
#include <sstream>
#include <string>

#include <sys/stat.h>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "pbve/core/footage.hpp"
#include "pbve/edit/report.hpp"
#include "support/cli.hpp"
#include "support/test_util.hpp"

namespace {

namespace fs = std::filesystem;
using pbve::test::CmdResult;
using pbve::test::pbve_cmd;
using pbve::test::read_text;
using pbve::test::write_text;

/// 1-based number of the first line of `text` containing `needle` (0 if none).
int line_containing(const std::string& text, const std::string& needle) {
  const size_t at = text.find(needle);
  if (at == std::string::npos) return 0;
  return 1 + static_cast<int>(std::count(text.begin(), text.begin() + static_cast<long>(at), '\n'));
}

class BadInput : public ::testing::Test {
 protected:
  void SetUp() override {
    const CmdResult r =
        pbve_cmd("synth --size 64x48 --frames 3 --supersample 1 " + dir.path().string());
    ASSERT_EQ(r.status, 0) << r.output;
    scene = dir / "scene.yaml";
  }

  /// Replaces the first `from` in `file` by `to` (which must be there).
  void replace(const fs::path& file, const std::string& from, const std::string& to) {
    std::string text = read_text(file);
    const size_t at = text.find(from);
    ASSERT_NE(at, std::string::npos) << from << " not in " << file;
    text.replace(at, from.size(), to);
    write_text(file, text);
  }
  /// Replaces the scene line starting with `prefix` (after indentation) by `line`.
  void replace_scene_line(const std::string& prefix, const std::string& line) {
    std::string text = read_text(scene);
    const size_t at = text.find(prefix);
    ASSERT_NE(at, std::string::npos) << prefix;
    const size_t bol = text.rfind('\n', at) + 1;
    text.replace(bol, text.find('\n', at) - bol, line);
    write_text(scene, text);
  }
  /// Sets value `index` (1-based) of line `line` (1-based) of the pose file to `value`.
  void set_pose_value(int line, int index, const std::string& value) {
    std::istringstream in(read_text(dir / "poses.txt"));
    std::string out, text;
    for (int l = 1; std::getline(in, text); ++l) {
      if (l == line) {
        std::istringstream fields(text);
        std::string field, rebuilt;
        for (int k = 1; fields >> field; ++k)
          rebuilt += (k > 1 ? " " : "") + (k == index ? value : field);
        text = rebuilt;
      }
      out += text + "\n";
    }
    write_text(dir / "poses.txt", out);
  }
  /// Line of `needle` in the scene file.
  int scene_line(const std::string& needle) { return line_containing(read_text(scene), needle); }
  std::string location(const std::string& needle) {
    return "scene.yaml:" + std::to_string(scene_line(needle)) + ": ";
  }

  /// `pbve edit SCENE --quiet --no-control EXTRA`.
  CmdResult edit(const std::string& extra = {}) {
    return pbve_cmd("edit " + scene.string() + " --quiet --no-control " + extra);
  }

  /// Exit status 1, every piece of `expected` in the message, nothing under the output names.
  void expect_error(const CmdResult& r, std::initializer_list<std::string> expected,
                    std::initializer_list<fs::path> outputs = {}) {
    EXPECT_EQ(r.status, 1) << r.output;
    EXPECT_NE(r.output.find("pbve edit: error: "), std::string::npos) << r.output;
    for (const auto& e : expected)
      EXPECT_NE(r.output.find(e), std::string::npos) << e << "\n" << r.output;
    expect_no_output(outputs);
  }
  void expect_no_output(std::initializer_list<fs::path> outputs = {}) {
    std::vector<fs::path> all = {dir / "edited.mp4", dir / "report.json"};
    all.insert(all.end(), outputs.begin(), outputs.end());
    for (const auto& p : all) {
      EXPECT_FALSE(fs::exists(p)) << p;
      EXPECT_FALSE(fs::exists(pbve::partial_path(p))) << pbve::partial_path(p);
    }
  }

  /// Runs and expects success with a warning containing every piece of `expected`, in the
  /// output and in the report.
  void expect_warning(std::initializer_list<std::string> expected) {
    const CmdResult r = edit();
    ASSERT_EQ(r.status, 0) << r.output;
    const pbve::Report rep = pbve::read_report(dir / "report.json");
    EXPECT_EQ(rep.frames.size(), 3u);
    EXPECT_EQ(pbve::Footage::open_video(dir / "edited.mp4").frame_count(), 3);
    for (const auto& e : expected) {
      EXPECT_NE(r.output.find("warning: "), std::string::npos) << r.output;
      EXPECT_NE(r.output.find(e), std::string::npos) << e << "\n" << r.output;
      EXPECT_TRUE(std::any_of(rep.warnings.begin(), rep.warnings.end(), [&](const std::string& w) {
        return w.find(e) != std::string::npos;
      })) << e;
    }
  }

  pbve::test::TempDir dir;
  fs::path scene;
};

// ---- the scene file --------------------------------------------------------------------------

TEST_F(BadInput, MissingSceneFile) {
  fs::remove(scene);
  expect_error(edit(), {"scene.yaml: scene file not found"});
}

TEST_F(BadInput, SceneFileIsAFolder) {
  fs::remove(scene);
  fs::create_directory(scene);
  expect_error(edit(), {"scene.yaml: the scene file is a folder"});
}

TEST_F(BadInput, EmptySceneFile) {
  write_text(scene, "# nothing here\n");
  expect_error(edit(), {"scene.yaml: the scene file is empty"});
}

TEST_F(BadInput, MalformedYamlNamesTheLine) {
  replace(scene, "  scale: 1.01", "  scale: 1.01: 2");
  expect_error(edit(), {location("scale:") + "YAML syntax error"});
}

TEST_F(BadInput, UnknownTopLevelKeySuggestsTheNearest) {
  replace(scene, "output:", "outptu:");
  expect_error(edit(),
               {location("outptu:") + "key 'outptu': unknown key", "did you mean 'output'?"});
}

TEST_F(BadInput, MistypedCameraKeySuggestsTheNearest) {
  replace(scene, "fx:", "fxx:");
  expect_error(edit(), {location("fxx:") + "key 'camera.fxx': unknown key", "did you mean 'fx'?"});
}

TEST_F(BadInput, MistypedMaterialParameterSuggestsTheNearest) {
  replace(scene, "  substeps: 3", "  substeps: 3\n  densty: 30");
  expect_error(edit(),
               {location("densty:") + "key 'simulation.densty'", "did you mean 'density'?"});
}

TEST_F(BadInput, RegionParameterTheEngineLacksNamesTheKey) {
  replace(scene, "  substeps: 3",
          "  substeps: 3\n  regions: [{box: {min: [0, 0, 0], max: [1, 1, 1]}, densty: 30}]");
  expect_error(edit(), {location("regions:") + "key 'simulation.regions.densty'",
                        "a region sets volume_stiffness"});
}

TEST_F(BadInput, RegionsOfACloth) {
  replace(
      scene, "  substeps: 3",
      "  substeps: 3\n  regions: [{box: {min: [0, 0, 0], max: [1, 1, 1]}, volume_stiffness: 30}]");
  expect_error(edit(), {location("regions:") + "key 'simulation.regions': regions apply to solids "
                                               "(material elastic or stiff), not to cloth"});
}

TEST_F(BadInput, AParameterOfAnotherMaterialNamesTheKey) {
  // The synthetic scene is a cloth: an interior lattice's spacing would be ignored.
  replace(scene, "  substeps: 3", "  substeps: 3\n  lattice_spacing: 0.01");
  expect_error(edit(), {location("lattice_spacing:") + "key 'simulation.lattice_spacing': applies "
                                                       "to material elastic and stiff only, not "
                                                       "to cloth (engine mass_spring)"});
}

TEST_F(BadInput, AMisspeltNumericSimulationKeyNamesTheNearestOne) {
  replace(scene, "substeps: 3", "substep: 3");
  expect_error(edit(), {location("substep:") + "key 'simulation.substep': unknown key for engine "
                                               "mass_spring (did you mean 'substeps'?)"});
}

TEST_F(BadInput, WrongTypeNamesTheKey) {
  replace(scene, "substeps: 3", "substeps: many");
  expect_error(edit(), {location("substeps:") + "key 'simulation.substeps'",
                        "expected a number, found 'many'"});
}

TEST_F(BadInput, FractureWithOnePieceNamesTheKey) {
  replace(scene, "  scale: 1.01", "  scale: 1.01\n  fracture: {pieces: 1}");
  expect_error(edit(), {location("fracture:") + "key 'object.fracture.pieces'",
                        "must be between 2 and 1000, found 1"});
}

TEST_F(BadInput, FractureOfAConcaveMeshNamesTheVertex) {
  replace(scene, "  scale: 1.01", "  scale: 1.01\n  fracture: {pieces: 4}");
  // The board's last corner pushed into its middle: no longer convex.
  replace(dir / "object.obj", "v 0.2 0.3 0.005", "v 0 0.15 0");
  expect_error(edit(), {location("fracture:") + "key 'object.fracture'",
                        "fracture needs a convex mesh: vertex", "in front of the plane of a face"});
}

// ---- the mesh ----------------------------------------------------------------------------------

TEST_F(BadInput, MissingMesh) {
  fs::remove(dir / "object.obj");
  expect_error(edit(), {location("mesh:") + "key 'object.mesh': mesh file not found",
                        (dir / "object.obj").string()});
}

TEST_F(BadInput, UnreadableMesh) {
  // A folder in place of the file (file permissions do not stop a root user).
  fs::remove(dir / "object.obj");
  fs::create_directory(dir / "object.obj");
  expect_error(edit(), {location("mesh:") + "key 'object.mesh': mesh file is a folder"});
}

TEST_F(BadInput, EmptyMesh) {
  write_text(dir / "object.obj", "# no geometry\n");
  expect_error(edit(), {"object.obj: empty mesh: the file has no vertices"});
}

TEST_F(BadInput, FaceIndexOutOfRangeNamesTheLine) {
  std::string obj = read_text(dir / "object.obj");
  obj += "f 1 2 999\n";
  write_text(dir / "object.obj", obj);
  const int line = line_containing(obj, "f 1 2 999");
  expect_error(edit(), {"object.obj:" + std::to_string(line) + ": vertex index 999 out of range"});
}

TEST_F(BadInput, NonFiniteMeshVertexNamesTheLine) {
  const std::string obj = read_text(dir / "object.obj");
  const int line = line_containing(obj, "\nv ") + 1;
  replace(dir / "object.obj", "\nv ", "\nv nan ");
  // "v nan x y z" has 4 numbers; the first three are read, the first is NaN.
  expect_error(edit(), {"object.obj:" + std::to_string(line) + ": non-finite coordinate 'nan'"});
}

TEST_F(BadInput, MalformedPlyHeaderNamesTheLine) {
  write_text(dir / "object.ply", "ply\nformat ascii 1.0\nelement vertex three\nend_header\n");
  replace(scene, "object.obj", "object.ply");
  expect_error(edit(), {"object.ply:3: "});
}

TEST_F(BadInput, DegenerateTrianglesAreSimulatedWithAWarning) {
  // A triangle with a repeated vertex and one with three collinear vertices.
  std::string obj = read_text(dir / "object.obj");
  obj += "f 1 1 2\nv 0 0 0\nv 0.001 0 0\nv 0.002 0 0\nf -1 -2 -3\n";
  write_text(dir / "object.obj", obj);
  expect_warning({"object.obj: 2 degenerate triangles", "simulated as given"});
}

TEST_F(BadInput, NonManifoldMeshIsSimulatedWithAWarning) {
  // A third triangle on the edge 1-2.
  std::string obj = read_text(dir / "object.obj");
  obj += "v 0 0 0.05\nf 1 2 -1\n";
  write_text(dir / "object.obj", obj);
  expect_warning(
      {"object.obj: 1 non-manifold edge shared by more than two triangles", "simulated as given"});
}

TEST_F(BadInput, MeshWithOnlyDegenerateTrianglesFails) {
  write_text(dir / "object.obj", "v 0 0 0\nv 0.05 0 0\nv 0.1 0 0\nf 1 2 3\nf 3 2 1\n");
  replace_scene_line("anchors:", "  anchors: {vertices: [0]}");
  expect_error(edit(), {"object.obj: every triangle of the mesh is degenerate"});
}

// ---- the footage -------------------------------------------------------------------------------

TEST_F(BadInput, MissingVideo) {
  fs::remove(dir / "clip.mp4");
  expect_error(edit(), {location("video: clip") + "key 'input.video': video file not found",
                        (dir / "clip.mp4").string()});
}

TEST_F(BadInput, GarbageVideoHasNoDecodableFrame) {
  std::string noise(4000, '\0');
  for (size_t i = 0; i < noise.size(); ++i) noise[i] = static_cast<char>((i * 7919u) >> 3);
  write_text(dir / "clip.mp4", noise);
  expect_error(edit(), {"clip.mp4: not a readable video"});
}

TEST_F(BadInput, TruncatedVideoHasNoDecodableFrame) {
  const std::string video = read_text(dir / "clip.mp4");
  write_text(dir / "clip.mp4", video.substr(0, video.size() / 3));
  expect_error(edit(), {"clip.mp4: ", "video"});
}

TEST_F(BadInput, EmptyImageSequence) {
  replace_scene_line("input:", "input: {sequence: frames/%04d.png, fps: 30}");
  expect_error(edit(), {"frames/%04d.png: empty image sequence"});
}

TEST_F(BadInput, FramesOutsideTheFootage) {
  expect_error(edit("--frames 10:20"),
               {"clip.mp4: frames 10:20 requested, but the footage has 3 frames"});
  // An end past the footage is not cut short silently.
  expect_error(edit("--frames 1:200"),
               {"clip.mp4: frames 1:200 requested, but the footage has 3 frames (0:3)"});
}

TEST_F(BadInput, FramesThatAreNotWholeNumbersOrGivenTwice) {
  for (const auto& [option, message] :
       {std::pair<std::string, std::string>{"--frames 1x:3", "expects A:B with whole numbers"},
        {"--frames -1:3", "frame numbers start at 0"},
        {"--frames 0:1 --frames 1:2", "option --frames given twice"}}) {
    const CmdResult r = edit(option);
    EXPECT_EQ(r.status, 2) << option << "\n" << r.output;
    EXPECT_NE(r.output.find(message), std::string::npos) << option << "\n" << r.output;
    expect_no_output();
  }
}

// ---- the poses ---------------------------------------------------------------------------------

TEST_F(BadInput, MissingPoses) {
  fs::remove(dir / "poses.txt");
  expect_error(edit(), {location("poses:") + "key 'object.poses': pose file not found"});
}

TEST_F(BadInput, FewerPosesThanFramesNamesBothCounts) {
  const std::string poses = read_text(dir / "poses.txt");
  write_text(dir / "poses.txt", poses.substr(0, poses.find('\n', poses.find('\n') + 1) + 1));
  expect_error(edit(), {"poses.txt: the pose file has 2 poses but the footage has 3 frames"});
}

TEST_F(BadInput, MorePosesThanFramesWarnsAndRuns) {
  const std::string poses = read_text(dir / "poses.txt");
  write_text(dir / "poses.txt", poses + poses.substr(0, poses.find('\n') + 1));
  expect_warning({"the pose file has 4 poses for 3 frames: the extra poses are ignored"});
}

TEST_F(BadInput, APoseFileNeedsPosesOnlyUpToTheEditedRange) {
  // Two poses for a 3-frame clip: enough for --frames 0:2 (the third frame counts as lost for
  // the plate), not for the whole clip or for 1:3.
  const std::string poses = read_text(dir / "poses.txt");
  write_text(dir / "poses.txt", poses.substr(0, poses.find('\n', poses.find('\n') + 1) + 1));
  const CmdResult ok = edit("--frames 0:2");
  ASSERT_EQ(ok.status, 0) << ok.output;
  EXPECT_EQ(pbve::read_report(dir / "report.json").frames.size(), 2u);
  fs::remove(dir / "edited.mp4");
  fs::remove(dir / "report.json");
  expect_error(edit("--frames 1:3"),
               {"poses.txt: the pose file has 2 poses but the footage has 3 frames"});
}

TEST_F(BadInput, AMissingSequenceOrMaskSequenceNamesItsKey) {
  replace(scene, "input: {video: clip.mp4}", "input: {sequence: nope/%04d.png, fps: 30}");
  expect_error(edit(), {location("input:") + "key 'input.sequence': ",
                        "nope/%04d.png: empty image sequence"});
  replace(scene, "input: {sequence: nope/%04d.png, fps: 30}", "input: {video: clip.mp4}");
  replace(scene, "simulation:", "background: {remove: nope/%04d.png}\nsimulation:");
  expect_error(edit(), {location("background:") + "key 'background.remove': ",
                        "no mask file for the first frame"});
}

TEST_F(BadInput, AnUnreadableOrMisSizedMaskStopsTheRunBeforeAnyFrame) {
  // The plate is given, so no mask is read before the edit loop: the last frame's mask is
  // still checked before the first frame is edited. Frame 1 has no mask (an empty one).
  fs::create_directory(dir / "masks");
  ASSERT_TRUE(cv::imwrite((dir / "masks" / "0000.png").string(), cv::Mat::zeros(48, 64, CV_8UC1)));
  write_text(dir / "masks" / "0002.png", "not an image\n");
  write_text(scene,
             read_text(scene) + "background: {remove: masks/%04d.png, plate: plate_true.png}\n");
  expect_error(edit(), {location("background:") + "key 'background.remove': ",
                        "masks/0002.png: cannot read the mask"});
  ASSERT_TRUE(cv::imwrite((dir / "masks" / "0002.png").string(), cv::Mat::zeros(24, 32, CV_8UC1)));
  expect_error(edit(), {location("background:") + "key 'background.remove': ",
                        "masks/0002.png: mask is 32x24, the footage is 64x48"});
  // Frames 0 and 1 only: frame 2's mask is not needed, and the run goes through.
  const CmdResult r = edit("--frames 0:2");
  ASSERT_EQ(r.status, 0) << r.output;
  EXPECT_EQ(pbve::read_report(dir / "report.json").frames.size(), 2u);
}

TEST_F(BadInput, AFrameRateWithAVideoIsRefused) {
  replace(scene, "input: {video: clip.mp4}", "input: {video: clip.mp4, fps: 60}");
  expect_error(edit(), {location("input:") + "key 'input.fps': only used with input.image or "
                                             "input.sequence (a video has its own)"});
}

TEST_F(BadInput, AdjointGradientsWithAnEngineWithoutDerivatives) {
  if (read_text(dir / "scene.yaml").find("gradient: auto") == std::string::npos)
    GTEST_SKIP() << "the synthetic scene has no gradient key";
  replace(scene, "engine: mass_spring", "engine: bullet");
  replace(scene, "gradient: auto", "gradient: adjoint");
  const CmdResult r = pbve_cmd("edit " + scene.string() + " --quiet");
  if (r.output.find("not built") != std::string::npos ||
      r.output.find("is not one of") != std::string::npos)
    GTEST_SKIP() << "no Bullet in this build: " << r.output;
  expect_error(r, {location("gradient:") + "key 'control.gradient': gradient: adjoint requested "
                                           "but bullet offers no derivatives"});
}

TEST_F(BadInput, TheReportsSettingsAreTheRunsNotTheScenes) {
  const CmdResult r = pbve_cmd("edit " + scene.string() + " --quiet --no-control -o " +
                               (dir / "other.mp4").string());
  ASSERT_EQ(r.status, 0) << r.output;
  const std::string report = read_text(dir / "report.json");
  EXPECT_NE(report.find("\"enabled\": false"), std::string::npos) << report;
  EXPECT_NE(report.find("\"video\": \"" + fs::absolute(dir / "other.mp4").string() + "\""),
            std::string::npos)
      << report;
  EXPECT_NE(report.find("\"substeps\": 3"), std::string::npos) << report;
  EXPECT_EQ(report.find("\"substeps\": 3.0"), std::string::npos) << report;  // an integer
}

TEST_F(BadInput, NanInAPoseNamesTheLine) {
  set_pose_value(2, 1, "nan");
  expect_error(edit(), {"poses.txt:2: value 1 is not finite: 'nan'"});
}

TEST_F(BadInput, InfInAPoseNamesTheLine) {
  set_pose_value(3, 4, "inf");
  expect_error(edit(), {"poses.txt:3: value 4 is not finite: 'inf'"});
}

TEST_F(BadInput, PoseThatIsNotARotationNamesTheLine) {
  set_pose_value(2, 1, "2");  // scales the first row of the rotation
  expect_error(edit(), {"poses.txt:2: the 3x3 part is not a rotation"});
}

TEST_F(BadInput, PoseLineWithFiveNumbersNamesTheLine) {
  std::string poses = read_text(dir / "poses.txt");
  poses = "# comment line\n0 0 0 0 0\n" + poses;
  write_text(dir / "poses.txt", poses);
  expect_error(edit(), {"poses.txt:2: expected 16 or 6 numbers or 'lost', found 5"});
}

TEST_F(BadInput, EveryPoseLost) {
  write_text(dir / "poses.txt", "lost\nlost\nlost\n");
  expect_error(edit(), {"poses.txt: every pose is 'lost'"});
}

// ---- anchors -----------------------------------------------------------------------------------

TEST_F(BadInput, AnchorIndexOutOfRangeNamesTheKey) {
  replace_scene_line("anchors:", "  anchors: {vertices: [0, 9999]}");
  expect_error(edit(), {location("anchors:") + "key 'object.anchors.vertices': anchor vertex 9999 "
                                               "is out of range"});
}

TEST_F(BadInput, NegativeAnchorIndexNamesTheKey) {
  replace_scene_line("anchors:", "  anchors: {vertices: [-1]}");
  expect_error(edit(), {location("anchors:") + "key 'object.anchors.vertices'", "negative"});
}

TEST_F(BadInput, AnchorBoxSelectingNoVertexWarns) {
  replace_scene_line("anchors:", "  anchors: {box: {min: [5, 5, 5], max: [6, 6, 6]}}");
  expect_warning({location("anchors:") + "key 'object.anchors.box': selects no vertex"});
}

// ---- physical parameters -----------------------------------------------------------------------

TEST_F(BadInput, NegativeDensityNamesTheKey) {
  replace(scene, "  substeps: 3", "  substeps: 3\n  density: -1");
  expect_error(edit(),
               {location("density:") + "key 'simulation.density'", "density must be positive"});
}

TEST_F(BadInput, ZeroStiffnessNamesTheKey) {
  replace(scene, "  substeps: 3", "  substeps: 3\n  stretch_stiffness: 0");
  expect_error(edit(), {location("stretch_stiffness:") + "key 'simulation.stretch_stiffness'",
                        "stretch_stiffness must be positive"});
}

TEST_F(BadInput, AnIntegerParameterBeyondIntNamesTheKey) {
  replace(scene, "  substeps: 3", "  substeps: 3\n  newton_iterations: 3e9");
  expect_error(edit(), {location("newton_iterations:") + "key 'simulation.newton_iterations'",
                        "expected an integer, got one too large: 3e+09"});
  replace(scene, "newton_iterations: 3e9", "newton_iterations: 2.5");
  expect_error(edit(), {location("newton_iterations:") + "key 'simulation.newton_iterations'",
                        "expected an integer"});
}

TEST_F(BadInput, ZeroSubstepsNamesTheKey) {
  replace(scene, "substeps: 3", "substeps: 0");
  expect_error(edit(), {location("substeps:") + "key 'simulation.substeps': must be between 1"});
}

TEST_F(BadInput, NonPositiveFrameRateNamesTheKey) {
  // A single picture takes its frame rate (the time step 1/fps) from the scene.
  const cv::Mat frame = pbve::Footage::open_video(dir / "clip.mp4").frame(0);
  ASSERT_TRUE(cv::imwrite((dir / "picture.png").string(), frame));
  replace_scene_line("input:", "input: {image: picture.png, frames: 3, fps: 0}");
  expect_error(edit(), {location("input:") + "key 'input.fps': must be positive, found 0"});
}

// ---- camera ------------------------------------------------------------------------------------

TEST_F(BadInput, NonPositiveFocalLengthNamesTheKey) {
  replace(scene, "fy: 60", "fy: -60");
  expect_error(edit(), {location("camera:") + "key 'camera.fy': must be positive, found -60"});
}

TEST_F(BadInput, PrincipalPointOutsideTheImageNamesTheKey) {
  replace(scene, "cy: 23.5", "cy: 480");
  expect_error(edit(), {location("camera:") + "key 'camera.cy': principal point y 480 lies "
                                              "outside the image (height 48)"});
}

// ---- background --------------------------------------------------------------------------------

TEST_F(BadInput, MissingBackgroundPlate) {
  write_text(scene, read_text(scene) + "background: {plate: plate.png}\n");
  expect_error(edit(), {location("background:") + "key 'background.plate': background plate not "
                                                  "found"});
}

TEST_F(BadInput, UnreadableBackgroundPlate) {
  write_text(dir / "plate.png", "not an image");
  write_text(scene, read_text(scene) + "background: {plate: plate.png}\n");
  expect_error(edit(), {"plate.png: cannot read the background plate"});
}

TEST_F(BadInput, BackgroundPlateOfTheWrongSize) {
  write_text(scene, read_text(scene) + "background: {plate: plate_true.png}\n");
  ASSERT_TRUE(cv::imwrite((dir / "plate_true.png").string(), cv::Mat(10, 20, CV_8UC3)));
  expect_error(edit(), {"plate_true.png: background plate is 20x10, the footage is 64x48"});
}

TEST_F(BadInput, RefinementTooFineForAnyEditIsRefusedAtOnce) {
  // A length in millimetres where metres are meant: billions of vertices, the memory filled.
  replace(scene, "refine: 0.05", "refine: 0.000001");
  expect_error(edit(), {location("refine:") + "key 'object.refine': refining to edges of 1e-06 m "
                                              "would make more than 2000000 vertices"});
}

TEST_F(BadInput, PoseFartherThanAnyFilmedObject) {
  set_pose_value(2, 12, "1e20");  // t_z of the second pose
  expect_error(edit(), {"poses.txt:2: the translation is 1e+20 m from the camera"});
}

TEST_F(BadInput, ObjectBehindTheCameraInEveryFrame) {
  // Poses of an OpenGL camera (looking along -z): t_z negated in every pose.
  for (int line = 1; line <= 3; ++line) {
    std::istringstream in(read_text(dir / "poses.txt"));
    std::string text;
    for (int l = 1; std::getline(in, text) && l < line; ++l) {
    }
    std::istringstream fields(text);
    std::string field;
    for (int k = 1; fields >> field; ++k)
      if (k == 12) set_pose_value(line, 12, std::to_string(-std::stod(field)));
  }
  expect_error(edit(), {"poses.txt: the object is behind the camera in every edited frame",
                        "OpenCV camera axes"});
}

TEST_F(BadInput, NegativeRegionStiffnessNamesItsLine) {
  replace(scene, "material: cloth", "material: elastic");
  replace(scene, "  substeps: 3\n",
          "  substeps: 3\n  regions:\n    - {box: {min: [-1, -1, -1], max: [1, 1, 1]},\n"
          "       volume_stiffness: -5}\n");
  expect_error(edit(), {location("volume_stiffness: -5") +
                        "key 'simulation.regions.volume_stiffness': must be positive (Pa), found "
                        "-5"});
}

TEST_F(BadInput, DuplicateSceneKey) {
  write_text(scene, read_text(scene) + "control:\n  enabled: false\n");
  expect_error(edit(), {"key 'control': key given twice (first at line"});
}

// ---- outputs -----------------------------------------------------------------------------------

TEST_F(BadInput, OutputVideoEqualToTheInputVideo) {
  const std::string before = read_text(dir / "clip.mp4");
  expect_error(edit("-o " + (dir / "clip.mp4").string()),
               {"clip.mp4: the output would overwrite the input file"});
  EXPECT_EQ(read_text(dir / "clip.mp4"), before);
}

TEST_F(BadInput, ReportEqualToTheMeshNamesTheKey) {
  const std::string before = read_text(dir / "object.obj");
  replace(scene, "report: report.json", "report: object.obj");
  expect_error(edit(), {location("output:") + "key 'output.report': the output would overwrite "
                                              "the input file",
                        "object.obj"});
  EXPECT_EQ(read_text(dir / "object.obj"), before);
}

TEST_F(BadInput, VideoAndReportTheSameFileOnTheCommandLine) {
  // Two spellings of one new file in the current folder; the message names no scene key.
  const CmdResult r =
      pbve_cmd("edit " + scene.string() + " --quiet --no-control -o " + (dir / "e.mkv").string() +
               " --report " + (dir / "." / "e.mkv").string());
  EXPECT_EQ(r.status, 1) << r.output;
  EXPECT_NE(r.output.find("e.mkv: the video and the report would be the same file"),
            std::string::npos)
      << r.output;
  EXPECT_EQ(r.output.find("key 'output.report'"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir / "e.mkv"));
}

TEST_F(BadInput, VideoAndReportTheSameFile) {
  replace(scene, "report: report.json", "report: edited.mp4");
  expect_error(edit(), {location("output:") + "key 'output.report': the video and the report "
                                              "would be the same file"});
}

TEST_F(BadInput, OutputFolderMissing) {
  expect_error(edit("-o " + (dir / "no_such_folder" / "out.mp4").string()),
               {"out.mp4: the output folder", "no_such_folder does not exist"});
}

TEST_F(BadInput, OutputFolderUnwritable) {
  // /proc accepts no new files, even from root.
  expect_error(edit("--report /proc/pbve_report.json"),
               {"/proc/pbve_report.json: cannot create files in the output folder /proc"},
               {"/proc/pbve_report.json"});
}

TEST_F(BadInput, ReportOntoAFileOfAnInputSequence) {
  // Masks of extra regions to fill, one per frame: an output named like one of them would
  // overwrite it.
  fs::create_directory(dir / "masks");
  for (int i = 0; i < 3; ++i)
    ASSERT_TRUE(cv::imwrite((dir / "masks" / ("000" + std::to_string(i) + ".png")).string(),
                            cv::Mat::zeros(48, 64, CV_8UC1)));
  write_text(scene, read_text(scene) + "background: {remove: masks/%04d.png}\n");
  const std::string before = read_text(dir / "masks" / "0001.png");
  expect_error(
      edit("--report " + (dir / "masks" / "./0001.png").string()),
      {"0001.png: the output would overwrite a file of the input sequence", "masks/%04d.png"});
  EXPECT_EQ(read_text(dir / "masks" / "0001.png"), before);
  replace(scene, "masks/%04d.png", "masks/%04i.png");  // the other integer conversion
  expect_error(
      edit("--report " + (dir / "masks" / "0002.png").string()),
      {"0002.png: the output would overwrite a file of the input sequence", "masks/%04i.png"});
}

TEST_F(BadInput, ReportOntoTheInitialPoseOfTracking) {
  fs::copy_file(dir / "poses.txt", dir / "first.txt");
  replace(scene, "poses: poses.txt", "poses: track\n  initial_pose: first.txt");
  const std::string before = read_text(dir / "first.txt");
  expect_error(edit("--report " + (dir / "first.txt").string()),
               {"first.txt: the output would overwrite the input file"});
  EXPECT_EQ(read_text(dir / "first.txt"), before);
}

TEST_F(BadInput, TrackedPosesOntoTheReport) {
  replace(scene, "poses: poses.txt",
          "poses: track\n  initial_pose: poses.txt\n  tracked_poses: report.json");
  expect_error(edit(), {location("tracked_poses:") + "key 'object.tracked_poses': the tracked "
                                                     "poses and",
                        "report.json would be the same file"});
}

TEST_F(BadInput, ReportOntoAPipeIsRefused) {
  // Moving the finished report onto a pipe (or a device such as /dev/null) would replace it.
  const fs::path pipe = dir / "pipe";
  ASSERT_EQ(::mkfifo(pipe.c_str(), 0644), 0);
  expect_error(edit("--report " + pipe.string()),
               {"pipe: the output", "is a pipe, not a file it can replace"});
  EXPECT_TRUE(fs::is_fifo(pipe));
}

TEST_F(BadInput, AnInputNamedLikeATemporaryOutputIsKept) {
  // The video and the report are written under temporary names that no existing file has.
  fs::rename(dir / "clip.mp4", dir / "edited.partial.mp4");
  replace(scene, "video: clip.mp4", "video: edited.partial.mp4");
  fs::rename(dir / "poses.txt", dir / "report.partial.json");
  replace(scene, "poses: poses.txt", "poses: report.partial.json");
  const std::string video = read_text(dir / "edited.partial.mp4");
  const std::string poses = read_text(dir / "report.partial.json");
  const CmdResult r = edit();
  ASSERT_EQ(r.status, 0) << r.output;
  EXPECT_EQ(read_text(dir / "edited.partial.mp4"), video);
  EXPECT_EQ(read_text(dir / "report.partial.json"), poses);
  EXPECT_TRUE(fs::exists(dir / "edited.mp4"));
  EXPECT_TRUE(fs::exists(dir / "report.json"));
  EXPECT_FALSE(fs::exists(dir / "edited.partial-2.mp4"));
  EXPECT_FALSE(fs::exists(dir / "report.partial-2.json"));
}

TEST_F(BadInput, UnsupportedVideoExtension) {
  expect_error(edit("-o " + (dir / "edited.xyz").string()),
               {"edited.xyz: no video codec for the extension '.xyz'", ".mp4"},
               {dir / "edited.xyz"});
  // Named by the scene: its line and key too.
  replace(scene, "video: edited.mp4", "video: edited.webm");
  expect_error(edit(),
               {location("output:") + "key 'output.video': ",
                "edited.webm: no video codec for the extension '.webm'"},
               {dir / "edited.webm"});
}

// ---- pbve plot and pbve synth -----------------------------------------------------------------

TEST_F(BadInput, SynthChecksItsOptionsBeforeWritingAnything) {
  const fs::path mine = dir / "mine";
  fs::create_directory(mine);
  write_text(mine / "poses.txt", "precious\n");
  CmdResult r = pbve_cmd("synth --size 64x48 --frames 3 --supersample 0 " + mine.string());
  EXPECT_EQ(r.status, 2) << r.output;  // bad usage
  EXPECT_NE(r.output.find("supersample must be 1 to 8, got 0"), std::string::npos) << r.output;
  EXPECT_EQ(read_text(mine / "poses.txt"), "precious\n");
  EXPECT_EQ(std::distance(fs::directory_iterator(mine), fs::directory_iterator{}), 1);
  r = pbve_cmd("synth --size 100000x100000 " + mine.string());
  EXPECT_EQ(r.status, 2) << r.output;
  EXPECT_NE(r.output.find("--size: image size too large"), std::string::npos) << r.output;
  EXPECT_EQ(read_text(mine / "poses.txt"), "precious\n");
  r = pbve_cmd("synth --size 64x48 --frames 3 --fps 1e308 " + (dir / "new").string());
  EXPECT_EQ(r.status, 2) << r.output;
  EXPECT_NE(r.output.find("fps must be above 0 and at most 1e6"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir / "new"));
}

TEST_F(BadInput, PlotOntoItsReportOrWithTheWrongLabels) {
  ASSERT_EQ(edit().status, 0);
  const fs::path report = dir / "report.json";
  const std::string before = read_text(report);
  CmdResult r = pbve_cmd("plot " + report.string() + " -o " + report.string());
  EXPECT_EQ(r.status, 2) << r.output;
  EXPECT_NE(r.output.find("the plot is a PNG image"), std::string::npos) << r.output;
  r = pbve_cmd("plot " + report.string() + " --labels a,b");
  EXPECT_EQ(r.status, 2) << r.output;
  EXPECT_NE(r.output.find("--labels gives 2 labels for 1 reports"), std::string::npos) << r.output;
  EXPECT_EQ(read_text(report), before);
  EXPECT_FALSE(fs::exists(dir / "report.png"));
  // A report that happens to have a .png name is not written over either.
  fs::copy_file(report, dir / "r.png");
  r = pbve_cmd("plot " + (dir / "r.png").string() + " -o " + (dir / "." / "r.png").string());
  EXPECT_EQ(r.status, 1) << r.output;  // as `pbve edit` refuses its outputs
  EXPECT_NE(r.output.find("the plot would overwrite the report"), std::string::npos) << r.output;
  EXPECT_EQ(read_text(dir / "r.png"), before);
}

TEST_F(BadInput, BenchOptionsAreCheckedBeforeAnyWork) {
  fs::create_directory(dir / "work");
  write_text(dir / "work" / "scene.yaml", "mine\n");
  for (const auto& [option, message] :
       {std::pair<std::string, std::string>{"--vertices 0", "a target must be positive, got 0"},
        {"--vertices -5", "a target must be positive, got -5"},
        {"--modes ''", "--modes is empty"},
        {"--work " + (dir / "work").string(), "must be a new or empty folder"}}) {
    const CmdResult r =
        pbve_cmd("bench -o " + (dir / "bench.json").string() + " --quiet " + option);
    EXPECT_EQ(r.status, 2) << option << "\n" << r.output;
    EXPECT_NE(r.output.find(message), std::string::npos) << option << "\n" << r.output;
  }
  EXPECT_EQ(read_text(dir / "work" / "scene.yaml"), "mine\n");
  EXPECT_FALSE(fs::exists(dir / "bench.json"));
}

TEST_F(BadInput, PlotOfAnInvalidReportWritesNoPlot) {
  write_text(dir / "bad.json", "{\"frames\": [{\"index\": 0}]}");
  const CmdResult r = pbve_cmd("plot " + (dir / "bad.json").string());
  EXPECT_EQ(r.status, 1) << r.output;
  EXPECT_NE(r.output.find("bad.json: key 'frames[0].violation_pct': not a pbve report: missing"),
            std::string::npos)
      << r.output;
  EXPECT_FALSE(fs::exists(dir / "bad.png"));
  EXPECT_FALSE(fs::exists(dir / "bad.partial.png"));
}

TEST_F(BadInput, SynthWithABadFrameRateIsAUsageError) {
  const CmdResult r = pbve_cmd("synth --fps zero " + (dir / "s").string());
  EXPECT_EQ(r.status, 2) << r.output;
  EXPECT_NE(r.output.find("--fps expects a positive number, got 'zero'"), std::string::npos)
      << r.output;
  EXPECT_FALSE(fs::exists(dir / "s"));
}

}  // namespace
