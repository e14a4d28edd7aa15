// Scene file parsing: every documented key, and errors that name file, line and key.

#include <limits>
#include <string>

#include <gtest/gtest.h>

#include "pbve/core/error.hpp"
#include "pbve/edit/scene.hpp"
#include "pbve/engines.hpp"
#include "support/test_util.hpp"

namespace {

using pbve::InputError;
using pbve::parse_scene;

const char* kFull = R"(input:   {video: clip.mp4}
camera:  {fx: 600, fy: 610, cx: 320, cy: 240}
object:
  mesh: object.obj
  poses: poses.txt
  scale: 1.02
  refine: 0.005
  anchors: {vertices: [0, 5, 9], box: {min: [0, 0, 0], max: [0.1, 0.2, 0.3]}}
background: {plate: plate.png, remove: masks/%04d.png}
simulation:
  engine: mass_spring
  material: cloth
  gravity: [0, 9.81, 0]
  ground: {point: [0, 0.1, 0], normal: [0, -2, 0]}
  substeps: 12
  stretch_stiffness: 500
control:
  enabled: true
  weights: {visibility: 1.0, force: 0.002, temporal: 0.003}
  window: 3
  solver: ipopt
  gradient: central
output:  {video: edited.mp4, report: report.json}
)";

std::string error_of(const std::string& text) {
  try {
    parse_scene(text, "/scenes/s.yaml");
  } catch (const InputError& e) {
    return e.what();
  }
  return "(no error)";
}

TEST(Scene, ParsesEveryDocumentedKey) {
  const pbve::Scene s = parse_scene(kFull, "/scenes/s.yaml");
  EXPECT_EQ(s.input.video, "/scenes/clip.mp4");
  EXPECT_EQ(s.fy, 610);
  EXPECT_EQ(s.object.mesh, "/scenes/object.obj");
  EXPECT_EQ(s.object.poses, "/scenes/poses.txt");
  EXPECT_DOUBLE_EQ(s.object.scale, 1.02);
  EXPECT_DOUBLE_EQ(s.object.refine, 0.005);
  EXPECT_EQ(s.object.anchors.vertices, (std::vector<int>{0, 5, 9}));
  ASSERT_TRUE(s.object.anchors.box_max.has_value());
  EXPECT_DOUBLE_EQ(s.object.anchors.box_max->z(), 0.3);
  EXPECT_EQ(s.background.plate, "/scenes/plate.png");
  EXPECT_EQ(s.background.remove, "/scenes/masks/%04d.png");
  EXPECT_EQ(s.simulation.material, "cloth");
  ASSERT_TRUE(s.simulation.ground.has_value());
  EXPECT_DOUBLE_EQ(s.simulation.ground->normal.y(), -1.0);  // normalized
  EXPECT_EQ(s.simulation.substeps, 12);
  ASSERT_EQ(s.simulation.parameters.count("stretch_stiffness"), 1u);
  EXPECT_DOUBLE_EQ(s.simulation.parameters.at("stretch_stiffness").first, 500);
  EXPECT_EQ(s.simulation.parameters.at("stretch_stiffness").second, 16);  // its line
  EXPECT_EQ(s.control.window, 3);
  EXPECT_EQ(s.control.solver, "ipopt");
  EXPECT_EQ(s.control.gradient, "central");
  EXPECT_DOUBLE_EQ(s.control.weight_temporal, 0.003);
  EXPECT_EQ(s.output.video, "/scenes/edited.mp4");
  EXPECT_EQ(s.output.report, "/scenes/report.json");
}

TEST(Scene, DefaultsForOptionalSections) {
  const pbve::Scene s = parse_scene(
      "input: {image: p.png, frames: 90}\ncamera: {fx: 1, fy: 1, cx: 0, cy: 0}\n"
      "object: {mesh: m.ply, poses: p.txt}\noutput: {video: o.mkv}\n",
      "/x/s.yaml");
  EXPECT_EQ(s.input.frames, 90);
  EXPECT_DOUBLE_EQ(s.object.scale, 1.01);
  EXPECT_TRUE(s.control.enabled);
  EXPECT_EQ(s.simulation.engine, "mass_spring");
  EXPECT_TRUE(s.output.report.empty());  // named after the video the run writes
  EXPECT_TRUE(s.background.plate.empty());
}

TEST(Scene, RoundTripsThroughYaml) {
  const pbve::Scene a = parse_scene(kFull, "/scenes/s.yaml");
  const pbve::Scene b = parse_scene(pbve::scene_to_yaml(a), "/elsewhere/s.yaml");
  EXPECT_EQ(a.object.mesh, b.object.mesh);
  EXPECT_EQ(a.control.solver, b.control.solver);
  ASSERT_EQ(b.simulation.parameters.count("stretch_stiffness"), 1u);
  EXPECT_EQ(b.simulation.parameters.at("stretch_stiffness").first, 500);
  EXPECT_EQ(a.object.anchors.vertices, b.object.anchors.vertices);
  EXPECT_EQ(a.simulation.substeps, b.simulation.substeps);
}

TEST(SceneErrors, UnknownTopLevelKeySuggestsNearest) {
  std::string text = kFull;
  text.replace(text.find("output:"), 7, "ouptut:");
  const std::string e = error_of(text);
  EXPECT_NE(e.find("/scenes/s.yaml:23"), std::string::npos) << e;
  EXPECT_NE(e.find("'ouptut'"), std::string::npos) << e;
  EXPECT_NE(e.find("did you mean 'output'"), std::string::npos) << e;
}

TEST(SceneErrors, MistypedNestedKeyNamesFullKeyAndLine) {
  std::string text = kFull;
  text.replace(text.find("refine:"), 7, "refien:");
  const std::string e = error_of(text);
  EXPECT_NE(e.find(":7:"), std::string::npos) << e;
  EXPECT_NE(e.find("object.refien"), std::string::npos) << e;
  EXPECT_NE(e.find("did you mean 'refine'"), std::string::npos) << e;
}

TEST(SceneErrors, UnknownSolverSuggests) {
  std::string text = kFull;
  text.replace(text.find("ipopt"), 5, "slsqq");
  const std::string e = error_of(text);
  EXPECT_NE(e.find(":21:"), std::string::npos) << e;
  EXPECT_NE(e.find("control.solver"), std::string::npos) << e;
  EXPECT_NE(e.find("did you mean 'slsqp'"), std::string::npos) << e;
}

TEST(Scene, AnyEngineNameForAProgramsOwnAdapter) {
  // A program's own adapter is selected by its name (its make_simulator reads it); the pbve
  // command checks the name against the engines built in, at the key's line.
  std::string text = kFull;
  text.replace(text.find("mass_spring"), 11, "spring_particles");
  const pbve::Scene s = parse_scene(text, "/scenes/s.yaml");
  EXPECT_EQ(s.simulation.engine, "spring_particles");
  try {
    pbve::check_engine(s);
    ADD_FAILURE() << "no error for an engine that is not built in";
  } catch (const InputError& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("/scenes/s.yaml:11"), std::string::npos) << m;
    EXPECT_NE(m.find("simulation.engine"), std::string::npos) << m;
    EXPECT_NE(m.find("engine 'spring_particles' is not built into this pbve (available: "
                     "mass_spring"),
              std::string::npos)
        << m;
  }
  text.replace(text.find("spring_particles"), 16, "mass_sprng");
  try {
    pbve::check_engine(parse_scene(text, "/scenes/s.yaml"));
    ADD_FAILURE() << "no error for a misspelt engine";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("did you mean 'mass_spring'?"), std::string::npos)
        << e.what();
  }
  EXPECT_NO_THROW(pbve::check_engine(parse_scene(kFull, "/scenes/s.yaml")));
}

TEST(SceneErrors, EngineNameMustBeAnIdentifier) {
  std::string text = kFull;
  text.replace(text.find("mass_spring"), 11, "\"mass spring\"");
  const std::string e = error_of(text);
  EXPECT_NE(e.find(":11:"), std::string::npos) << e;
  EXPECT_NE(e.find("expected an engine name"), std::string::npos) << e;
}

TEST(SceneErrors, DuplicateKeysNameTheSecondAndTheFirstLine) {
  // YAML forbids two equal keys in one mapping; the parser would keep the first silently.
  std::string text = kFull;
  text.replace(text.find("fx: 600,"), 8, "fx: 600, fx: 300,");
  std::string e = error_of(text);
  EXPECT_NE(e.find("/scenes/s.yaml:2: key 'camera.fx': key given twice (first at line 2)"),
            std::string::npos)
      << e;
  e = error_of(std::string(kFull) + "control:\n  enabled: false\n");
  EXPECT_NE(e.find(":24: key 'control': key given twice (first at line 17)"), std::string::npos)
      << e;
}

TEST(SceneErrors, AMisspeltSimulationKeyNamesTheNearestOne) {
  // Any other key of `simulation:` is a material parameter, a number: a misspelt section key
  // with another value is named as such, at its line.
  std::string text = kFull;
  text.replace(text.find("  material: cloth"), 16, "  materal: cloth");
  std::string e = error_of(text);
  EXPECT_NE(e.find(":12: key 'simulation.materal': unknown key (did you mean 'material'?)"),
            std::string::npos)
      << e;
  text = kFull;
  text.replace(text.find("  ground:"), 9, "  grond:");
  e = error_of(text);
  EXPECT_NE(e.find(":14: key 'simulation.grond': unknown key (did you mean 'ground'?)"),
            std::string::npos)
      << e;
}

TEST(SceneErrors, AnEmptyValueIsReportedAtItsKey) {
  // An empty value is a null node that the parser marks at the next token, here lines below.
  std::string text = kFull;
  const std::string plate = "background: {plate: plate.png, remove: masks/%04d.png}\n";
  text.replace(text.find(plate), plate.size(), "background:\n\n\n# the plate\n");
  std::string e = error_of(text);
  EXPECT_NE(e.find(":9: key 'background': expected a mapping of keys"), std::string::npos) << e;
  text = kFull;
  const std::string line = "  substeps: 12\n";
  text.replace(text.find(line), line.size(), "  substeps:\n\n");
  e = error_of(text);
  EXPECT_NE(e.find(":15: key 'simulation.substeps': expected a number"), std::string::npos) << e;
}

TEST(SceneErrors, ScaleIsAnEnlargementNotAUnitChange) {
  std::string text = kFull;
  text.replace(text.find("scale: 1.02"), 11, "scale: 1000");
  const std::string e = error_of(text);
  EXPECT_NE(e.find("/scenes/s.yaml:6: key 'object.scale'"), std::string::npos) << e;
  EXPECT_NE(e.find("between 0.9 and 1.5, found 1000"), std::string::npos) << e;
}

TEST(SceneErrors, WrongTypeNamesKey) {
  std::string text = kFull;
  text.replace(text.find("fx: 600"), 7, "fx: six");
  const std::string e = error_of(text);
  EXPECT_NE(e.find(":2:"), std::string::npos) << e;
  EXPECT_NE(e.find("camera.fx"), std::string::npos) << e;
  EXPECT_NE(e.find("'six'"), std::string::npos) << e;
}

TEST(SceneErrors, NonPositiveValue) {
  std::string text = kFull;
  text.replace(text.find("scale: 1.02"), 11, "scale: -1.0");
  const std::string e = error_of(text);
  EXPECT_NE(e.find(":6:"), std::string::npos) << e;
  EXPECT_NE(e.find("object.scale"), std::string::npos) << e;
  EXPECT_NE(e.find("positive"), std::string::npos) << e;
}

TEST(Scene, ControlClusters) {
  std::string text = kFull;
  const std::string gradient = "  gradient: central";
  text.replace(text.find(gradient), gradient.size(), gradient + "\n  clusters: 16");
  EXPECT_EQ(parse_scene(text, "/scenes/s.yaml").control.clusters, 16);
  EXPECT_EQ(parse_scene(kFull, "/scenes/s.yaml").control.clusters, 0);
  text.replace(text.find("clusters: 16"), 12, "clusters: -2");
  const std::string e = error_of(text);
  EXPECT_NE(e.find(":23:"), std::string::npos) << e;
  EXPECT_NE(e.find("control.clusters"), std::string::npos) << e;
  EXPECT_NE(e.find("negative"), std::string::npos) << e;
}

TEST(Scene, CompressedDifferences) {
  std::string text = kFull;
  const std::string gradient = "  gradient: central";
  text.replace(text.find(gradient), gradient.size(),
               "  gradient: compressed\n  difference_rings: 3");
  const pbve::Scene s = parse_scene(text, "/scenes/s.yaml");
  EXPECT_EQ(s.control.gradient, "compressed");
  EXPECT_EQ(s.control.difference_rings, 3);
  EXPECT_EQ(parse_scene(kFull, "/scenes/s.yaml").control.difference_rings, 2);
  text.replace(text.find("difference_rings: 3"), 19, "difference_rings: -1");
  const std::string e = error_of(text);
  EXPECT_NE(e.find(":23:"), std::string::npos) << e;
  EXPECT_NE(e.find("control.difference_rings"), std::string::npos) << e;
  EXPECT_NE(e.find("between 0 and 50"), std::string::npos) << e;
}

// kFull with `regions` (one entry per line) in place of its `substeps: 12` line (line 15).
std::string with_regions(const std::string& entries) {
  std::string text = kFull;
  const std::string line = "  substeps: 12\n";
  text.replace(text.find(line), line.size(), line + "  regions:\n" + entries);
  return text;
}

TEST(Scene, SimulationRegions) {
  const pbve::Scene s = parse_scene(
      with_regions("    - {box: {min: [-1, -0.2, -1], max: [1, -0.05, 1]}, volume_stiffness: 3e4}\n"
                   "    - box: {min: [0, 0, 0], max: [0, 0, 0]}\n"
                   "      volume_stiffness: 5\n"),
      "/scenes/s.yaml");
  ASSERT_EQ(s.simulation.regions.size(), 2u);
  const pbve::SceneRegion& a = s.simulation.regions[0];
  EXPECT_DOUBLE_EQ(a.box_min.y(), -0.2);
  EXPECT_DOUBLE_EQ(a.box_max.y(), -0.05);
  ASSERT_EQ(a.parameters.count("volume_stiffness"), 1u);
  EXPECT_DOUBLE_EQ(a.parameters.at("volume_stiffness").first, 3e4);
  EXPECT_EQ(a.line, 17);
  EXPECT_EQ(s.simulation.regions[1].parameters.at("volume_stiffness").second, 19);
  const pbve::Scene b = parse_scene(pbve::scene_to_yaml(s), "/elsewhere/s.yaml");
  ASSERT_EQ(b.simulation.regions.size(), 2u);
  EXPECT_EQ(b.simulation.regions[0].box_min, a.box_min);
  EXPECT_EQ(b.simulation.regions[0].box_max, a.box_max);
  EXPECT_EQ(b.simulation.regions[1].parameters.at("volume_stiffness").first, 5);
}

TEST(SceneErrors, BadRegionsNameKeyAndLine) {
  auto expect = [](const std::string& entries, const std::string& line, const std::string& key,
                   const std::string& what) {
    const std::string e = error_of(with_regions(entries));
    EXPECT_NE(e.find(line), std::string::npos) << e;
    EXPECT_NE(e.find(key), std::string::npos) << e;
    EXPECT_NE(e.find(what), std::string::npos) << e;
  };
  expect("    - {volume_stiffness: 3e4}\n", ":17:", "simulation.regions.box", "missing");
  expect("    - {box: {min: [0, 1, 0], max: [1, 0, 1]}, volume_stiffness: 3e4}\n",
         ":17:", "simulation.regions.box", "min must not exceed max");
  expect("    - {box: {min: [0, 0, 0], max: [1, 1, 1]}}\n", ":17:", "simulation.regions",
         "needs a material parameter");
  expect("    - {box: {min: [0, 0, 0], mx: [1, 1, 1]}, volume_stiffness: 1}\n",
         ":17:", "simulation.regions.box.mx", "did you mean 'max'");
  expect("    - {box: {min: [0, 0, 0], max: [1, 1, 1]}, volume_stiffness: soft}\n",
         ":17:", "simulation.regions.volume_stiffness", "'soft'");
  const std::string e = error_of(
      "input:   {video: clip.mp4}\n"
      "camera:  {fx: 600, fy: 610, cx: 320, cy: 240}\n"
      "object: {mesh: m.obj, poses: p.txt}\n"
      "simulation: {regions: 3}\noutput: {video: o.mp4}\n");
  EXPECT_NE(e.find(":4:"), std::string::npos) << e;
  EXPECT_NE(e.find("expected a list of regions"), std::string::npos) << e;
}

TEST(Scene, LinearizedTolerance) {
  std::string text = kFull;
  const std::string gradient = "  gradient: central";
  EXPECT_DOUBLE_EQ(parse_scene(text, "/scenes/s.yaml").control.linearized_tolerance, 1e-3);
  text.replace(text.find(gradient), gradient.size(), gradient + "\n  linearized_tolerance: 0");
  const pbve::Scene s = parse_scene(text, "/scenes/s.yaml");
  EXPECT_EQ(s.control.linearized_tolerance, 0.0);
  EXPECT_EQ(parse_scene(pbve::scene_to_yaml(s), "/x/s.yaml").control.linearized_tolerance, 0.0);
  text.replace(text.find("linearized_tolerance: 0"), 23, "linearized_tolerance: 1");
  const std::string e = error_of(text);
  EXPECT_NE(e.find(":23:"), std::string::npos) << e;
  EXPECT_NE(e.find("control.linearized_tolerance"), std::string::npos) << e;
  EXPECT_NE(e.find("less than 1"), std::string::npos) << e;
}

// control.margin becomes the optimizer's barrier margin: the values ControlOptions::validate()
// refuses (0 among them, which the scene took before) are errors at the key and its line.
TEST(SceneErrors, ControlValuesTheOptimizerRefusesNameKeyAndLine) {
  const std::string gradient = "  gradient: central";
  auto with_margin = [&](const std::string& value) {
    std::string text = kFull;
    text.replace(text.find(gradient), gradient.size(), gradient + "\n  margin: " + value);
    return text;
  };
  EXPECT_DOUBLE_EQ(parse_scene(with_margin("0.2"), "/scenes/s.yaml").control.margin, 0.2);
  for (const std::string value : {"0", "1", "-0.1"}) {
    const std::string e = error_of(with_margin(value));
    EXPECT_NE(e.find("/scenes/s.yaml:23: key 'control.margin': must be greater than 0 and less "
                     "than 1, got " +
                     value),
              std::string::npos)
        << e;
  }
  // A scene made in code: the value is named by the key that would set it.
  pbve::Scene s = parse_scene(kFull, "/scenes/s.yaml");
  s.control.weight_force = std::numeric_limits<double>::quiet_NaN();
  try {
    pbve::control_options(s);
    ADD_FAILURE() << "a NaN force weight was accepted";
  } catch (const InputError& e) {
    EXPECT_EQ(e.line(), 19);
    EXPECT_EQ(e.key(), "key 'control.weights.force'");
    EXPECT_NE(std::string(e.what()).find("nan"), std::string::npos) << e.what();
  }
  s.control.weight_force = 0.002;
  s.control.solver = "knitro";
  EXPECT_THROW(pbve::control_options(s), InputError);
  s.control.solver = "slsqp";
  const pbve::ControlOptions o = pbve::control_options(s);
  EXPECT_EQ(o.window, 3);
  EXPECT_DOUBLE_EQ(o.weights.temporal, 0.003);
  EXPECT_EQ(o.gradient, pbve::GradientMode::central);
}

TEST(SceneErrors, MissingRequiredKey) {
  const std::string e = error_of(
      "input: {video: a.mp4}\ncamera: {fx: 1, fy: 1, cx: 0, cy: 0}\nobject: {mesh: m.obj}\n"
      "output: {video: o.mp4}\n");
  EXPECT_NE(e.find("object.poses"), std::string::npos) << e;
  EXPECT_NE(e.find("missing"), std::string::npos) << e;
}

TEST(SceneErrors, YamlSyntaxErrorHasLine) {
  const std::string e = error_of("input: {video: a.mp4}\ncamera: {fx: 1, fy: [1\n");
  EXPECT_NE(e.find("/scenes/s.yaml:"), std::string::npos) << e;
  EXPECT_NE(e.find("YAML syntax error"), std::string::npos) << e;
}

TEST(SceneErrors, TwoInputsAreAmbiguous) {
  const std::string e = error_of(
      "input: {video: a.mp4, image: b.png, frames: 3}\ncamera: {fx: 1, fy: 1, cx: 0, cy: 0}\n"
      "object: {mesh: m.obj, poses: p.txt}\noutput: {video: o.mp4}\n");
  EXPECT_NE(e.find(":1:"), std::string::npos) << e;
  EXPECT_NE(e.find("exactly one"), std::string::npos) << e;
}

TEST(SceneErrors, MissingFileNamesIt) {
  try {
    pbve::load_scene("/nonexistent/scene.yaml");
    FAIL() << "no error";
  } catch (const InputError& e) {
    EXPECT_EQ(e.file(), "/nonexistent/scene.yaml");
  }
}

TEST(SceneErrors, NegativeAnchorIndex) {
  std::string text = kFull;
  text.replace(text.find("[0, 5, 9]"), 9, "[0, -5, 9]");
  const std::string e = error_of(text);
  EXPECT_NE(e.find(":8:"), std::string::npos) << e;
  EXPECT_NE(e.find("object.anchors.vertices"), std::string::npos) << e;
}

TEST(SceneNearestKey, FindsCloseAndRejectsFar) {
  EXPECT_EQ(pbve::nearest_key("substep", {"substeps", "gravity"}), "substeps");
  EXPECT_EQ(pbve::nearest_key("zzzzzzzz", {"substeps", "gravity"}), "");
}

}  // namespace
