// Runs `pbve edit` on a scene with the custom adapter instead of a built-in engine (the scene
// says `engine: spring_particles`):
//   custom_adapter SCENE.yaml [OUT.mp4]
// Everything but the engine (visibility, control by central differences, rendering, report) is
// pbve's own.

#include <cstdio>
#include <exception>
#include <memory>
#include <string>
#include <vector>

#include "pbve/core/error.hpp"
#include "pbve/edit/editor.hpp"
#include "pbve/edit/scene.hpp"
#include "spring_particles.hpp"

namespace {

// The scene's `simulation:` section as this engine reads it: `engine: spring_particles`,
// `gravity`, `substeps` and its own parameters `stiffness` (N/m), `mass` (kg per particle) and
// `damping` (1/s). What it cannot honour is an error naming the key, like the built-in engines'
// (pbve fills in the key's line when the error gives none).
std::unique_ptr<pbve::Simulator> make_spring_particles(const pbve::EngineRecipe& r) {
  const pbve::SceneSimulation& s = r.simulation;
  auto fail = [&](const std::string& key, int line, const std::string& message) {
    throw pbve::InputError(message, r.scene_file, line, "key 'simulation." + key + "'");
  };
  if (s.engine != "spring_particles")
    fail("engine", 0, "this program runs the engine spring_particles, not '" + s.engine + "'");
  if (s.material != "cloth") fail("material", 0, "spring_particles models cloth only");
  if (s.ground || !s.planes.empty())
    fail(s.ground ? "ground" : "planes", 0, "spring_particles has no collisions");
  if (!s.regions.empty()) fail("regions", 0, "spring_particles has one material per object");
  example::SpringParticles::Params p;
  p.gravity = s.gravity;
  p.substeps = s.substeps;
  const std::vector<std::string> names = {"stiffness", "mass", "damping"};
  for (const auto& [key, value_line] : s.parameters) {
    const auto [value, line] = value_line;
    if (key == "stiffness" || key == "damping") {
      if (!(value >= 0)) fail(key, line, "must be >= 0");
      (key == "stiffness" ? p.stiffness : p.damping) = value;
    } else if (key == "mass") {
      if (!(value > 0)) fail(key, line, "must be positive");
      p.mass = value;
    } else {
      const std::string near = pbve::nearest_key(key, names);
      fail(key, line,
           "unknown key for engine spring_particles" +
               (near.empty() ? std::string() : " (did you mean '" + near + "'?)") +
               "; parameters: stiffness, mass, damping");
    }
  }
  return std::make_unique<example::SpringParticles>(r.mesh, r.rest_positions, r.anchors, p);
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2 || argc > 3) {
    std::fprintf(stderr, "usage: custom_adapter SCENE.yaml [OUT.mp4]\n");
    return 2;
  }
  try {
    const pbve::Scene scene = pbve::load_scene(argv[1]);
    pbve::EditOptions options;
    if (argc == 3) {
      options.video = argv[2];
      options.report = std::filesystem::path(argv[2]).replace_extension(".json");
    }
    pbve::EditCallbacks callbacks;
    callbacks.make_simulator = make_spring_particles;
    callbacks.progress = [](const pbve::EditProgress& p) {
      std::fprintf(stderr, "\rframe %d/%d  violation %.2f%%", p.frame, p.total,
                   p.record.violation_pct);
    };
    const pbve::EditResult result = pbve::run_edit(scene, options, callbacks);
    const pbve::ReportSummary s = result.report.summary();
    std::printf("\nwrote %s (violation mean %.3f%%) and %s\n", result.video.c_str(),
                s.violation_pct_mean, result.report_path.c_str());
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "custom_adapter: error: %s\n", e.what());
    return 1;
  }
}
