// Runs `pbve edit` on a scene with the custom adapter instead of a built-in engine:
//   custom_adapter SCENE.yaml [OUT.mp4]
// Everything but the engine (visibility, control by central differences, rendering, report) is
// pbve's own.

#include <cstdio>
#include <exception>

#include "pbve/edit/editor.hpp"
#include "pbve/edit/scene.hpp"
#include "spring_particles.hpp"

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
    callbacks.make_simulator = [](const pbve::EngineRecipe& r) {
      return std::make_unique<example::SpringParticles>(r.mesh, r.rest_positions, r.anchors);
    };
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
