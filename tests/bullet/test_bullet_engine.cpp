// `simulation: engine: bullet` through pbve::make_engine: every material, parameter overrides,
// and clear errors for unknown parameters.

#include <string>

#include <gtest/gtest.h>

#include "bullet/scenes.hpp"
#include "pbve/bullet/bullet.hpp"
#include "pbve/core/error.hpp"
#include "pbve/edit/synth.hpp"
#include "pbve/engines.hpp"

namespace {

using pbve::EngineRecipe;
using pbve::InputError;

// A scene whose simulation section is `simulation` (YAML lines, indented by two spaces).
pbve::Scene scene_with(const std::string& simulation) {
  return pbve::parse_scene(
      "input: {image: p.png, frames: 3}\ncamera: {fx: 600, fy: 600, cx: 320, cy: 240}\n"
      "object: {mesh: m.obj, poses: p.txt}\noutput: {video: o.mkv}\nsimulation:\n" +
          simulation,
      "/scenes/s.yaml");
}

EngineRecipe recipe(const pbve::Scene& scene, const pbve::Mesh& mesh, std::vector<int> anchors) {
  EngineRecipe r;
  r.simulation = scene.simulation;
  r.mesh = mesh;
  r.rest_positions = mesh.vertices;
  r.anchors = std::move(anchors);
  r.scene_file = "/scenes/s.yaml";
  return r;
}

TEST(BulletEngine, IsAvailable) {
  const auto engines = pbve::available_engines();
  EXPECT_NE(std::find(engines.begin(), engines.end(), "bullet"), engines.end());
  const auto keys = pbve::engine_parameters("bullet");
  EXPECT_NE(std::find(keys.begin(), keys.end(), "linear_stiffness"), keys.end());
  EXPECT_NE(std::find(keys.begin(), keys.end(), "position_iterations"), keys.end());
}

TEST(BulletEngine, BuildsEveryMaterialFromAScene) {
  const pbve::Mesh cloth = pbve::test::grid_mesh(5, 0.2);
  const pbve::Mesh ball = pbve::test::icosphere(1, 0.05, Eigen::Vector3d(0, 0, 1));
  for (const char* material : {"cloth", "elastic", "stiff", "rigid"}) {
    SCOPED_TRACE(material);
    const pbve::Scene s = scene_with(std::string("  engine: bullet\n  material: ") + material +
                                     "\n  substeps: 4\n  ground: {point: [0, 0.3, 0], normal: "
                                     "[0, -1, 0]}\n");
    const bool is_cloth = std::string(material) == "cloth";
    auto sim = pbve::make_engine(recipe(s, is_cloth ? cloth : ball, {0}));
    ASSERT_TRUE(sim);
    EXPECT_EQ(sim->name(), "bullet");
    auto* b = dynamic_cast<pbve::bullet::BulletSimulator*>(sim.get());
    ASSERT_NE(b, nullptr);
    EXPECT_EQ(b->params().substeps, 4);
    ASSERT_EQ(b->params().planes.size(), 1u);
    EXPECT_EQ(pbve::bullet::to_string(b->params().material), material);
    EXPECT_EQ(sim->control_layout().space, std::string(material) == "rigid"
                                               ? pbve::ControlSpace::body_wrench
                                               : pbve::ControlSpace::vertex_force);
    pbve::StepInput in;
    sim->step(in);
    EXPECT_TRUE(sim->positions().allFinite());
  }
}

TEST(BulletEngine, ParameterOverridesReachTheSimulator) {
  const pbve::Scene s = scene_with(
      "  engine: bullet\n  material: elastic\n  linear_stiffness: 0.5\n  pressure: 300\n"
      "  position_iterations: 12\n");
  auto sim =
      pbve::make_engine(recipe(s, pbve::test::icosphere(1, 0.05, Eigen::Vector3d(0, 0, 1)), {0}));
  const auto& p = dynamic_cast<pbve::bullet::BulletSimulator&>(*sim).params();
  EXPECT_EQ(p.linear_stiffness, 0.5);
  EXPECT_EQ(p.pressure, 300.0);
  EXPECT_EQ(p.position_iterations, 12);
  // Untouched fields keep the elastic preset.
  EXPECT_EQ(p.volume_stiffness,
            pbve::bullet::Params::preset(pbve::bullet::Material::elastic).volume_stiffness);
  // A board made into cloth as two layers instead of one sheet.
  const pbve::Scene two = scene_with("  engine: bullet\n  material: cloth\n  single_sheet: 0\n");
  auto cloth = pbve::make_engine(
      recipe(two, pbve::refine_mesh(pbve::make_box_mesh(0.2, 0.2, 0.01), 0.05), {0}));
  const auto& b = dynamic_cast<pbve::bullet::BulletSimulator&>(*cloth);
  EXPECT_EQ(b.params().single_sheet, 0);
  EXPECT_EQ(b.num_nodes(), b.num_vertices());
  EXPECT_GT(b.num_layer_ties(), 0);
}

std::string error_of(const std::string& simulation, const pbve::Mesh& mesh) {
  try {
    pbve::make_engine(recipe(scene_with(simulation), mesh, {0}));
  } catch (const InputError& e) {
    return e.what();
  }
  return "(no error)";
}

TEST(BulletEngine, UnknownParameterNamesTheKeyAndTheNearestOne) {
  const std::string msg = error_of("  engine: bullet\n  material: cloth\n  linear_stifness: 0.5\n",
                                   pbve::test::grid_mesh(4, 0.2));
  EXPECT_NE(msg.find("s.yaml"), std::string::npos) << msg;
  EXPECT_NE(msg.find("simulation.linear_stifness"), std::string::npos) << msg;
  EXPECT_NE(msg.find("did you mean 'linear_stiffness'"), std::string::npos) << msg;
  // The line of the offending key (line 8 of the scene text).
  EXPECT_NE(msg.find("s.yaml:8"), std::string::npos) << msg;
}

TEST(BulletEngine, InvalidValuesAreInputErrors) {
  const pbve::Mesh grid = pbve::test::grid_mesh(4, 0.2);
  std::string msg = error_of("  engine: bullet\n  material: cloth\n  linear_stiffness: 2\n", grid);
  EXPECT_NE(msg.find("linear_stiffness"), std::string::npos) << msg;
  msg = error_of("  engine: bullet\n  material: cloth\n  position_iterations: 2.5\n", grid);
  EXPECT_NE(msg.find("expected an integer"), std::string::npos) << msg;
  msg = error_of("  engine: bullet\n  material: cloth\n  shape_matching: 0.5\n", grid);
  EXPECT_NE(msg.find("simulation.shape_matching"), std::string::npos) << msg;
  EXPECT_NE(msg.find("applies to material elastic and stiff only, not to cloth"), std::string::npos)
      << msg;
  msg = error_of("  engine: bullet\n  material: cloth\n  single_sheet: 2\n", grid);
  EXPECT_NE(msg.find("single_sheet"), std::string::npos) << msg;
  // An open sheet has no volume to keep.
  msg = error_of("  engine: bullet\n  material: elastic\n", grid);
  EXPECT_NE(msg.find("closed mesh"), std::string::npos) << msg;
  // Away from the camera an open sheet's tetrahedra from the origin sum to a volume: it is
  // still refused, as a soft solid and as rigid pieces.
  pbve::Mesh far = grid;
  far.vertices.col(2).array() += 1.3;
  for (const char* material : {"elastic", "rigid"}) {
    msg = error_of(std::string("  engine: bullet\n  material: ") + material + "\n", far);
    EXPECT_NE(msg.find("borders a hole"), std::string::npos) << material << ": " << msg;
  }
}

// A parameter of another material would be ignored: the scene is refused at the key's line,
// naming the materials it applies to, whatever its value (even the preset's own).
TEST(BulletEngine, AParameterOfAnotherMaterialNamesTheKeyAndItsMaterials) {
  const pbve::Mesh grid = pbve::test::grid_mesh(4, 0.2);
  const pbve::Mesh ball = pbve::test::icosphere(1, 0.05, Eigen::Vector3d(0, 0, 1));
  struct Case {
    const char* material;
    const char* line;
    const char* expected;
  };
  for (const Case& c : {
           Case{"cloth", "restitution: 0.5", "applies to material rigid only, not to cloth"},
           Case{"cloth", "volume_stiffness: 2e4",
                "applies to material elastic and stiff only, not to cloth"},
           Case{"cloth", "pressure: 0", "applies to material elastic and stiff only"},
           Case{"elastic", "single_sheet: 1", "applies to material cloth only, not to elastic"},
           Case{"stiff", "layer_distance: 0.01", "applies to material cloth only, not to stiff"},
           Case{"elastic", "hull_tolerance: 0.05", "applies to material rigid only"},
           Case{"rigid", "linear_stiffness: 0.5",
                "applies to material cloth, elastic and stiff only, not to rigid"},
           Case{"rigid", "damping: 0.01", "not to rigid"},
           Case{"rigid", "position_iterations: 4", "not to rigid"},
       }) {
    SCOPED_TRACE(std::string(c.material) + ", " + c.line);
    const std::string msg = error_of(
        std::string("  engine: bullet\n  material: ") + c.material + "\n  " + c.line + "\n",
        std::string(c.material) == "cloth" ? grid : ball);
    const std::string key = std::string(c.line).substr(0, std::string(c.line).find(':'));
    // The offending key is on line 8 of the scene text.
    EXPECT_NE(msg.find("s.yaml:8"), std::string::npos) << msg;
    EXPECT_NE(msg.find("simulation." + key), std::string::npos) << msg;
    EXPECT_NE(msg.find(c.expected), std::string::npos) << msg;
  }
  // Keys of every material, and a material's own keys, are still accepted.
  for (const char* material : {"cloth", "rigid"}) {
    SCOPED_TRACE(material);
    const bool is_cloth = std::string(material) == "cloth";
    const std::string own = is_cloth ? "  layer_stiffness: 0.4\n" : "  restitution: 0.3\n";
    EXPECT_EQ(error_of(std::string("  engine: bullet\n  material: ") + material +
                           "\n  density: 500\n  friction: 0.5\n  collision_margin: 0.003\n" + own,
                       is_cloth ? grid : ball),
              "(no error)");
  }
}

}  // namespace
