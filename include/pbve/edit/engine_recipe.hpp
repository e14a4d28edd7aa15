#pragma once
/// @file
/// What an engine needs to build the simulated object of a scene (see pbve/engines.hpp).

#include <filesystem>
#include <vector>

#include "pbve/core/mesh.hpp"
#include "pbve/edit/scene.hpp"

namespace pbve {

/// Everything an engine needs to build the simulated object.
struct EngineRecipe {
  SceneSimulation simulation;        ///< engine, material, gravity, planes, substeps, overrides
  Mesh mesh;                         ///< the simulated mesh (refined), mesh coordinates
  Vertices rest_positions;           ///< #V by 3, camera frame, metres (first aligned pose)
  std::vector<int> anchors;          ///< anchored vertex ids (sorted)
  std::filesystem::path scene_file;  ///< for messages about parameter overrides
};

}  // namespace pbve
