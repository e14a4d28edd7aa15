// Fuzz target: scene-file text through pbve::parse_scene (the parser and value checks of
// load_scene) and scene_to_yaml. The scene path is absolute and names no real folder: parsing
// resolves paths but neither opens nor writes files.

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string>

#include "fuzz_check.hpp"
#include "pbve/core/error.hpp"
#include "pbve/edit/scene.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::filesystem::path name = "/nonexistent-pbve-fuzz/scene.yaml";
  const std::string text(reinterpret_cast<const char*>(data), size);
  pbve::Scene scene;
  try {
    scene = pbve::parse_scene(text, name);
  } catch (const pbve::InputError& e) {
    pbve::fuzz::check_error(e, name);
    return 0;
  }
  using pbve::fuzz::expect;
  // The required keys are there and the values are in their documented ranges.
  expect(scene.file == name, "the scene knows its file");
  expect(scene.object.mesh.is_absolute() && scene.object.poses.is_absolute() &&
             scene.output.video.is_absolute() &&
             (scene.output.report.empty() || scene.output.report.is_absolute()),
         "paths are absolute");
  const int inputs =
      !scene.input.video.empty() + !scene.input.image.empty() + !scene.input.sequence.empty();
  expect(inputs == 1, "exactly one input");
  expect(scene.input.image.empty() || scene.input.frames >= 1, "a picture has frames");
  expect(scene.input.fps > 0 && scene.fx > 0 && scene.fy > 0, "positive rates and focal lengths");
  expect(std::isfinite(scene.fx) && std::isfinite(scene.fy) && std::isfinite(scene.cx) &&
             std::isfinite(scene.cy) && scene.simulation.gravity.allFinite(),
         "finite camera and gravity");
  expect(scene.control.weight_visibility >= 0 && scene.control.weight_force >= 0 &&
             scene.control.weight_temporal >= 0 && scene.control.force_bound >= 0,
         "non-negative weights and bound");
  for (const auto& [key, value] : scene.simulation.parameters)
    expect(std::isfinite(value.first) && value.second >= 1, "finite material parameters");
  expect(scene.object.scale > 0 && scene.object.refine >= 0, "positive scale");
  expect(scene.simulation.substeps >= 1 && scene.simulation.substeps <= 10000, "substeps range");
  expect(scene.control.window >= 1 && scene.control.window <= 100, "window range");
  expect(scene.control.max_iterations >= 1 && scene.control.clusters >= 0, "control ranges");
  expect(scene.control.margin > 0 && scene.control.margin < 1, "margin range");
  for (const auto& [key, line] : scene.lines) expect(line >= 1, "key lines are 1-based");
  // The resolved scene as text (the report's settings) for any accepted scene.
  expect(!pbve::scene_to_yaml(scene).empty(), "the resolved scene has text");
  return 0;
}
