#pragma once
/// @file
/// Creates a simulator for a scene's `simulation:` section with any engine of this build.

#include <filesystem>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "pbve/core/mesh.hpp"
#include "pbve/edit/engine_recipe.hpp"
#include "pbve/edit/scene.hpp"
#include "pbve/sim/simulator.hpp"

namespace pbve {

/// Names of the engines built into this library ("mass_spring", and "bullet" when built).
std::vector<std::string> available_engines();

/// Material parameters an engine accepts as `simulation:` overrides, for messages and docs.
std::vector<std::string> engine_parameters(const std::string& engine);

/// Builds the simulator. Throws InputError naming the scene file, line and key for an
/// unknown engine or material, an unknown parameter (with the nearest valid one) or an
/// invalid value.
std::unique_ptr<Simulator> make_engine(const EngineRecipe& recipe);

/// Checks, before any work, that the scene's engine is one of available_engines() (InputError
/// naming the scene file, the line of `simulation.engine` and the nearest engine otherwise) and
/// that its `simulation:` parameters are valid for it (InputError with the key and its line):
/// everything make_engine() checks that needs no mesh.
void check_engine(const Scene& scene);

}  // namespace pbve
